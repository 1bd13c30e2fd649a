"""The peer (GVGC keep rate) and the clip-level finding the validation compares with it."""

from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest

from geocon_core.record import CLIP_SCORE_SLOPE, clip_finding, clip_score
from geocon_core.validation.metrics import auc
from geocon_core.validation.peer import PEER_FILE, PEER_VERSION, peer_keep_rate, raw_frames
from geocon_core.validation.results import peer_score
from geocon_core.validation.runner import _peer_done, _peer_one


def _warped_copy(clip, folder, amplitude: float, frames: int) -> None:
    """The clip's frames, each bent by its own smooth random displacement field (a background that
    melts: no two frames are related by one camera motion)."""
    rng = np.random.default_rng(0)
    folder.mkdir()
    for i, bgr in enumerate(raw_frames(clip, frames)):
        h, w = bgr.shape[:2]
        coarse = rng.normal(0.0, amplitude, (2, 4, 6)).astype(np.float32)
        dx, dy = (cv2.resize(c, (w, h), interpolation=cv2.INTER_CUBIC) for c in coarse)
        xx, yy = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
        cv2.imwrite(str(folder / f"{i:03d}.png"), cv2.remap(bgr, xx + dx, yy + dy, cv2.INTER_LINEAR))


@pytest.mark.full
def test_peer_keeps_a_rigid_scene_and_drops_a_melting_one(synth_dir, tmp_path):
    clip = synth_dir / "c3_translation.mp4"  # a lateral truck past a rendered rigid scene
    rigid = peer_keep_rate(clip, 12)
    assert rigid.frames == 12 and rigid.pairs == 11 and rigid.matches > 1000
    assert rigid.keep_rate is not None and rigid.keep_rate > 0.8
    again = peer_keep_rate(clip, 12)
    assert (again.keep_rate, again.matches, again.inliers) == (rigid.keep_rate, rigid.matches, rigid.inliers)
    _warped_copy(clip, tmp_path / "melting", 4.0, 12)
    melting = peer_keep_rate(tmp_path / "melting")
    assert melting.keep_rate is not None and melting.keep_rate < rigid.keep_rate - 0.3
    assert melting.score is not None and math.isclose(melting.score, 1.0 - melting.keep_rate)
    with pytest.raises(ValueError, match="gap"):
        peer_keep_rate(clip, 4, gap=0)


def test_peer_is_saved_beside_the_record_once_and_read_back(synth_dir, tmp_path):
    clip = str(synth_dir / "c3_translation.mp4")
    saved = _peer_one(clip, str(tmp_path), 6)
    assert saved["clip"] == clip and saved["version"] == PEER_VERSION and saved["frames"] == 6
    assert _peer_done(tmp_path, clip) and not _peer_done(tmp_path, clip + ".other")
    assert peer_score(tmp_path) == pytest.approx(1.0 - saved["keep_rate"])
    (tmp_path / PEER_FILE).write_text(json.dumps({**saved, "version": PEER_VERSION + 1}))
    assert peer_score(tmp_path) is None and not _peer_done(tmp_path, clip)  # another protocol: recomputed
    failed = _peer_one(str(tmp_path / "gone.mp4"), str(tmp_path), 6)  # unreadable: kept with its reason
    assert failed["keep_rate"] is None and "no such file" in failed["error"] and peer_score(tmp_path) is None


def test_clip_score_reads_the_report_gate_headroom():
    assert clip_score(0.0) == 0.5 and clip_score(None) is None and clip_score(float("nan")) is None
    assert clip_score(1.0) == pytest.approx(1 / (1 + math.exp(CLIP_SCORE_SLOPE)))
    margins = [-1e9, -2.0, -0.1, 0.0, 0.05, 0.5, 1.0]
    scores = [clip_score(m) for m in margins]
    assert scores == sorted(scores, reverse=True) and all(s is not None and 0 <= s <= 1 for s in scores)
    gates = dict(ir_gate=0.97, ge_gate=0.6)
    bad = clip_finding(model="F", ir=0.9, ge=0.8, consistent=False, margin=-2.0, note="", shots=2, **gates)
    assert bad.verdict == "inconsistent" and bad.clip_score is not None and bad.clip_score > 0.5
    assert "90.0% of its matches fit" in bad.reason and "0.80 px" in bad.reason and "of 2" in bad.reason
    good = clip_finding(model="H", ir=0.99, ge=0.2, consistent=True, margin=0.5, note="", **gates)
    assert good.verdict == "consistent" and good.clip_score is not None and good.clip_score < 0.5
    none = clip_finding(model="H", ir=None, ge=None, consistent=None, margin=None, note="too few pairs", **gates)
    assert (none.verdict, none.reason, none.clip_score) == ("cannot judge", "too few pairs", None)


