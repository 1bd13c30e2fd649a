"""The reward for training loops: frames scored in memory equal the files scored by `geocon
score`, guards keep frozen, slowed and blurred copies from winning, and `geocon pairs` writes,
resumes and refuses as documented."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from geocon_core.config import RewardConfig, preset
from geocon_core.media import ClipError, as_bgr_frames, probe_clip, probe_frames
from geocon_core.record import read_record
from geocon_core.reward import (
    ManifestError,
    RewardScorer,
    decode_clip,
    read_manifest,
    reward_hash,
    reward_of_record,
    sample_evenly,
    score_reward,
    write_pairs,
)
from geocon_core.scoring import score_frames
from geocon_core.synth import ClipPlan, write_clip
from geocon_viewer.cli import app

runner = CliRunner()


@pytest.fixture(scope="module")
def clips(tmp_path_factory) -> dict[str, Path]:
    """Synthetic clips of a turning and a translating camera, and a turning one that breathes (480x270)."""
    out = tmp_path_factory.mktemp("reward")
    plans = {"turn": ClipPlan("C2"), "move": ClipPlan("C3"), "breathing": ClipPlan("C2", "breathing", 3.0)}
    paths = {}
    for key, plan in plans.items():
        before = set(out.glob("*.mp4"))
        write_clip(plan, out, seed=5, width=480, height=270, num_frames=24)
        (paths[key],) = set(out.glob("*.mp4")) - before
    return paths


@pytest.fixture(scope="module")
def png_folder(clips, tmp_path_factory) -> tuple[Path, np.ndarray]:
    """The turning clip's decoded frames, and the same frames as a folder of lossless PNG files."""
    frames = decode_clip(clips["turn"])
    folder = tmp_path_factory.mktemp("png")
    for t, bgr in enumerate(frames):
        cv2.imwrite(str(folder / f"frame_{t:03d}.png"), bgr)
    return folder, frames


def test_frames_of_any_layout_become_the_same_bgr_bytes():
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, size=(3, 20, 24, 3), dtype=np.uint8)
    bgr = as_bgr_frames(rgb)
    assert bgr.shape == (3, 20, 24, 3) and (bgr[..., 0] == rgb[..., 2]).all()
    chw_float = np.moveaxis(rgb, -1, 1).astype(np.float32) / 255.0
    assert (as_bgr_frames(chw_float) == bgr).all(), "(T, 3, H, W) floats in [0, 1] read as the same bytes"
    assert (as_bgr_frames(rgb[..., ::-1], channel_order="bgr") == bgr).all()
    grey = as_bgr_frames(rgb[..., 0])
    assert (grey[..., 0] == grey[..., 2]).all()


@pytest.mark.parametrize(
    ("frames", "words"),
    [
        (np.zeros((1, 32, 32, 3), np.uint8), "at least 2"),
        (np.zeros((4, 32, 32, 4), np.uint8), "3 colour channels"),
        (np.zeros((4, 32), np.uint8), "must have shape"),
        (np.full((4, 32, 32, 3), 2.0, np.float32), "[0, 1]"),
        (np.full((4, 32, 32, 3), np.nan, np.float32), "NaN"),
        (np.zeros((4, 8, 8, 3), np.uint8), "too small"),
        (np.full((4, 32, 32, 3), 300, np.int32), "0..255"),
    ],
)
def test_unusable_frames_are_refused_with_one_sentence(frames, words):
    with pytest.raises(ClipError) as info:
        as_bgr_frames(frames)
    assert words in str(info.value) and "\n" not in str(info.value)


def test_frames_in_memory_probe_as_their_png_folder(png_folder):
    folder, frames = png_folder
    cfg = preset("reward")
    a, b = probe_frames(frames, "mem", cfg).to_dict(), probe_clip(folder, cfg).to_dict()
    for key in ("path", "abs_path", "fingerprint", "kind", "from_record", "warnings"):
        a.pop(key), b.pop(key)
    assert a == b


