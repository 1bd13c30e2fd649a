"""Headless screenshots of a Rerun recording: a solid colour filling a 2D view must show up as a large
area of that colour in the PNG, and the native viewer must show the frame it was asked for;
`geocon view --screenshot` waits until the frame panel shows the decoded video (the readiness
decision is checked on drawn screenshots: a blank panel, loading dots, a textured frame)."""

from __future__ import annotations

import logging
import re
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from geocon_core.files import stamp_png
from geocon_viewer.capture import screenshot
from geocon_viewer.capture.screenshot import (
    MIN_SHARE,
    ScreenshotError,
    find_chromium,
    find_frame,
    poll_until_ready,
    screenshot_native,
    screenshot_rrd,
    screenshot_web,
    shot_ready,
)


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
    # a solid colour is an image but not a video frame: wait for any image
    out = screenshot_web(colour_rrd, tmp_path / "shot.png", wait_for="image", width=width, height=height)
    assert out == tmp_path / "shot.png"
    assert cv2.imread(str(out)).shape == (height, width, 3)
    # The web viewer follows the data as it streams in and stops on the last frame: blue.
    assert _share(out, 2) > 0.3 and _share(out, 0) < 0.01


@pytest.mark.slow
def test_native_screenshot_moves_the_time_cursor(colour_rrd: Path, tmp_path: Path) -> None:
    try:
        early = screenshot_native(colour_rrd, tmp_path / "early.png", at="frame@2", wait_for="image")
    except ScreenshotError as exc:
        pytest.skip(f"no headless native viewer here: {exc}")
    late = screenshot_native(colour_rrd, tmp_path / "late.png", at="frame@7", wait_for="image")
    assert _share(early, 0) > 0.2 and _share(early, 2) < 0.01
    assert _share(late, 2) > 0.2 and _share(late, 0) < 0.01


def test_bad_time_is_one_clear_error(colour_rrd: Path, tmp_path: Path) -> None:
    with pytest.raises(ScreenshotError, match="TIMELINE@INDEX"):
        screenshot_rrd(colour_rrd, tmp_path / "x.png", at="frame12")


# --- waiting for the decoded video ---------------------------------------------------------------

W, H = 1600, 1000
PANELS = [(0, 533), (534, 1066), (1067, 1600)]  # the audit layout's top row: three 2D views
TOP, BOTTOM = 60, 595  # their image areas, below the title bars


def _viewer(rng: np.random.Generator) -> np.ndarray:
    """A drawn screenshot of the audit layout before any frame is decoded: the white background,
    grey panel borders, title text, and matches (green points) and a mask (a flat pastel disc)
    floating over the empty frame panel."""
    img = np.full((H, W, 3), 255, np.uint8)
    img[30, :] = 223
    img[TOP - 1, :] = 223
    img[BOTTOM, :] = 223
    for x0, _ in PANELS[1:]:
        img[30:, x0 - 1] = 223
    for x0, _ in PANELS:
        cv2.putText(img, "Frame + background matches", (x0 + 8, 50), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (40, 40, 40), 1)
    cv2.putText(img, "Audit card: verdict, gate", (1200, 700), cv2.FONT_HERSHEY_SIMPLEX, 0.9, (0, 0, 0), 2)
    cv2.circle(img, (150, 330), 45, (213, 220, 255), -1)
    for x, y in zip(rng.integers(20, 510, 1500), rng.integers(180, 480, 1500), strict=True):
        cv2.circle(img, (int(x), int(y)), 3, (30, 160, 60), -1)
    return img


def _dots(img: np.ndarray, phase: int) -> np.ndarray:
    """Rerun's loading indicator in the middle of each panel: three dots, one of them dark."""
    out = img.copy()
    for x0, x1 in PANELS:
        cx, cy = (x0 + x1) // 2, (TOP + BOTTOM) // 2
        for k in range(3):
            grey = 20 if k == phase % 3 else 140
            cv2.circle(out, (cx - 12 + 12 * k, cy), 4, (grey, grey, grey), -1)
    return out


