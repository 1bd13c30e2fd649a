"""Headless screenshots of Rerun ``.rrd`` recordings, as a user sees them.

Two ways, both on 127.0.0.1 only and always cleaned up:

- native (preferred): the ``rerun`` executable shipped in the rerun-sdk wheel runs ``--headless``
  (needs a Vulkan driver: a GPU's or Mesa's software one), ``rerun.experimental.ViewerClient`` opens
  the file, moves the time cursor and takes the screenshot;
- web (fallback): the same executable serves the recording and the web viewer, headless Chromium
  opens it and is driven through the DevTools protocol over ``--remote-debugging-pipe`` (no websocket
  library needed), and ``Page.captureScreenshot`` writes the PNG. Chromium resolves no host but
  127.0.0.1; its profile, config, cache and crash-report dirs live in one temp dir that is removed.

Every child runs in its own process group and is stopped with its group at the end.
"""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import tempfile
import time
from pathlib import Path
from typing import TypedDict, Unpack

from .chromium import capture, check_capture, find_chromium
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
    "ScreenshotError",
    "find_chromium",
    "find_rerun_binary",
    "screenshot_native",
    "screenshot_rrd",
    "screenshot_web",
    "screenshot_url",
]


WEB_TIMEOUT_S = 120.0
"""How long :func:`screenshot_web` waits by default, in seconds."""


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
    rrd: str | Path, png: str | Path, *, at: str | None = None, settle_s: float = 4.0, timeout_s: float = 90.0
) -> Path:
    """Screenshot ``rrd`` as the *native* viewer shows it, run headless (``rerun --headless``, 1920x1080):
    the viewer listens on 127.0.0.1 only, opens the file, moves the time cursor to ``at``
    (``TIMELINE@INDEX``) and saves the whole window as a PNG. Needs a Vulkan driver (a GPU's, or Mesa's
    software ``lavapipe`` from Debian ``mesa-vulkan-drivers``); raises ScreenshotError without one."""
    rrd_path = Path(rrd).resolve()
    png_path = Path(png)
    if not rrd_path.is_file():
        raise ScreenshotError(f"Recording {rrd_path} does not exist.")
    when = _parse_at(at)
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
                time.sleep(min(2.0, max(0.0, deadline - time.monotonic())))
            data = client.take_screenshot()
        except ScreenshotError:
            raise
        except Exception as exc:  # the client raises plain RuntimeErrors and timeouts
            tail = log_tail(log_path, 300)
            raise ScreenshotError(f"The headless viewer could not take the screenshot ({exc}). {tail}".strip()) from exc
        if not data.startswith(b"\x89PNG"):
            raise ScreenshotError("The headless viewer returned something that is not a PNG.")
        png_path.parent.mkdir(parents=True, exist_ok=True)
        png_path.write_bytes(data)
        return png_path
    finally:
        kill_group(proc)
        shutil.rmtree(workdir, ignore_errors=True)


class WebShot(TypedDict, total=False):
    """How :func:`screenshot_rrd` passes its web-viewer settings on to :func:`screenshot_web`."""

    at: str | None
    width: int
    height: int
    settle_s: float
    timeout_s: float


def screenshot_rrd(rrd: str | Path, png: str | Path, *, backend: str = "auto", **shot: Unpack[WebShot]) -> Path:
    """Screenshot ``rrd``: ``backend="native"`` (headless native viewer, needs Vulkan), ``"web"`` (the web
    viewer in headless Chromium, width x height) or ``"auto"`` (native, then web if that fails). ``shot``
    takes the keyword arguments of :func:`screenshot_web`."""
    if backend not in ("auto", "native", "web"):
        raise ScreenshotError(f"Unknown screenshot backend {backend!r}: use auto, native or web.")
    at = shot.get("at")
    _parse_at(at)
    if backend in ("auto", "native"):
        try:
            return screenshot_native(rrd, png, at=at, timeout_s=min(90.0, shot.get("timeout_s", WEB_TIMEOUT_S)))
        except ScreenshotError:
            if backend == "native" or find_chromium() is None:
                raise
    return screenshot_web(rrd, png, **shot)


def screenshot_web(
    rrd: str | Path,
    png: str | Path,
    *,
    at: str | None = None,
    width: int = 1600,
    height: int = 1000,
    settle_s: float = 20.0,
    timeout_s: float = WEB_TIMEOUT_S,
) -> Path:
    """Serve `rrd` with the `rerun` executable shipped in the rerun-sdk wheel (web viewer bound to 127.0.0.1,
    free ports), open it in headless Chromium (the web viewer takes no time cursor from its page URL, so
    ``at`` is accepted for symmetry and not applied: the viewer follows the data to its last frame), wait
    until the viewer has rendered (settle_s after load), save a
    PNG of width x height to `png` and return its path. Raises ScreenshotError (a RuntimeError subclass, with one
    clear sentence) when Chromium or the rerun executable is missing or the capture fails. Always cleans up both
    processes (including the real rerun binary behind any wrapper) and temp profile dirs."""
    rrd_path = Path(rrd).resolve()
    if not rrd_path.is_file():
        raise ScreenshotError(f"Recording {rrd_path} does not exist.")
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
        )
        _raise_on_import_error(rrd_path, rerun_log)
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