def test_frames_in_memory_score_as_geocon_score_scores_their_png_folder(png_folder, tmp_path):
    folder, frames = png_folder
    cfg = preset("reward")
    mem = score_frames(frames, cfg, channel_order="bgr", workers=1)
    res = runner.invoke(app, ["score", str(folder), "--preset", "reward", "--out", str(tmp_path / "rec")])
    assert res.exit_code == 0, res.output
    disk = read_record(tmp_path / "rec")
    assert mem.background.ir == disk.background.ir and mem.background.ge == disk.background.ge
    assert [(p.t0, p.t1, p.h, p.f) for p in mem.pairs] == [(p.t0, p.t1, p.h, p.f) for p in disk.pairs]
    rcfg = RewardConfig()
    reward = score_reward(frames, channel_order="bgr")
    assert reward.judged, reward.reason
    sampled = np.ascontiguousarray(frames[sample_evenly(len(frames), rcfg.max_frames)])
    assert reward.score == reward_of_record(disk, rcfg, frames=sampled).score, "the API's reward is the CLI record's"
    with pytest.raises(ValueError, match="needs the frames"):
        reward_of_record(disk, rcfg)
    assert reward.interval is not None and reward.interval[0] <= reward.score <= reward.interval[1]
    assert score_frames(frames, cfg, channel_order="bgr", workers=2).background.ir == mem.background.ir


def test_a_torch_tensor_scores_as_its_numpy_frames(png_folder):
    torch = pytest.importorskip("torch")
    _, frames = png_folder
    rgb = np.ascontiguousarray(frames[..., ::-1])
    tensor = torch.from_numpy(np.moveaxis(rgb, -1, 1).copy()).float() / 255.0  # (T, 3, H, W) in [0, 1]
    assert score_reward(tensor).score == score_reward(rgb).score


