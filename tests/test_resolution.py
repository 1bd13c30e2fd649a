"""The resolution policy (never upscale, fixed-pixel thresholds at the clip's own resolution) on
synthetic scenes with exact geometry: the same clean scene gets the same verdict and nearly the
same IR at every size, and a breathing background stays detected at small sizes."""

from __future__ import annotations

from pathlib import Path

import pytest

from geocon_core.config import preset
from geocon_core.media import probe_clip
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
    # ratio 0.7; the paper's three scales, so that the scale rule (min_scale_side) is seen at work
    return score_clip(path, preset("audit").with_(masks="none", gaps=(1, 8), scales=(0.25, 0.5, 1.0)))


@pytest.mark.full
def test_a_clean_scene_reads_the_same_at_every_size(clips):
    small, large = _score(clips["clean", 256]), _score(clips["clean", 720])
    assert small.video.scale == 1.0 and small.video.working_size == (448, 256)  # not upscaled
    assert large.video.scale == 1.0 and large.video.working_size == (1280, 720)  # long side <= 1280: kept
    assert small.background.consistent and large.background.consistent
    assert small.background.ir == pytest.approx(large.background.ir, abs=0.02)
    # the quarter scale of a 256 px clip would be 64 px high: not scored, and not held against it
    assert small.background.chosen.invalid_reasons.get("scale_too_small", 0) > 0
    assert all(g.judged for g in small.background.chosen.per_gap)


@pytest.mark.full
def test_a_breathing_background_stays_detected_at_every_size(clips):
    for h in (256, 720):
        rec = _score(clips["breathing", h])
        assert rec.background.consistent is False, h


def test_the_default_canvas_keeps_the_long_side_at_1280_px(tmp_path):
    """A full-HD clip, landscape or portrait, is resized once at decode to a long side of 1280 px;
    1280x720 and smaller clips keep their own pixels."""
    plan = plan_clips("C1")[0]
    for (w, h), canvas in (((1920, 1080), (1280, 720)), ((1080, 1920), (720, 1280)), ((1280, 720), (1280, 720))):
        gt = write_clip(plan, tmp_path / f"{w}x{h}", width=w, height=h, num_frames=2, codec="png")
        info = probe_clip(tmp_path / f"{w}x{h}" / f"{gt.clip_id}.frames", preset("audit"))
        assert info.working_size == canvas, (w, h)
        assert info.scale == pytest.approx(canvas[0] / w, abs=1e-3)


@pytest.mark.full
def test_a_resized_clip_says_so_and_gives_its_ge_in_source_pixels(clips):
    """The record of a clip resized at decode names both sizes and converts the background's GE
    (working px) to source px with the decode scale; an unresized clip says nothing."""
    rec = score_clip(clips["clean", 720], preset("audit").with_(masks="none", gaps=(1,), working_size=(640, 640)))
    c = rec.canvas()
    assert c["resized"] and c["source_size"] == [1280, 720] and c["working_size"] == [640, 360]
    assert c["scale"] == pytest.approx(0.5)
    assert c["ge_source_px"] == pytest.approx(rec.background.ge / 0.5)
    note = rec.canvas_note()
    assert note is not None and "1280x720 to 640x360" in note and "source px" in note
    assert rec.summary()["canvas"] == c
    same = _score(clips["clean", 256])
    assert same.canvas_note() is None and same.canvas()["ge_source_px"] == pytest.approx(same.background.ge)
