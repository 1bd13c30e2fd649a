"""Opening a recording: the native Rerun viewer when a display is available, otherwise the web
viewer served by the ``rerun`` executable on 127.0.0.1 (never on all interfaces)."""

from __future__ import annotations

import contextlib
import socket
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Callable

from ..capture import ScreenshotError, find_rerun_binary, free_port, kill_group, start_rerun

__all__ = ["open_native", "serve_web"]


def _binary() -> str:
    exe = find_rerun_binary()
    if exe is None:
        raise RuntimeError(
            "the rerun executable was not found: install the viewer extra (pip install 'geocon[viewer]')"
        )
    return exe


def open_native(rrd: Path, *, frame: int | None = None, timeout_s: float = 20.0) -> subprocess.Popen:
    """Start the native viewer on ``rrd`` (its server bound to 127.0.0.1 on a free port) and return
    once it shows the recording, with the time cursor on ``frame`` when given (best effort: an
    older viewer simply opens at the start). The viewer keeps running after this process ends."""
    port = free_port()
    cmd = [_binary(), "--bind", "127.0.0.1", "--port", str(port), str(Path(rrd).resolve())]
    proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, start_new_session=True)
    if frame is None:
        return proc
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and proc.poll() is None:
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=1):
                break
        except OSError:
            time.sleep(0.2)
    with contextlib.suppress(Exception):  # the cursor is a convenience; the viewer is already open
        from rerun.experimental import ViewerClient

        time.sleep(1.0)
        ViewerClient.connect(f"rerun+http://127.0.0.1:{port}/proxy").set_time(
            "frame", sequence=int(frame), play_state="paused"
        )
    return proc


def serve_web(rrd: Path, *, announce: Callable[[str], None], timeout_s: float = 60.0) -> None:
    """Serve ``rrd`` and the web viewer on 127.0.0.1 (free ports), announce the address, and
    keep serving until interrupted (Ctrl-C)."""
    with tempfile.TemporaryDirectory(prefix="geocon-serve-") as tmp:
        try:
            proc, url, _ = start_rerun(_binary(), Path(rrd).resolve(), Path(tmp), time.monotonic() + timeout_s)
        except ScreenshotError as exc:
            raise RuntimeError(str(exc)) from None
        try:
            announce(url)
            while proc.poll() is None:
                time.sleep(0.5)
        except KeyboardInterrupt:
            pass
        finally:
            kill_group(proc)