def _copies(frames: np.ndarray) -> dict[str, np.ndarray]:
    n = len(frames)
    return {
        "frozen": np.repeat(frames[:1], n, axis=0),
        "slowed": np.repeat(frames[: (n + 1) // 2], 2, axis=0)[:n],
        "blurred": np.stack([cv2.GaussianBlur(f, (0, 0), 3.0) for f in frames]),
    }


@pytest.mark.parametrize("key", ["turn", "move", "breathing"])
def test_frozen_slowed_and_blurred_copies_never_outrank_the_clip(clips, key):
    frames = decode_clip(clips[key])
    scorer = RewardScorer(workers=1)
    own = scorer.score(frames, channel_order="bgr")
    assert own.judged, own.reason
    for name, copy in _copies(frames).items():
        got = scorer.score(copy, channel_order="bgr")
        assert not got.judged or got.score < own.score, f"{name} copy of {key} outranks it: {got.score} vs {own.score}"
    frozen = scorer.score(_copies(frames)["frozen"], channel_order="bgr")
    assert frozen.guard == "motion" and "too little motion" in (frozen.reason or "")
    assert scorer.score(_copies(frames)["slowed"], channel_order="bgr").guard == "repeated"


def test_a_hard_cut_cannot_be_judged(clips):
    a, b = decode_clip(clips["turn"]), decode_clip(clips["move"])
    cut = np.concatenate([a[:12], b[12:]])
    got = score_reward(cut, channel_order="bgr")
    assert got.guard == "cut" and not got.judged


def test_a_batch_comes_back_in_order_with_the_numbers_of_one_clip_at_a_time(clips):
    frames = [decode_clip(clips[k]) for k in ("turn", "move")]
    scorer = RewardScorer(workers=2)
    batch = scorer.score_batch([f[..., ::-1] for f in frames] + [np.zeros((1, 32, 32, 3), np.uint8)])
    one = [scorer.score(f, channel_order="bgr").score for f in frames]
    assert [r.score for r in batch[:2]] == one
    assert batch[2].guard == "frames" and "at least 2" in (batch[2].reason or "")


def test_sampling_keeps_first_and_last_and_at_most_the_budget():
    idx = sample_evenly(100, 32)
    assert len(idx) == 32 and idx[0] == 0 and idx[-1] == 99 and (np.diff(idx) > 0).all()
    assert sample_evenly(10, 32).tolist() == list(range(10))


def _manifest(tmp_path: Path, clips: dict[str, Path], rows: list[tuple[str, str]]) -> Path:
    for key, clip in clips.items():
        target = tmp_path / f"{key}.mp4"
        if not target.exists():
            target.symlink_to(clip)
    m = tmp_path / "manifest.csv"
    m.write_text("path,group\n" + "".join(f"{p},{g}\n" for p, g in rows))
    return m


def test_pairs_prefer_the_clean_clip_resume_and_never_choose_a_frozen_one(clips, tmp_path):
    frames = decode_clip(clips["turn"])
    folder = tmp_path / "frozen"
    folder.mkdir()
    for t in range(len(frames)):
        cv2.imwrite(str(folder / f"f{t:03d}.png"), frames[0])
    m = _manifest(tmp_path, clips, [("turn.mp4", "a"), ("breathing.mp4", "a"), ("frozen", "a"), ("move.mp4", "b")])
    out = tmp_path / "pairs.jsonl"
    summary = write_pairs(m, out, RewardScorer(workers=2))
    lines = [json.loads(x) for x in out.read_text().splitlines()]
    assert summary.scored == 4 and summary.small_groups == 1
    assert [(x["chosen"], x["rejected"]) for x in lines] == [("turn.mp4", "breathing.mp4")]
    assert lines[0]["margin"] > 0 and lines[0]["margin_interval"][0] > 0
    assert lines[0]["reward_hash"] == reward_hash(RewardConfig()) != reward_hash(RewardConfig(window=3))
    assert {p for p, _ in summary.unjudged} == {"frozen"}
    again = write_pairs(m, out, RewardScorer(workers=2))
    assert again.scored == 0 and again.resumed == 4 and out.read_text().splitlines() == [json.dumps(x) for x in lines]


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ("clip,group\nturn.mp4,a\n", "no 'path' column"),
        ("path,kind\nturn.mp4,a\n", "no 'group'"),
        ("path,group\n", "lists no clip"),
        ("path,group\nmissing.mp4,a\n", "does not exist"),
        ("path,group\nturn.mp4,a\nturn.mp4,b\n", "listed twice"),
        ("path,group\nturn.mp4,\n", "has no group"),
    ],
)
def test_a_bad_manifest_is_refused_with_one_sentence(clips, tmp_path, text, words):
    _manifest(tmp_path, clips, [])
    m = tmp_path / "bad.csv"
    m.write_text(text)
    with pytest.raises(ManifestError) as info:
        read_manifest(m)
    assert words in str(info.value) and "\n" not in str(info.value)
    res = runner.invoke(app, ["pairs", str(m), "--out", str(tmp_path / "p.jsonl")])
    assert res.exit_code != 0 and words in res.output and not (tmp_path / "p.jsonl").exists()


def test_prompt_serves_as_the_group_column(clips, tmp_path):
    _manifest(tmp_path, clips, [])
    m = tmp_path / "p.csv"
    m.write_text("path,prompt\nturn.mp4,a cat\nmove.mp4,a cat\n")
    assert [r.group for r in read_manifest(m)] == ["a cat", "a cat"]


def test_the_soft_share_reads_sub_pixel_residuals_that_the_inlier_ratio_ties(png_folder):
    """A record whose matches are moved by a known sub-pixel amount: the inlier ratio stays 1,
    the soft share falls exactly as its formula says."""
    from dataclasses import replace

    from geocon_core.reward import pair_values

    _, frames = png_folder
    record = score_frames(frames, preset("reward"), channel_order="bgr", workers=1)
    m = record.matches
    fam = record.background.model
    name = "h_res" if fam == "H" else "f_res_px"
    shifted = replace(m, **{name: np.full_like(getattr(m, name), 0.5)})
    moved = replace(record, matches=shifted)
    assert np.allclose(pair_values(moved, 1.0), 1.0 / (1.0 + 0.25)), "every match 0.5 px off weighs 0.8"
    assert (pair_values(moved, 0.0) == pair_values(record, 0.0)).all(), "IR reads the record's inliers"
    assert (pair_values(record, 1.0) <= 1.0).all() and pair_values(record, 1.0).mean() > 0.8


