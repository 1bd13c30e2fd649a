"""End-to-end scoring against synthetic ground truth and real footage with known geometry."""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from geocon_core.config import ScoreConfig, preset
from geocon_core.geometry import apply_homography, inlier_stats
from geocon_core.record import read_record, write_record
from geocon_core.scoring import score_clip
from geocon_core.synth import ClipPlan, load_ground_truth, write_clip

from .conftest import SHARED_DATA

TWO_SCALES = ScoreConfig(scales=(0.5, 1.0))


@pytest.fixture(scope="module")
def clips(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("score")
    for plan in (ClipPlan("C1"), ClipPlan("C2"), ClipPlan("C3")):
        write_clip(plan, out, seed=11, width=640, height=360, num_frames=20)
    return out


@pytest.fixture(scope="module")
def scored(clips) -> dict:
    return {cid: score_clip(clips / f"{cid}.mp4", TWO_SCALES) for cid in ("c1_static", "c2_rotation", "c3_translation")}


@pytest.mark.full
@pytest.mark.parametrize("cid", ["c1_static", "c2_rotation"])
def test_static_and_rotation_gate_h_and_are_consistent(scored, clips, cid):
    rec = scored[cid]
    gt = load_ground_truth(clips / f"{cid}.gt.json")
    assert rec.gate.label == "H" and rec.gate.model == "H" and rec.gate.pose_present
    assert rec.gate.t_inf == pytest.approx(gt.t_inf, abs=0.01)
    assert rec.background.ir >= 0.97 and rec.background.ge <= 1.0
    assert rec.background.consistent is True
    assert rec.background.valid_pairs == rec.background.total_pairs == 19 * 2
    assert rec.video.duplicates == () and rec.video.cuts == ()


@pytest.mark.full
def test_translation_gates_f(scored, clips):
    rec = scored["c3_translation"]
    gt = load_ground_truth(clips / "c3_translation.gt.json")
    assert rec.gate.label == "F" and rec.gate.model == "F"
    assert abs(rec.gate.t_inf - gt.t_inf) <= max(0.01, 0.3 * gt.t_inf)
    assert rec.gate.margin == pytest.approx(rec.gate.t_inf - 0.05)
    assert rec.background.ir >= 0.9
    # the pixel equivalent of tau_F is logged and is far looser than tau_H
    assert rec.background.tau_f_px > 5


@pytest.mark.full
@pytest.mark.parametrize("cid", ["c1_static", "c2_rotation", "c3_translation"])
def test_fast_preset_keeps_the_gate_and_the_verdict(scored, clips, cid):
    gt = load_ground_truth(clips / f"{cid}.gt.json")
    rec, ref = score_clip(clips / f"{cid}.mp4", preset("fast")), scored[cid]
    assert rec.gate.label == ref.gate.label == gt.expected_gate
    assert abs(rec.gate.t_inf - gt.t_inf) <= max(0.01, 0.3 * gt.t_inf)
    assert rec.background.consistent is ref.background.consistent is True
    # one scale, on the 512x360 canvas (the 640x360 clip downscaled), every pair valid
    assert rec.video.working_size == (512, 288) and rec.background.valid_pairs == 19


@pytest.mark.slow
def test_breathing_raises_ge_and_strict_gaps_expose_it(clips):
    """A 3 px rubber-sheet breathing (24-frame period): GE rises by half or more under the paper
    preset while IR at gap 1 barely moves (0.104 -> 0.185 px on the reproducible render of this
    scene; the earlier bound, twice, was set on renders that were not reproducible); the strict
    preset's long gaps drop IR below 0.9."""
    write_clip(ClipPlan("C2", "breathing", 3.0), clips, seed=11, width=640, height=360, num_frames=20)
    clean = score_clip(clips / "c2_rotation.mp4", preset("paper"))
    paper = score_clip(clips / "c2_rotation__breathing-s3.mp4", preset("paper"))
    strict = score_clip(clips / "c2_rotation__breathing-s3.mp4", preset("strict"))
    assert paper.gate.label == "H" and clean.background.consistent
    assert paper.background.ge >= 1.5 * clean.background.ge, (paper.background.ge, clean.background.ge)
    assert strict.background.ir < 0.9
    per_gap = {g.gap: g for g in strict.background.chosen.per_gap}
    assert set(per_gap) == {1, 4, 8} and per_gap[8].ir < per_gap[1].ir


@pytest.mark.slow
@pytest.mark.parametrize("fov", [48.0, 72.0])
def test_gate_decisions_survive_a_wrong_field_of_view(clips, scored, fov):
    for cid in ("c2_rotation", "c3_translation"):
        rec = score_clip(clips / f"{cid}.mp4", TWO_SCALES.with_(scales=(1.0,), fov_x_deg=fov))
        assert rec.gate.label == scored[cid].gate.label, (cid, fov, rec.gate.t_inf)


@pytest.mark.full
def test_record_round_trips_and_rescoring_is_byte_identical(clips, scored, tmp_path):
    rec = scored["c3_translation"]
    write_record(rec, tmp_path / "a")
    again = score_clip(clips / "c3_translation.mp4", TWO_SCALES)
    write_record(again, tmp_path / "b")
    for name in ("record.json", "matches.npz"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes(), name
    back = read_record(tmp_path / "a")
    assert back.summary() == rec.summary()
    assert back.config == rec.config and back.pairs == rec.pairs
    for name in back.matches.NAMES:
        np.testing.assert_array_equal(getattr(back.matches, name), getattr(rec.matches, name))
    # re-gating the stored residuals at the recorded thresholds reproduces every IR and GE
    checked = 0
    for p in back.pairs:
        arr = back.matches.pair(p.index)
        if p.skip is None and p.h.model is not None:
            _, ir, ge = inlier_stats(arr["h_res"], arr["h_res"], back.config.tau_h)
            assert (ir, ge) == (p.h.ir, p.h.ge)
            checked += 1
        if p.skip is None and p.f.model is not None:
            _, ir, ge = inlier_stats(arr["f_res"], arr["f_res_px"], back.config.tau_f)
            assert (ir, ge) == (p.f.ir, p.f.ge)
            checked += 1
    assert checked > len(back.pairs)


def test_presets_are_named_and_recorded():
    assert preset("strict").gaps == (1, 4, 8) and preset("paper").gaps == (1,)
    with pytest.raises(ValueError, match="valid: paper, strict"):
        preset("loose")


def _image_pair(tmp_path: Path, a: Path, b: Path) -> Path:
    folder = tmp_path / "pair"
    folder.mkdir()
    shutil.copyfile(a, folder / f"0{a.suffix}")
    shutil.copyfile(b, folder / f"1{b.suffix}")
    return folder


def _requires_shared():
    if not SHARED_DATA.is_dir():
        pytest.skip("../shared/data is not available")


def test_graf_homography_matches_the_true_one(tmp_path):
    _requires_shared()
    src = SHARED_DATA / "real" / "opencv"
    rec = score_clip(_image_pair(tmp_path, src / "graf1.png", src / "graf3.png"), ScoreConfig(scales=(1.0,)))
    pair = next(p for p in rec.pairs if p.scale == 1.0)
    assert pair.h.valid
    H_work = np.array(pair.h.model)
    s, (ox, oy) = rec.video.scale, rec.video.offset
    S = np.array([[s, 0, ox + 0.5 * s - 0.5], [0, s, oy + 0.5 * s - 0.5], [0, 0, 1]])
    H_src = np.linalg.inv(S) @ H_work @ S
    fs = cv2.FileStorage(str(src / "H1to3p.xml"), cv2.FILE_STORAGE_READ)
    H_true = fs.getFirstTopLevelNode().mat()
    w, h = rec.video.source_size
    gx, gy = np.meshgrid(np.linspace(0, w - 1, 20), np.linspace(0, h - 1, 16))
    pts = np.column_stack([gx.ravel(), gy.ravel()])
    diff = np.linalg.norm(apply_homography(H_src, pts) - apply_homography(H_true, pts), axis=1)
    assert np.median(diff) < 2.0, np.median(diff)


def test_aloe_stereo_is_explained_by_f(tmp_path):
    _requires_shared()
    src = SHARED_DATA / "real" / "opencv"
    rec = score_clip(_image_pair(tmp_path, src / "aloeL.jpg", src / "aloeR.jpg"), ScoreConfig(scales=(1.0,)))
    pair = next(p for p in rec.pairs if p.scale == 1.0)
    assert pair.f.valid and pair.f.ge < 1.0, pair.f.ge
    assert pair.f.ir > pair.h.ir
    assert rec.gate.model == "F"