def _video_frame(rng: np.random.Generator, w: int, h: int) -> np.ndarray:
    """A textured picture like a decoded video frame: smooth colour noise and shapes."""
    frame = cv2.resize(rng.integers(0, 256, (h // 16, w // 16, 3), dtype=np.uint8), (w, h), cv2.INTER_CUBIC)
    for _ in range(60):
        c = tuple(int(v) for v in rng.integers(0, 256, 3))
        cv2.circle(frame, (int(rng.integers(0, w)), int(rng.integers(0, h))), int(rng.integers(4, 25)), c, -1)
    return frame


def _with_frames(img: np.ndarray, frame: np.ndarray, panels: list[int]) -> np.ndarray:
    out = img.copy()
    h, w = frame.shape[:2]
    for i in panels:
        x0 = PANELS[i][0] + (PANELS[i][1] - PANELS[i][0] - w) // 2
        y0 = (TOP + BOTTOM - h) // 2
        out[y0 : y0 + h, x0 : x0 + w] = frame
    return out


def test_blank_panels_and_loading_dots_are_not_ready() -> None:
    rng = np.random.default_rng(0)
    blank = _viewer(rng)
    found = find_frame(blank)
    assert found.background == (255, 255, 255) and found.share < MIN_SHARE  # points, text, a mask: no image
    assert shot_ready(blank, blank) == "no 2D view shows an image yet"
    assert shot_ready(_dots(blank, 1), _dots(blank, 0)) == "no 2D view shows an image yet"
    page = np.full((H, W, 3), (13, 16, 17), np.uint8)  # the page while the viewer's wasm loads
    assert shot_ready(page, page) == "no 2D view shows an image yet"


def test_a_textured_frame_twice_in_a_row_is_ready() -> None:
    rng = np.random.default_rng(1)
    blank = _viewer(rng)
    frame = _video_frame(rng, 520, 292)
    shown = _with_frames(blank, frame, [0, 1, 2])
    found = find_frame(shown)
    assert found.box is not None and found.share > 0.08 and found.texture > 10
    x0, y0, x1, y1 = found.box
    assert abs((x1 - x0) - 520) <= 2 and abs((y1 - y0) - 292) <= 2  # the frame itself, not its panel
    assert shot_ready(shown, shown.copy()) is None
    assert shot_ready(shown, None) == "the viewer had not yet shown the same picture twice"
    # one panel decoded, the others still showing animated loading dots: not yet
    partly = _with_frames(blank, frame, [0])
    assert "still changing" in str(shot_ready(_dots(partly, 2), _dots(partly, 1)))
    # another frame (the viewer still moving through the video): not yet
    other = _with_frames(blank, _video_frame(rng, 520, 292), [0, 1, 2])
    assert "still changing" in str(shot_ready(other, shown))


def test_a_flat_image_is_an_image_but_not_a_video_frame() -> None:
    rng = np.random.default_rng(2)
    blank = _viewer(rng)
    flat = _with_frames(blank, np.full((292, 520, 3), (213, 220, 255), np.uint8), [0])  # e.g. a mask over nothing
    assert find_frame(flat).share > MIN_SHARE and find_frame(flat).texture == 0
    assert "not a decoded video frame" in str(shot_ready(flat, flat))
    assert shot_ready(flat, flat, "image") is None
    with pytest.raises(ValueError, match="video"):
        shot_ready(flat, flat, "frames")  # type: ignore[arg-type]


def _png(rgb: np.ndarray) -> bytes:
    ok, data = cv2.imencode(".png", rgb[..., ::-1])
    assert ok
    return data.tobytes()


def test_polling_stops_at_the_first_ready_screenshot_and_times_out_with_the_reason() -> None:
    rng = np.random.default_rng(3)
    blank = _viewer(rng)
    frame = _video_frame(rng, 520, 292)
    partly, shown = _with_frames(blank, frame, [0]), _with_frames(blank, frame, [0, 1, 2])
    shots = [_png(s) for s in (blank, _dots(blank, 0), _dots(partly, 1), _dots(partly, 2), shown, shown, blank)]
    taken: list[bytes] = []

    def take() -> bytes:
        taken.append(shots[len(taken)])
        return taken[-1]

    data, n = poll_until_ready(take, wait_for="video", deadline=time.monotonic() + 30, what="clip.rrd", poll_s=0)
    assert n == 6 and data == shots[5]
    never = "^Screenshot of clip\\.rrd timed out: no 2D view shows an image yet\\.$"
    with pytest.raises(ScreenshotError, match=never):
        poll_until_ready(
            lambda: shots[0], wait_for="video", deadline=time.monotonic() + 0.3, what="clip.rrd", poll_s=0.05
        )


def test_native_path_polls_the_viewer_until_the_frame_is_shown(tmp_path: Path, monkeypatch, caplog) -> None:
    """The native path's wiring without a Vulkan driver: a stand-in ``rerun`` that only listens on its
    port, and a stand-in viewer client whose screenshots go from blank to a decoded frame."""
    pytest.importorskip("rerun")
    import sys

    import rerun.experimental

    fake_rerun = tmp_path / "rerun"
    fake_rerun.write_text(
        f"#!{sys.executable}\n"
        "import socket, sys, time\n"
        "port = int(sys.argv[sys.argv.index('--port') + 1])\n"
        "s = socket.socket(); s.bind(('127.0.0.1', port)); s.listen(); time.sleep(60)\n"
    )
    fake_rerun.chmod(0o755)
    monkeypatch.setenv("RERUN_CLI_PATH", str(fake_rerun))
    rng = np.random.default_rng(4)
    blank = _viewer(rng)
    frame = _video_frame(rng, 520, 292)
    partly, shown = _with_frames(blank, frame, [0]), _with_frames(blank, frame, [0, 1, 2])
    shots = [_png(s) for s in (blank, _dots(partly, 0), _dots(partly, 1), shown, shown)]
    calls: list[tuple] = []

    class FakeClient:
        @classmethod
        def connect(cls, url: str) -> FakeClient:
            assert url.startswith("rerun+http://127.0.0.1:")
            return cls()

        def open(self, path: str) -> None:
            calls.append(("open", Path(path).name))

        def set_time(self, timeline: str, *, sequence: int, play_state: str) -> None:
            calls.append(("set_time", timeline, sequence, play_state))

        def take_screenshot(self) -> bytes:
            calls.append(("shot",))
            return shots[sum(c[0] == "shot" for c in calls) - 1]

    monkeypatch.setattr(rerun.experimental, "ViewerClient", FakeClient)
    monkeypatch.setattr(screenshot, "POLL_S", 0.01)
    rrd = tmp_path / "clip.rrd"
    rrd.write_bytes(b"not read by the stand-ins")
    with caplog.at_level(logging.INFO, logger="geocon_viewer.capture.screenshot"):
        out = screenshot_native(rrd, tmp_path / "native.png", at="frame@3", settle_s=0.0, timeout_s=30.0)
    assert out.read_bytes() == stamp_png(shots[4])  # the second screenshot of the shown frame, stamped as GeoCon's
    assert calls[:2] == [("open", "clip.rrd"), ("set_time", "frame", 3, "paused")] and len(calls) == 2 + 5
    assert any("clip.rrd (native viewer): the viewer showed a video frame after" in m for m in caplog.messages)


@pytest.fixture(scope="module")
def small_record(synth_clips, tmp_path_factory) -> Path:
    """The record of a short 320x180 synthetic clip with moving objects (masks, matches, flow)."""
    from typer.testing import CliRunner

    from geocon_core.synth import ClipPlan
    from geocon_viewer.cli import app

    clip = synth_clips([ClipPlan("C4")], seed=3, width=320, height=180, num_frames=8) / "c4_objects.mp4"
    rec = tmp_path_factory.mktemp("shot-record") / "rec"
    res = CliRunner().invoke(app, ["score", str(clip), "--masks", str(clip.with_suffix(".masks")), "--out", str(rec)])
    assert res.exit_code == 0, res.output
    return rec


@pytest.mark.slow
def test_view_screenshot_shows_the_decoded_frame(small_record: Path, tmp_path: Path, caplog) -> None:
    """`geocon view --screenshot` saves the frame panel with the video in it, not the empty panel with
    matches and masks floating over the viewer background (about 25-40 s on 2 cores, web viewer)."""
    if find_chromium() is None:
        pytest.skip("Chromium is not installed")
    from typer.testing import CliRunner

    from geocon_viewer.cli import app

    png = tmp_path / "view.png"
    started = time.monotonic()
    with caplog.at_level(logging.INFO, logger="geocon_viewer.capture.screenshot"):
        res = CliRunner().invoke(app, ["view", str(small_record), "--screenshot", str(png)])
    took = time.monotonic() - started
    assert res.exit_code == 0, res.output
    waited = [m for m in caplog.messages if "the viewer showed a video frame after" in m]
    assert waited, caplog.messages
    print(f"\ngeocon view --screenshot: {took:.1f} s in all; {waited[-1]}")
    assert float(re.findall(r"after ([0-9.]+) s", waited[-1])[0]) <= took

    rgb = cv2.imread(str(png))[..., ::-1].astype(np.float64)
    h, w = rgb.shape[:2]
    assert (h, w) == (1000, 1600)
    # the audit layout: the frame panel is the left third of the top row; a 16:9 frame spans most of its
    # width, so the middle of the panel is frame and the strip under its title bar is background. The
    # variance alone cannot tell: matches drawn densely over an empty panel vary as much as a frame.
    panel_middle = rgb[int(0.26 * h) : int(0.42 * h), int(0.08 * w) : int(0.25 * w)]
    background = rgb[int(0.07 * h) : int(0.12 * h), int(0.02 * w) : int(0.31 * w)]
    values, counts = np.unique(rgb.reshape(-1, 3), axis=0, return_counts=True)
    bg_colour = values[np.argmax(counts)]
    off_background = np.abs(panel_middle - bg_colour).max(axis=-1) > 24
    assert off_background.mean() > 0.95, "the frame panel shows the viewer background, not a frame"
    grey_var = panel_middle.mean(axis=-1).var()
    assert background.mean(axis=-1).var() < 4.0, "the strip under the title bar is flat background"
    assert grey_var > 100.0, f"the frame panel has the variance of a flat colour ({grey_var:.1f}), not of a frame"


@pytest.mark.slow
def test_no_video_is_one_sentence_after_the_timeout(tmp_path: Path) -> None:
    """A recording without any image: the web viewer never shows a frame, and the wait ends in time."""
    if find_chromium() is None:
        pytest.skip("Chromium is not installed")
    import rerun as rr

    rrd = tmp_path / "series.rrd"
    rec = rr.RecordingStream("geocon_screenshot_no_video")
    rec.save(rrd)
    for i in range(5):
        rec.set_time("frame", sequence=i)
        rec.log("series/x", rr.Scalars(float(i)))
    rec.flush()
    rec.disconnect()
    started = time.monotonic()
    with pytest.raises(ScreenshotError, match=r"^Screenshot of series\.rrd timed out: no 2D view shows an image"):
        screenshot_web(rrd, tmp_path / "x.png", width=800, height=600, timeout_s=20.0)
    assert time.monotonic() - started < 20.0 + 15.0  # the timeout, plus stopping Chromium and rerun
    assert not (tmp_path / "x.png").exists()