def _turning_texture(n: int, slide_px_per_frame: float = 0.0) -> np.ndarray:
    """A textured plane seen by a camera that pans 2 px a frame (one homography between any two
    frames), optionally with a disc that slides ``slide_px_per_frame`` further each frame."""
    rng = np.random.default_rng(3)
    tex = cv2.GaussianBlur(rng.uniform(0, 255, (400, 700)).astype(np.float32), (0, 0), 2.0)
    tex = cv2.normalize(tex, None, 0, 255, cv2.NORM_MINMAX)
    yy, xx = np.mgrid[:300, :560]
    disc = np.clip((80.0 - np.hypot(xx - 280, yy - 150)) / 10.0, 0.0, 1.0)[..., None]
    out = []
    for t in range(n):
        shift = np.float32([[1, 0, -2.0 * t], [0, 1, 0]])
        base = cv2.warpAffine(tex, shift, (560, 300), flags=cv2.INTER_CUBIC)
        shift[0, 2] -= slide_px_per_frame * t
        moved = cv2.warpAffine(tex, shift, (560, 300), flags=cv2.INTER_CUBIC)
        grey = base[..., None] * (1 - disc) + moved[..., None] * disc
        out.append(np.repeat(np.clip(grey, 0, 255).astype(np.uint8), 3, axis=2))
    return np.stack(out)


def test_windows_read_a_pan_as_one_homography_and_a_sliding_region_as_damage():
    """Ground truth: a pan over a textured plane fits one homography per window (residuals of a
    fraction of a pixel, soft share near 1); a disc sliding 0.5 px a frame is 2 px off the
    background after a 4-step window, so its tracks weigh about 1/(1+4) and the window's share
    falls by about the disc's share of the tracks."""
    from geocon_core.reward.windows import window_values

    cfg = RewardConfig()
    clean = window_values(_turning_texture(16), "H", cfg)
    slid = window_values(_turning_texture(16, 0.5), "H", cfg)
    assert len(clean) == len(slid) == len(range(0, 16 - cfg.window, cfg.window_step))
    assert clean.min() > 0.95, clean
    disc_share = np.pi * 75**2 / (560 * 300)  # the disc's core, of the frame the tracks cover
    assert (clean - slid).mean() == pytest.approx(disc_share * (1 - 1 / (1 + 2.0**2)), rel=0.5)
    assert (slid < clean).all()
    assert (window_values(_turning_texture(16), "H", cfg) == clean).all(), "the same frames, the same numbers"
    f_clean = window_values(_turning_texture(16), "F", cfg)
    assert len(f_clean) and f_clean.min() > 0.9, "a homography's matches satisfy a fundamental matrix too"


def test_the_reward_prefers_a_clip_to_its_sliding_twin():
    scorer = RewardScorer(workers=1)
    clean = scorer.score(_turning_texture(24), channel_order="bgr")
    slid = scorer.score(_turning_texture(24, 0.5), channel_order="bgr")
    assert clean.judged and slid.judged, (clean.reason, slid.reason)
    assert clean.score > slid.score and clean.readings["windows"] == len(clean.pair_scores)


@pytest.mark.parametrize(
    ("settings", "words"),
    [
        ({"reading": "flow"}, "reading must be"),
        ({"window": 0}, "at least 1"),
        ({"soft_px": 0.0}, "soft_px > 0"),
        ({"window_models": "E"}, "window_models must be"),
    ],
)
def test_bad_reward_settings_are_refused(settings, words):
    with pytest.raises(ValueError, match=words):
        RewardConfig(**settings)
