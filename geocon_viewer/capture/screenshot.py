"""Headless screenshots of Rerun ``.rrd`` recordings, as a user sees them.

Two ways, both on 127.0.0.1 only and always cleaned up:

- native (preferred): the ``rerun`` executable shipped in the rerun-sdk wheel runs ``--headless``
  (needs a Vulkan driver: a GPU's or Mesa's software one), ``rerun.experimental.ViewerClient`` opens
  the file, moves the time cursor and takes the screenshot;
- web (fallback): the same executable serves the recording and the web viewer, headless Chromium
  opens it and is driven through the DevTools protocol over ``--remote-debugging-pipe`` (no websocket
  library needed), and ``Page.captureScreenshot`` writes the PNG. Chromium resolves no host but
  127.0.0.1; its profile, config, cache and crash-report dirs live in one temp dir that is removed.

Neither viewer says when it has decoded the video, so both paths take screenshots until one is ready
(:func:`poll_until_ready`): the largest image in a 2D view must be a textured picture, not the flat
viewer background with matches and masks floating on it (:func:`find_frame`), and the screenshot must
equal the one before (loading dots animate). The time it took is logged on the ``geocon_viewer.capture.screenshot``
logger at INFO.

Every child runs in its own process group and is stopped with its group at the end.
"""

from __future__ import annotations

import logging
import os
import shutil
import socket
import subprocess
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Literal, TypedDict, Unpack

import cv2
import numpy as np

from .chromium import capture, check_capture, find_chromium, save_png
from .processes import (
    ScreenshotError,
    find_rerun_binary,
    free_port,
    kill_group,
    log_tail,
    private_env,
    rerun_import_error,
    start_rerun,
)

__all__ = [
    "FrameCheck",
    "ScreenshotError",
    "WaitFor",
    "find_chromium",
    "find_frame",
    "find_rerun_binary",
    "poll_until_ready",
    "screenshot_native",
    "screenshot_rrd",
    "screenshot_web",
    "screenshot_url",
    "shot_ready",
]

logger = logging.getLogger(__name__)


WEB_TIMEOUT_S = 120.0
"""How long :func:`screenshot_web` waits by default, in seconds."""


WaitFor = Literal["video", "image"]
"""What a screenshot waits for: ``"video"`` (the largest image in a 2D view is a textured picture, as
a decoded video frame is) or ``"image"`` (any opaque image, flat colours included)."""

MIN_WEB_S = 30.0
""":func:`screenshot_rrd` tries the web viewer after the native one only with at least this much time left."""
POLL_S = 0.5
"""Pause between two screenshots while waiting for the viewer, in seconds."""
MIN_SHARE = 0.02
"""The smallest share of the screenshot the largest image in a 2D view must cover. A frame panel of the
audit layout shows a frame over about a tenth of the window; masks and the toasts of the welcome page
cover less than 1.5 %."""
MIN_TEXTURE = 3.0
"""The smallest texture (median absolute deviation of a channel, grey levels) of a video frame. The flat
background, masks and content-box bands are uniform (0), also where matches are drawn over them."""
BACKGROUND_TOL = 12
"""How far (grey levels, in any channel) a pixel must be from the viewer background to count as drawn."""
STABLE_TOL = 8
"""A pixel has changed between two screenshots when a channel moved by more than this (grey levels)."""
STABLE_PIXELS = 16
"""Two screenshots are the same when at most this many pixels changed (a loading dot alone is more)."""


@dataclass(frozen=True)
class FrameCheck:
    """The largest opaque image in a screenshot: ``box`` (x0, y0, x1, y1, pixels, exclusive ends; None
    when nothing is drawn), ``share`` (its area over the screenshot's), ``texture`` (the largest
    median absolute deviation of its pixels over the R, G, B channels, grey levels) and ``background``
    (the viewer's background colour, RGB: the screenshot's most common colour)."""

    box: tuple[int, int, int, int] | None
    share: float
    texture: float
    background: tuple[int, int, int]


