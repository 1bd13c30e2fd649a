"""Cross-fades: a translating camera (C3) dissolved over 8 frames into a still one (C1), both
scenes moving on during the dissolve. The reader finds the fade where it was made, its frames
belong to no shot and no pair among them is scored; each shot is judged on its own (the first
one's gate sees its translation) and the rigid clip passes. Not looking for fades (the paper),
the clip is one shot gated H. Clean clips of every family show no fade."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from geocon_core.config import CutConfig, ScoreConfig, preset
from geocon_core.media import Mp4Writer, probe_clip
from geocon_core.scoring import score_clip
from geocon_core.synth import FAMILIES, ClipPlan

from .conftest import read_video

W, H, N = 320, 180, 24
OUT, FADE = 12, 8  # frames of the first shot before the fade, and the fade's length (s = 11, e = 19)


@pytest.fixture(scope="module")
def dissolve(synth_clips, tmp_path_factory) -> Path:
    plans = [ClipPlan("C3"), ClipPlan("C1")]
    folder = synth_clips(plans, seed=5, width=W, height=H, num_frames=N)
    a, b = (read_video(folder / f"{p.clip_id}.mp4") for p in plans)
    frames = a[:OUT]
    for k in range(1, FADE):  # frames 12 .. 18: A keeps moving while B comes in
        w = k / FADE
        frames.append(np.clip((1 - w) * a[OUT - 1 + k] + w * b[k - 1], 0, 255).astype(np.uint8))
    frames += b[FADE - 1 :]  # frame 19 on: B alone, from where the fade left it
    path = tmp_path_factory.mktemp("fades") / "c3_dissolve_c1.mp4"
    with Mp4Writer(path, W, H, 24) as writer:
        for rgb in frames:
            writer.write(rgb)
    return path


def test_the_fade_is_found_where_it_was_made(dissolve):
    info = probe_clip(dissolve, preset("audit").with_(working_size=(W, H)))
    ((s, e),) = info.fades
    # the first frames of the fade, a quarter of the next shot or less over a moving camera, can
    # stay with the first shot
    assert OUT - 1 <= s <= OUT + 1 and abs(e - (OUT - 1 + FADE)) <= 1, info.fades
    assert info.shots == ((0, s), (e, info.num_frames - 1))
    assert info.pair_skip_reason(s + 1, e - 1) == "fade" and info.pair_skip_reason(s - 4, s) is None
    assert info.pair_skip_reason(s, e) == "hard_cut"
    assert probe_clip(dissolve, ScoreConfig(working_size=(W, H))).fades == ()  # the paper does not look


@pytest.mark.full
def test_each_shot_is_judged_and_the_dissolve_is_not(dissolve):
    rec = score_clip(dissolve, preset("audit").with_(working_size=(W, H)))
    assert len(rec.shots) == 2 and rec.background.consistent is True
    assert rec.shots[0].label in ("U", "F") and rec.shots[1].label == "H"  # a translating camera, then a still one
    assert all(s.consistent for s in rec.shots)
    assert any("cross-fade" in w for w in rec.warnings)
    assert not any(p.skip is None and rec.video.fades[0][0] < p.t0 < rec.video.fades[0][1] for p in rec.pairs)
    # not looking for fades, the clip is one shot: the gate composes hops through the dissolve and
    # calls the whole clip H, the first shot's translation unseen
    blind = score_clip(dissolve, preset("audit").with_(working_size=(W, H), cuts=CutConfig()))
    assert blind.video.fades == () and blind.shots == () and blind.gate.label == "H"


@pytest.mark.full
def test_clean_clips_show_no_fade(synth_clips):
    plans = [ClipPlan(code) for code in FAMILIES]
    folder = synth_clips(plans, seed=5, width=W, height=H, num_frames=N)
    audit = preset("audit").with_(working_size=(W, H))
    for p in plans:
        assert probe_clip(folder / f"{p.clip_id}.mp4", audit).fades == (), p.clip_id
