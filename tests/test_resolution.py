"""The resolution policy (never upscale, fixed-pixel thresholds at the clip's own resolution) on
synthetic scenes with exact geometry: the same clean scene gets the same verdict and nearly the
same IR at every size, and a breathing background stays detected at small sizes."""

from __future__ import annotations

from pathlib import Path

import pytest

from geocon_core.config import preset
from geocon_core.scoring import score_clip
from geocon_core.synth import plan_clips, write_clip

SIZES = ((448, 256), (1280, 720))


@pytest.fixture(scope="module")
def clips(tmp_path_factory) -> dict[tuple[str, int], Path]:
    root = tmp_path_factory.mktemp("resolution")
    out = {}
    for kind, plan in (("clean", plan_clips("C2")[0]), ("breathing", plan_clips("C2", "breathing", 3.0)[0])):
        for w, h in SIZES:
            gt = write_clip(plan, root / f"{kind}-{h}", width=w, height=h, num_frames=10, codec="h264", crf=18)
            out[kind, h] = root / f"{kind}-{h}" / f"{gt.clip_id}.mp4"
    return out


def _score(path: Path):
    return score_clip(path, preset("audit").with_(masks="none", gaps=(1, 8)))  # ratio 0.7


def test_a_clean_scene_reads_the_same_at_every_size(clips):
    small, large = _score(clips["clean", 256]), _score(clips["clean", 720])
    assert small.video.scale == 1.0 and small.video.working_size == (448, 256)  # not upscaled
    assert large.video.scale == 1.0 and large.video.working_size == (1280, 720)  # audit's full-HD canvas
    assert small.background.consistent and large.background.consistent
    assert small.background.ir == pytest.approx(large.background.ir, abs=0.02)
    # the quarter scale of a 256 px clip would be 64 px high: not scored, and not held against it
    assert small.background.chosen.invalid_reasons.get("scale_too_small", 0) > 0
    assert all(g.judged for g in small.background.chosen.per_gap)


def test_a_breathing_background_stays_detected_at_every_size(clips):
    for h in (256, 720):
        rec = _score(clips["breathing", h])
        assert rec.background.consistent is False, h
