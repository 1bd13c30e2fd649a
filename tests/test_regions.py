"""Region readings over the whole clip against scenes of known motion: a textured still scene in
which one elliptical region slides, warps or is redrawn by a known amount, a camera that pans,
a frame that breathes, a blank clip that cannot be judged, and the record's round trip."""

from __future__ import annotations

import dataclasses
import math

import cv2
import numpy as np
import pytest

from geocon_core.config import RegionsConfig, config_hash, preset
from geocon_core.regions import ClipTracks, RegionsPart, RegionTracker, read_regions, read_regions_again

W, H, T = 480, 320, 40
CENTRE, AXES = (300.0, 150.0), (80.0, 70.0)
CFG = RegionsConfig(enabled=True)


def texture(seed: int = 0, size: tuple[int, int] = (W + 80, H + 80)) -> np.ndarray:
    rng = np.random.default_rng(seed)
    noise = rng.random((size[1], size[0])).astype(np.float32)
    img = cv2.GaussianBlur(noise, (0, 0), 2.0) * 0.6 + cv2.GaussianBlur(noise, (0, 0), 6.0) * 0.4
    img = (img - img.min()) / (img.max() - img.min())
    return (img * 230 + 10).astype(np.float32)


def weight(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The region's weight: 1 inside half its radius, a half cosine to 0 at its rim."""
    r = np.hypot((x - CENTRE[0]) / AXES[0], (y - CENTRE[1]) / AXES[1])
    return np.where(r >= 1, 0.0, 0.5 * (1 + np.cos(math.pi * np.clip((r - 0.5) / 0.5, 0, 1))))


def render(field=None, pan=(0.0, 0.0), redraw: float = 0.0, seed: int = 0) -> list[np.ndarray]:
    """T frames of a still textured scene (or one panning by ``pan`` px per frame); ``field(t, x,
    y)`` the content's displacement at frame t (px); ``redraw``: the region's blend towards other
    texture at the last frame."""
    base, other = texture(seed), texture(seed + 1)
    ys, xs = np.mgrid[0:H, 0:W].astype(np.float32)
    frames = []
    for t in range(T):
        sx, sy = 40 + pan[0] * t, 40 + pan[1] * t
        mx, my = xs + sx, ys + sy
        if field is not None:
            dx, dy = field(t, xs, ys)
            mx, my = mx - dx.astype(np.float32), my - dy.astype(np.float32)
        img = cv2.remap(base, mx, my, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
        if redraw:
            w = (redraw * t / (T - 1) * weight(xs, ys)).astype(np.float32)
            img = img * (1 - w) + cv2.remap(other, xs + 40, ys + 40, cv2.INTER_CUBIC) * w
        frames.append(np.clip(img, 0, 255).astype(np.uint8))
    return frames


def track(frames, labels=None) -> ClipTracks:
    tk = RegionTracker(CFG, len(frames), (W, H))
    content = np.ones((H, W), bool)
    for t, g in enumerate(frames):
        tk.observe(t, g, content, None if labels is None else labels[t])
    return tk.result()


def slide(amount: float, direction=(1.0, 0.0)):
    def field(t, x, y):
        w = weight(x, y) * amount * t / (T - 1)
        return w * direction[0], w * direction[1]

    return field


@pytest.fixture(scope="module")
def clean() -> ClipTracks:
    return track(render())


@pytest.fixture(scope="module")
def slid() -> ClipTracks:
    return track(render(slide(8.0, (0.8, 0.6))))


def inside(point, share: float = 1.0) -> bool:
    return math.hypot((point[0] - CENTRE[0]) / AXES[0], (point[1] - CENTRE[1]) / AXES[1]) <= share


def test_a_still_clean_scene_drifts_nowhere(clean):
    r = read_regions(clean, CFG)
    assert r.values["drift"] is not None and r.values["drift"] < 0.3
    assert r.values["breathing"] < 0.3
    assert not r.fired
    assert r.models["H"] > 0 and r.coverage > 0.9


def test_a_sliding_region_is_found_where_it_slides_by_how_much_and_which_way(slid):
    r = read_regions(slid, CFG)
    (drift,) = [f for f in r.findings if f.reading == "drift"]
    assert drift.fires and "drift" in [f.reading for f in r.fired]
    assert inside(drift.centre, 0.75), drift.centre
    assert 0.5 * 8.0 < drift.value <= 8.5  # the core moves 8 px by the last frame; the region's median a bit less
    assert drift.direction[0] * 0.8 + drift.direction[1] * 0.6 > 0.95
    assert drift.last - drift.first >= CFG.min_baseline
    frames, values = zip(*drift.course, strict=True)
    assert list(frames) == sorted(frames) and values[-1] > values[0]  # it builds up over the clip


def test_a_slide_below_the_threshold_is_measured_but_does_not_fire():
    r = read_regions(track(render(slide(1.0))), CFG)
    assert 0.3 < r.values["drift"] < CFG.drift_px
    assert "drift" not in [f.reading for f in r.fired]


def test_a_panning_camera_is_the_camera_not_a_drift():
    r = read_regions(track(render(pan=(1.2, 0.4))), CFG)
    assert r.values["drift"] < 0.3 and not r.fired


def test_a_smooth_warp_inside_a_region_reads_as_drift_there():
    def melt(t, x, y):
        w = weight(x, y) * 6.0 * (t / (T - 1)) ** 2
        return w * np.sin((y - CENTRE[1]) / AXES[1] * 1.5), w * (1 + (y - CENTRE[1]) / AXES[1]) / 2

    r = read_regions(track(render(melt)), CFG)
    (drift,) = [f for f in r.findings if f.reading == "drift"]
    assert drift.fires and inside(drift.centre)


def test_a_breathing_frame_spreads_its_residual_field(clean):
    def breathe(t, x, y):
        s = 5.0 * math.sin(2 * math.pi * t / 24)
        return s * np.sin(2 * math.pi * x / W * 1.3), s * np.cos(2 * math.pi * y / H * 0.9)

    r = read_regions(track(render(breathe)), CFG, camera="H")  # a still camera: the gate says H
    assert read_regions(track(render(breathe)), CFG, camera="F").values["breathing"] < r.values["breathing"]
    quiet = read_regions(clean, CFG)
    assert r.values["breathing"] > CFG.breathing_px > 5 * quiet.values["breathing"]
    assert "breathing" in [f.reading for f in r.fired]


def test_a_redrawn_region_changes_its_look_there_and_nowhere_else(clean):
    r = read_regions(track(render(redraw=1.0)), CFG)
    (look,) = [f for f in r.findings if f.reading == "appearance"]
    assert look.value > read_regions(clean, CFG).values["appearance"] + 0.2
    assert inside(look.centre)


def test_a_mover_is_judged_by_its_own_motion_not_as_a_drift_of_the_background():
    side = 70

    def mover(t, x, y):  # a square that moves 3 px a frame: a mover, not a slide
        x0 = 60 + 3.0 * t
        inside_ = (x >= x0) & (x < x0 + side) & (y >= 120) & (y < 120 + side)
        return np.where(inside_, 3.0 * t, 0.0), np.zeros_like(x)

    frames = render(mover)
    labels = []
    ys, xs = np.mgrid[0:H, 0:W]
    for t in range(T):
        x0 = 60 + 6.0 * t
        labels.append(((xs >= x0) & (xs < x0 + side) & (ys >= 120) & (ys < 120 + side)).astype(np.int32))
    tr = track(frames, labels)
    r = read_regions(tr, CFG)
    assert r.values["drift"] < 1.0 and "drift" not in [f.reading for f in r.fired]


def test_a_blank_clip_cannot_be_judged_and_says_why():
    frames = [np.full((H, W), 120, np.uint8)] * T
    r = read_regions(track(frames), CFG)
    assert all(v is None for v in r.values.values()) and not r.findings
    assert set(r.reasons) == {"drift", "deformation", "appearance", "breathing"}
    assert "fewer than 40 background tracks" in r.reasons["drift"]


def test_a_fit_that_opencv_refuses_reads_as_no_camera_not_a_crash(slid, monkeypatch):
    """OpenCV's USAC asserts on some degenerate track sets (seen once on real footage) instead of
    returning no model: that pair of keyframes has no camera, and the clip still gets its readings."""
    from geocon_core.regions import readings

    def refuse(*_args, **_kwargs):
        raise cv2.error("OpenCV(4.x) usac: Assertion failed (!model.empty()) in setModelParameters")

    monkeypatch.setattr(readings.cv2, "findFundamentalMat", refuse)
    monkeypatch.setattr(readings.cv2, "findHomography", refuse)
    r = read_regions(slid, CFG)
    assert all(v is None for v in r.values.values()) and set(r.reasons) == set(readings.READING_NAMES)


def test_the_same_tracks_give_the_same_numbers(slid):
    a, b = read_regions(slid, CFG), read_regions(slid, CFG)
    assert a == b
    assert track(render(slide(8.0, (0.8, 0.6)))).xy.tobytes() == slid.xy.tobytes()


def test_a_part_round_trips_through_json_and_arrays_and_reads_again(slid):
    part = RegionsPart(read_regions(slid, CFG), slid, slid.size, slid.scale)
    back = RegionsPart.from_json_dict(part.to_json_dict(), part.arrays())
    assert back.readings == part.readings
    assert back.tracks is not None and np.array_equal(back.tracks.xy, slid.xy, equal_nan=True)
    stricter = dataclasses.replace(CFG, drift_px=50.0)
    again = read_regions_again(back, stricter)
    assert again.readings.values == part.readings.values and not [
        f for f in again.readings.fired if f.reading == "drift"
    ]
    with pytest.raises(ValueError, match="keeps no region tracks"):
        read_regions_again(RegionsPart(part.readings, None, part.size, part.scale), CFG)


def test_regions_are_on_in_audit_only_and_leave_paper_as_it_was():
    assert preset("audit").regions.enabled
    assert not preset("paper").regions.enabled and not preset("strict").regions.enabled
    assert config_hash(preset("paper")) == "9406eeccc05e551f"


class _Log:
    """A stand-in recording stream: what was logged where, at which frame."""

    def __init__(self) -> None:
        self.items: list[tuple[str, int | None, object]] = []
        self.t: int | None = None

    def log(self, path, item, static: bool = False) -> None:
        self.items.append((path, None if static else self.t, item))

    def at(self, t: int) -> None:
        self.t = t


@pytest.mark.full
def test_the_audit_record_keeps_the_readings_and_tracks_and_the_viewer_draws_them(synth_dir, scored_clip, tmp_path):
    from geocon_core.record import read_record, write_record
    from geocon_viewer.rerun.regions import log_regions

    clip = next(p for p in sorted(synth_dir.glob("*.mp4")) if "breathing" in p.name)
    record = scored_clip(clip, preset("audit"))
    part = record.regions
    assert part is not None and part.tracks is not None and len(part.tracks) > 100
    assert part.camera == record.background.model
    assert part.readings.values["breathing"] is not None
    # the stored tracks give the recorded readings again, with the record's camera
    assert read_regions_again(part, record.config.regions, record.config.seed).readings == part.readings
    write_record(record, tmp_path / "rec")
    back = read_record(tmp_path / "rec")
    assert back.regions is not None and back.regions.readings == part.readings
    assert np.array_equal(back.regions.tracks.xy, part.tracks.xy, equal_nan=True)
    assert "regions" in record.summary() and record.summary()["regions"]["tracks"] == part.readings.tracks
    log = _Log()
    assert log_regions(log, back, log.at)
    drawn = {path for path, _, _ in log.items}
    assert {f"frame/regions/{f.reading}" for f in part.readings.findings} <= drawn
    assert any(path.startswith("series/regions/") for path in drawn)
    paper = scored_clip(clip, preset("paper"))
    assert paper.regions is None
    log = _Log()
    assert not log_regions(log, paper, log.at)
    path, _, note = log.items[0]
    assert path == "frame/regions/note" and "off in the 'paper' preset" in str(note.text.as_arrow_array()[0])