def _background(rgb: np.ndarray) -> np.ndarray:
    """The most common colour of ``rgb`` (H, W, 3 uint8), from every 4th pixel each way."""
    sub = rgb[::4, ::4].reshape(-1, 3).astype(np.uint32)
    packed = (sub[:, 0] << 16) | (sub[:, 1] << 8) | sub[:, 2]
    values, counts = np.unique(packed, return_counts=True)
    top = int(values[np.argmax(counts)])
    return np.array([(top >> 16) & 255, (top >> 8) & 255, top & 255], np.uint8)


def _difference(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The largest absolute difference over the channels of two (H, W, 3) uint8 images: (H, W) uint8."""
    d = cv2.absdiff(np.ascontiguousarray(a), np.ascontiguousarray(b))
    return np.maximum(np.maximum(d[..., 0], d[..., 1]), d[..., 2])


def find_frame(rgb: np.ndarray) -> FrameCheck:
    """Find the largest opaque image in a viewer screenshot ``rgb`` (H, W, 3 uint8, RGB).

    Pixels farther than :data:`BACKGROUND_TOL` from the background colour are "drawn"; a morphological
    opening (a square about 1.2 % of the shorter side) removes what is thin or small (match points and
    lines, text, panel borders, loading dots), and the largest connected region left is the image. In
    the audit layout that is a frame panel's video frame once decoded, or nothing before."""
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        raise ValueError(f"find_frame needs an (H, W, 3) uint8 image, got {rgb.shape} {rgb.dtype}")
    h, w = rgb.shape[:2]
    bg = _background(rgb)
    background = (int(bg[0]), int(bg[1]), int(bg[2]))
    flat = np.empty_like(rgb)
    flat[:] = bg
    drawn = (_difference(rgb, flat) > BACKGROUND_TOL).astype(np.uint8)
    k = max(5, round(0.012 * min(h, w)))
    solid = cv2.morphologyEx(drawn, cv2.MORPH_OPEN, np.ones((k, k), np.uint8))
    n, labels, stats, _ = cv2.connectedComponentsWithStats(solid, connectivity=4)
    if n <= 1:
        return FrameCheck(None, 0.0, 0.0, background)
    i = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    x, y, bw, bh, area = (int(v) for v in stats[i])
    px = rgb[labels == i].astype(np.float32)
    texture = float(np.max(np.median(np.abs(px - np.median(px, axis=0)), axis=0)))
    return FrameCheck((x, y, x + bw, y + bh), area / (h * w), texture, background)


def shot_ready(rgb: np.ndarray, previous: np.ndarray | None, wait_for: WaitFor = "video") -> str | None:
    """None when the screenshot ``rgb`` (H, W, 3 uint8) shows what ``wait_for`` asks for and equals
    ``previous`` (the screenshot before it, or None for the first); otherwise why not, in a few words."""
    if wait_for not in ("video", "image"):
        raise ValueError(f"wait_for must be 'video' or 'image', got {wait_for!r}")
    found = find_frame(rgb)
    if found.share < MIN_SHARE:
        return "no 2D view shows an image yet"
    if wait_for == "video" and found.texture < MIN_TEXTURE:
        return "the largest image in a 2D view is flat, not a decoded video frame"
    if previous is None or previous.shape != rgb.shape:
        return "the viewer had not yet shown the same picture twice"
    changed = int(np.count_nonzero(_difference(rgb, previous) > STABLE_TOL))
    if changed > STABLE_PIXELS:
        return f"the viewer was still changing ({changed} pixels between two screenshots)"
    return None


def _decode_png(data: bytes) -> np.ndarray:
    bgr = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    if bgr is None:
        raise ScreenshotError("The viewer returned a screenshot that is not a readable PNG.")
    return np.ascontiguousarray(bgr[..., ::-1])


def poll_until_ready(
    take: Callable[[], bytes],
    *,
    wait_for: WaitFor,
    deadline: float,
    what: str,
    poll_s: float = POLL_S,
) -> tuple[bytes, int]:
    """Call ``take()`` (a PNG of the viewer) every ``poll_s`` until :func:`shot_ready` accepts a
    screenshot; return it and how many were taken. Raises ScreenshotError naming the last reason when
    ``deadline`` (a :func:`time.monotonic` time) passes first."""
    previous: np.ndarray | None = None
    reason = "no screenshot was taken"
    taken = 0
    while True:
        if time.monotonic() >= deadline:
            raise ScreenshotError(f"Screenshot of {what} timed out: {reason}.")
        try:
            data = take()
        except ScreenshotError as exc:
            if time.monotonic() < deadline:
                raise
            raise ScreenshotError(f"Screenshot of {what} timed out: {reason}.") from exc
        taken += 1
        rgb = _decode_png(data)
        found = shot_ready(rgb, previous, wait_for)
        logger.debug("%s: screenshot %d: %s", what, taken, found or "ready")
        if found is None:
            return data, taken
        reason, previous = found, rgb
        time.sleep(max(0.0, min(poll_s, deadline - time.monotonic())))


def _check_wait_for(wait_for: str) -> None:
    if wait_for not in ("video", "image"):
        raise ScreenshotError(f"A screenshot waits for 'video' or 'image', got {wait_for!r}.")


def _log_ready(what: str, wait_for: WaitFor, started: float, taken: int) -> None:
    shown = "a video frame" if wait_for == "video" else "an image"
    elapsed = time.monotonic() - started
    logger.info("%s: the viewer showed %s after %.1f s (%d screenshots)", what, shown, elapsed, taken)


def _raise_on_import_error(rrd: Path, rerun_log: Path) -> None:
    problem = rerun_import_error(rerun_log)
    if problem is not None:
        raise ScreenshotError(f"The rerun executable could not load {rrd.name}: {problem}")


def _parse_at(at: str | None) -> tuple[str, int] | None:
    if at is None:
        return None
    timeline, sep, value = at.partition("@")
    if not sep or not timeline or not value.lstrip("-").isdigit():
        raise ScreenshotError(f"The time to show must read TIMELINE@INDEX (e.g. frame@12), got {at!r}.")
    return timeline, int(value)


def screenshot_native(
    rrd: str | Path,
    png: str | Path,
    *,
    at: str | None = None,
    wait_for: WaitFor = "video",
    settle_s: float = 4.0,
    timeout_s: float = 90.0,
) -> Path:
    """Screenshot ``rrd`` as the *native* viewer shows it, run headless (``rerun --headless``, 1920x1080):
    the viewer listens on 127.0.0.1 only, opens the file, moves the time cursor to ``at``
    (``TIMELINE@INDEX``) ``settle_s`` later, takes screenshots until one shows what ``wait_for`` asks
    for (:func:`shot_ready`) and saves it as a PNG, all within ``timeout_s``. Needs a Vulkan driver (a
    GPU's, or Mesa's software ``lavapipe`` from Debian ``mesa-vulkan-drivers``); raises ScreenshotError
    without one, and when no ready screenshot comes in time."""
    started = time.monotonic()
    rrd_path = Path(rrd).resolve()
    png_path = Path(png)
    if not rrd_path.is_file():
        raise ScreenshotError(f"Recording {rrd_path} does not exist.")
    when = _parse_at(at)
    _check_wait_for(wait_for)
    rerun_bin = find_rerun_binary()
    if rerun_bin is None:
        raise ScreenshotError("The rerun executable (rerun_cli/rerun from the rerun-sdk wheel) was not found.")
    from rerun.experimental import ViewerClient

    deadline = time.monotonic() + timeout_s
    workdir = Path(tempfile.mkdtemp(prefix="geocon-rrdshot-"))
    log_path = workdir / "rerun-native.log"
    port = free_port()
    env = private_env(workdir, RERUN_ANALYTICS="0", RUST_LOG=os.environ.get("RUST_LOG", "warn"))
    env.pop("RERUN_CLI_PATH", None)
    cmd = [rerun_bin, "--headless", "--bind", "127.0.0.1", "--port", str(port), "--hide-welcome-screen"]
    proc: subprocess.Popen[bytes] | None = None
    try:
        with open(log_path, "wb") as log:
            proc = subprocess.Popen(
                cmd, stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT, env=env, start_new_session=True
            )
        while True:
            if proc.poll() is not None:
                raise ScreenshotError(
                    f"The headless viewer exited with code {proc.returncode}: {log_tail(log_path, 300)}"
                )
            try:
                with socket.create_connection(("127.0.0.1", port), timeout=1):
                    break
            except OSError:
                if time.monotonic() > deadline:
                    raise ScreenshotError("The headless viewer did not start listening in time.") from None
                time.sleep(0.2)
        try:
            client = ViewerClient.connect(f"rerun+http://127.0.0.1:{port}/proxy")
            client.open(str(rrd_path))
            time.sleep(min(settle_s, max(0.0, deadline - time.monotonic())))
            if when is not None:
                client.set_time(when[0], sequence=when[1], play_state="paused")

            def take() -> bytes:
                if proc is not None and proc.poll() is not None:
                    raise ScreenshotError(f"The headless viewer exited with code {proc.returncode}.")
                shot = client.take_screenshot()
                if not shot.startswith(b"\x89PNG"):
                    raise ScreenshotError("The headless viewer returned something that is not a PNG.")
                return bytes(shot)

            data, taken = poll_until_ready(
                take, wait_for=wait_for, deadline=deadline, what=rrd_path.name, poll_s=POLL_S
            )
        except ScreenshotError:
            raise
        except Exception as exc:  # the client raises plain RuntimeErrors and timeouts
            tail = log_tail(log_path, 300)
            raise ScreenshotError(f"The headless viewer could not take the screenshot ({exc}). {tail}".strip()) from exc
        save_png(data, png_path)
        _log_ready(f"{rrd_path.name} (native viewer)", wait_for, started, taken)
        return png_path
    finally:
        kill_group(proc)
        shutil.rmtree(workdir, ignore_errors=True)


class WebShot(TypedDict, total=False):
    """How :func:`screenshot_rrd` passes its web-viewer settings on to :func:`screenshot_web`."""

    at: str | None
    wait_for: WaitFor
    width: int
    height: int
    settle_s: float
    timeout_s: float


def screenshot_rrd(rrd: str | Path, png: str | Path, *, backend: str = "auto", **shot: Unpack[WebShot]) -> Path:
    """Screenshot ``rrd``: ``backend="native"`` (headless native viewer, needs Vulkan), ``"web"`` (the web
    viewer in headless Chromium, width x height) or ``"auto"`` (native, then web if that fails, in what
    is left of ``timeout_s``). ``shot`` takes the keyword arguments of :func:`screenshot_web`; both wait
    until a 2D view shows a decoded video frame (``wait_for``) or raise ScreenshotError."""
    if backend not in ("auto", "native", "web"):
        raise ScreenshotError(f"Unknown screenshot backend {backend!r}: use auto, native or web.")
    started = time.monotonic()
    at = shot.get("at")
    _parse_at(at)
    _check_wait_for(shot.get("wait_for", "video"))
    timeout_s = shot.get("timeout_s", WEB_TIMEOUT_S)
    if backend in ("auto", "native"):
        try:
            return screenshot_native(
                rrd, png, at=at, wait_for=shot.get("wait_for", "video"), timeout_s=min(90.0, timeout_s)
            )
        except ScreenshotError:
            left = timeout_s - (time.monotonic() - started)
            if backend == "native" or find_chromium() is None or left < MIN_WEB_S:
                raise
            shot = {**shot, "timeout_s": left}
    return screenshot_web(rrd, png, **shot)


def screenshot_web(
    rrd: str | Path,
    png: str | Path,
    *,
    at: str | None = None,
    wait_for: WaitFor = "video",
    width: int = 1600,
    height: int = 1000,
    settle_s: float = 2.0,
    timeout_s: float = WEB_TIMEOUT_S,
) -> Path:
    """Serve `rrd` with the `rerun` executable shipped in the rerun-sdk wheel (web viewer bound to 127.0.0.1,
    free ports), open it in headless Chromium (the web viewer takes no time cursor from its page URL, so
    ``at`` is accepted for symmetry and not applied: a recording with the stored layout, which pauses
    the timeline, shows its first frame), and
    from ``settle_s`` after the page has loaded take screenshots until one shows what ``wait_for`` asks
    for (:func:`shot_ready`: by default a decoded video frame, the same in two screenshots in a row); save
    it (width x height) to `png` and return its path. Raises ScreenshotError (a RuntimeError subclass, with
    one clear sentence) when Chromium or the rerun executable is missing, the capture fails or no ready
    screenshot comes within ``timeout_s``. Always cleans up both processes (including the real rerun binary
    behind any wrapper) and temp profile dirs."""
    started = time.monotonic()
    rrd_path = Path(rrd).resolve()
    if not rrd_path.is_file():
        raise ScreenshotError(f"Recording {rrd_path} does not exist.")
    _check_wait_for(wait_for)
    check_capture(width, height, settle_s, timeout_s)
    rerun_bin = find_rerun_binary()
    if rerun_bin is None:
        raise ScreenshotError("The rerun executable (rerun_cli/rerun from the rerun-sdk wheel) was not found.")
    deadline = time.monotonic() + timeout_s
    workdir = Path(tempfile.mkdtemp(prefix="geocon-rrdshot-"))
    rerun_proc: subprocess.Popen[bytes] | None = None
    try:
        rerun_proc, viewer_url, rerun_log = start_rerun(rerun_bin, rrd_path, workdir, deadline)
        # The web viewer has no way to take a time cursor from its page URL: ``at`` is not applied here.
        _raise_on_import_error(rrd_path, rerun_log)

        def alive() -> None:
            if rerun_proc is not None and rerun_proc.poll() is not None:
                raise ScreenshotError(f"The rerun server exited early with code {rerun_proc.returncode}.")

        taken = 0

        def wait(take: Callable[[], bytes]) -> bytes:
            nonlocal taken
            data, taken = poll_until_ready(
                take, wait_for=wait_for, deadline=deadline, what=rrd_path.name, poll_s=POLL_S
            )
            return data

        capture(
            viewer_url,
            Path(png),
            workdir,
            width=width,
            height=height,
            settle_s=settle_s,
            deadline=deadline,
            what=rrd_path.name,
            alive=alive,
            wait=wait,
        )
        _raise_on_import_error(rrd_path, rerun_log)
        _log_ready(f"{rrd_path.name} (web viewer)", wait_for, started, taken)
        return Path(png)
    finally:
        kill_group(rerun_proc)
        shutil.rmtree(workdir, ignore_errors=True)


def screenshot_url(
    url: str, png: str | Path, *, width: int = 1600, height: int = 1000, settle_s: float = 8.0, timeout_s: float = 90.0
) -> Path:
    """Open ``url`` (a page served on this machine, e.g. ``geocon serve``) in headless Chromium, wait
    ``settle_s`` after it loads, and save a PNG of width x height to ``png``. Raises ScreenshotError
    with one clear sentence when Chromium is missing or the capture fails; cleans up after itself."""
    check_capture(width, height, settle_s, timeout_s)
    deadline = time.monotonic() + timeout_s
    workdir = Path(tempfile.mkdtemp(prefix="geocon-pageshot-"))
    try:
        capture(url, Path(png), workdir, width=width, height=height, settle_s=settle_s, deadline=deadline, what=url)
        return Path(png)
    finally:
        shutil.rmtree(workdir, ignore_errors=True)