def test_record_summary_carries_the_finding(synth_dir, scored_clip):
    from geocon_core.config import preset

    rec = scored_clip(synth_dir / "c1_static.mp4", preset("fast"))
    summary = rec.summary()
    assert (
        summary["verdict"]["verdict"]
        == {True: "consistent", False: "inconsistent", None: "cannot judge"}[rec.background.consistent]
    )
    assert summary["clip_score"] == rec.finding().clip_score
    assert (summary["clip_score"] < 0.5) == bool(rec.background.consistent)


def test_auc_counts_pairs_ties_half_and_missing_scores_as_no_evidence():
    assert auc([0.9, 0.8], [0.1, 0.2]) == 1.0
    assert auc([0.1], [0.9]) == 0.0
    assert auc([0.5, 0.7], [0.5]) == 0.75  # one tie, one win
    assert auc([None], [0.2, 0.8]) == 0.5
    assert auc([], [0.1]) is None


def test_f_test_looseness_is_read_in_source_pixels(synth_dir, scored_clip):
    """A rendered rigid scene seen by a trucking camera: its background matches lie within a pixel
    or two of each pair's F, far inside the loose tau_F that the records translate to pixels."""
    from geocon_core.config import preset
    from geocon_core.validation.results import F_PX_STEPS, f_within_px

    rec = scored_clip(synth_dir / "c3_translation.mp4", preset("fast"))
    within, tau_px = f_within_px(rec)
    assert within is not None and tau_px is not None and len(within) == len(F_PX_STEPS)
    assert list(within) == sorted(within) and within[F_PX_STEPS.index(2.0)] > 0.9
    assert tau_px > 2.0  # tau_F (normalised) is several source pixels at this size
    assert f_within_px(rec, (1e9,))[0] == (1.0,)


def test_the_sampson_distance_is_zero_on_exact_two_view_geometry_and_grows_off_it():
    from geocon_core.validation.peer import sampson_squared

    rng = np.random.default_rng(1)
    K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])
    X = np.c_[rng.uniform(-2, 2, (50, 2)), rng.uniform(4, 8, 50)]
    R, _ = cv2.Rodrigues(np.array([0.02, -0.05, 0.01]))
    t = np.array([0.4, 0.05, 0.1])
    x1 = (X @ K.T)[:, :2] / X[:, 2:]
    Y = X @ R.T + t
    x2 = (Y @ K.T)[:, :2] / Y[:, 2:]
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    F = np.linalg.inv(K).T @ tx @ R @ np.linalg.inv(K)
    assert sampson_squared(F, x1, x2).max() < 1e-9
    off = sampson_squared(F, x1, x2 + np.array([0.0, 3.0]))
    assert 0.1 < np.median(off) < 9.0, "a 3 px shift reads as a squared distance of a few px^2"


@pytest.mark.full
def test_epipolar_dpo_reads_a_melting_scene_above_a_rigid_one_and_is_deterministic(synth_dir, tmp_path):
    from geocon_core.validation.peer import EPIPOLAR_STRIDE, epipolar_score

    clip = synth_dir / "c3_translation.mp4"
    rigid = epipolar_score(clip)
    assert rigid.frames == len(range(0, 24, EPIPOLAR_STRIDE)) and rigid.pairs == rigid.frames - 1
    assert rigid.sampson is not None and epipolar_score(clip).sampson == rigid.sampson
    _warped_copy(clip, tmp_path / "melting", 4.0, 24)
    melting = epipolar_score(tmp_path / "melting")
    assert melting.sampson is not None and melting.sampson > rigid.sampson


def test_the_peer_file_holds_both_peers(synth_dir, tmp_path):
    from geocon_core.validation.results import epipolar_peer_score

    clip = synth_dir / "c1_static.mp4"
    saved = _peer_one(str(clip), str(tmp_path), 16)
    assert saved["version"] == PEER_VERSION and saved["epipolar"]["sampson"] is not None
    assert epipolar_peer_score(tmp_path) == saved["epipolar"]["sampson"]
