"""Headless screenshots of a Rerun recording: a solid colour filling a 2D view must show up as a large
area of that colour in the PNG, and the native viewer must show the frame it was asked for."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from geocon_viewer.screenshot import ScreenshotError, find_chromium, screenshot_native, screenshot_rrd, screenshot_web


def _colour_recording(path: Path) -> None:
    """Red on frames 0..4, blue on frames 5..9 of the ``frame`` timeline."""
    import rerun as rr
    import rerun.blueprint as rrb

    rec = rr.RecordingStream("geocon_screenshot_test")
    blueprint = rrb.Blueprint(rrb.Spatial2DView(origin="/image", name="colour"), collapse_panels=True)
    rec.save(path, default_blueprint=blueprint)
    for i in range(10):
        img = np.zeros((480, 640, 3), dtype=np.uint8)
        img[..., 0 if i < 5 else 2] = 255
        rec.set_time("frame", sequence=i)
        rec.log("image", rr.Image(img))
    rec.flush()
    rec.disconnect()


def _share(png: Path, channel: int) -> float:
    bgr = cv2.imread(str(png), cv2.IMREAD_COLOR)
    assert bgr is not None
    rgb = bgr[..., ::-1].astype(int)
    others = [c for c in range(3) if c != channel]
    return float(np.mean((rgb[..., channel] > 200) & (rgb[..., others[0]] < 60) & (rgb[..., others[1]] < 60)))


@pytest.fixture(scope="module")
def colour_rrd(tmp_path_factory) -> Path:
    rrd = tmp_path_factory.mktemp("shot") / "colour.rrd"
    _colour_recording(rrd)
    return rrd


@pytest.mark.slow
def test_web_screenshot_shows_image(colour_rrd: Path, tmp_path: Path) -> None:
    if find_chromium() is None:
        pytest.skip("Chromium is not installed")
    width, height = 800, 600
    out = screenshot_web(colour_rrd, tmp_path / "shot.png", width=width, height=height, settle_s=15.0)
    assert out == tmp_path / "shot.png"
    assert cv2.imread(str(out)).shape == (height, width, 3)
    # The web viewer follows the data as it streams in and stops on the last frame: blue.
    assert _share(out, 2) > 0.3 and _share(out, 0) < 0.01


@pytest.mark.slow
def test_native_screenshot_moves_the_time_cursor(colour_rrd: Path, tmp_path: Path) -> None:
    try:
        early = screenshot_native(colour_rrd, tmp_path / "early.png", at="frame@2")
    except ScreenshotError as exc:
        pytest.skip(f"no headless native viewer here: {exc}")
    late = screenshot_native(colour_rrd, tmp_path / "late.png", at="frame@7")
    assert _share(early, 0) > 0.2 and _share(early, 2) < 0.01
    assert _share(late, 2) > 0.2 and _share(late, 0) < 0.01


def test_bad_time_is_one_clear_error(colour_rrd: Path, tmp_path: Path) -> None:
    with pytest.raises(ScreenshotError, match="TIMELINE@INDEX"):
        screenshot_rrd(colour_rrd, tmp_path / "x.png", at="frame12")
