"""Headless Chromium driven through the DevTools protocol over ``--remote-debugging-pipe`` (no
websocket library needed): open a page on this machine, wait for it to render (a fixed time, or
screenshots taken until the caller finds one ready), capture a PNG.
Chromium resolves no host but 127.0.0.1 and runs without a crash reporter, so every process it
starts stays in its process group and goes with it (:func:`~geocon_viewer.capture.processes.kill_group`)."""

from __future__ import annotations

import base64
import contextlib
import json
import os
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any, Callable

from .processes import ScreenshotError, kill_group, log_tail, private_env

__all__ = ["Page", "find_chromium", "start_chromium", "check_capture", "capture", "open_page", "save_png"]


def save_png(data: bytes, png_path: Path) -> None:
    """Save the screenshot ``data`` at ``png_path``, stamped as GeoCon's (its ``tEXt`` chunk, so a
    later screenshot may replace it, :func:`geocon_core.files.claim`), written beside its place and
    renamed into it (never onto a device)."""
    from geocon_core.files import part_path, replace_file, stamp_png

    png_path.parent.mkdir(parents=True, exist_ok=True)
    part = part_path(png_path)
    try:
        part.write_bytes(stamp_png(data))
        replace_file(part, png_path)
    finally:
        part.unlink(missing_ok=True)


_CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable", "chrome")


_CHROMIUM_FLAGS = (
    "--headless",
    "--no-sandbox",
    "--enable-unsafe-swiftshader",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--disable-breakpad",
    "--disable-crash-reporter",
    "--disable-extensions",
    "--disable-default-apps",
    "--no-first-run",
    "--no-default-browser-check",
    "--mute-audio",
    "--hide-scrollbars",
    # Nothing but loopback is resolved: the viewer's web-font links fail at once instead of hanging.
    "--host-resolver-rules=MAP * ~NOTFOUND , EXCLUDE 127.0.0.1",
    "--no-proxy-server",
    "--remote-debugging-pipe",
)


def find_chromium() -> str | None:
    """Path of a Chromium/Chrome executable (``$CHROMIUM`` first, then ``PATH``), or None."""
    env = os.environ.get("CHROMIUM")
    if env and os.access(env, os.X_OK):
        return env
    for name in _CHROMIUM_NAMES:
        found = shutil.which(name)
        if found:
            return found
    return None


class _DevToolsPipe:
    """Minimal Chrome DevTools protocol client over ``--remote-debugging-pipe`` (NUL-separated JSON)."""

    def __init__(self, write_fd: int, read_fd: int) -> None:
        self._write = os.fdopen(write_fd, "wb", buffering=0)
        self._read = os.fdopen(read_fd, "rb", buffering=0)
        self._next_id = 0
        self._lock = threading.Condition()
        self._responses: dict[int, dict[str, Any]] = {}
        self._events: list[dict[str, Any]] = []
        self._closed = False
        self._reader = threading.Thread(target=self._read_loop, name="devtools-pipe", daemon=True)
        self._reader.start()

    def _read_loop(self) -> None:
        buf = b""
        try:
            while True:
                chunk = self._read.read(1 << 16)
                if not chunk:
                    break
                buf += chunk
                while b"\0" in buf:
                    raw, buf = buf.split(b"\0", 1)
                    try:
                        msg = json.loads(raw)
                    except ValueError:
                        continue
                    with self._lock:
                        if "id" in msg:
                            self._responses[int(msg["id"])] = msg
                        else:
                            self._events.append(msg)
                        self._lock.notify_all()
        except (OSError, ValueError):
            pass
        finally:
            with self._lock:
                self._closed = True
                self._lock.notify_all()

    def call(
        self, method: str, params: dict[str, Any] | None = None, *, session: str | None = None, timeout: float = 30.0
    ) -> dict[str, Any]:
        with self._lock:
            self._next_id += 1
            msg_id = self._next_id
        msg: dict[str, Any] = {"id": msg_id, "method": method, "params": params or {}}
        if session is not None:
            msg["sessionId"] = session
        try:
            self._write.write(json.dumps(msg).encode() + b"\0")
        except OSError as exc:
            raise ScreenshotError(f"Lost the DevTools connection to Chromium while sending {method}.") from exc
        end = time.monotonic() + timeout
        with self._lock:
            while msg_id not in self._responses:
                left = end - time.monotonic()
                if self._closed or left <= 0:
                    why = "Chromium closed the DevTools pipe" if self._closed else "no answer in time"
                    raise ScreenshotError(f"DevTools call {method} failed ({why}).")
                self._lock.wait(left)
            reply = self._responses.pop(msg_id)
        if "error" in reply:
            raise ScreenshotError(f"DevTools call {method} failed: {reply['error'].get('message', reply['error'])}.")
        result: dict[str, Any] = reply.get("result", {})
        return result

    def wait_event(self, method: str, *, session: str | None = None, timeout: float) -> bool:
        """Wait for an event named ``method`` (consuming it); False on timeout or closed pipe."""
        end = time.monotonic() + timeout
        with self._lock:
            while True:
                for i, ev in enumerate(self._events):
                    if ev.get("method") == method and (session is None or ev.get("sessionId") == session):
                        del self._events[i]
                        return True
                left = end - time.monotonic()
                if self._closed or left <= 0:
                    return False
                self._lock.wait(left)

    def close(self) -> None:
        for f in (self._write, self._read):
            with contextlib.suppress(OSError):
                f.close()


# Put the two pipe ends on fds 3 and 4 of Chromium (what --remote-debugging-pipe expects), then exec it.
# A tiny Python trampoline does this so that subprocess keeps its own exec-error pipe and close_fds intact.
_FD_TRAMPOLINE = (
    "import fcntl, os, sys\n"
    "a, b = int(sys.argv[1]), int(sys.argv[2])\n"
    "a2, b2 = fcntl.fcntl(a, fcntl.F_DUPFD, 10), fcntl.fcntl(b, fcntl.F_DUPFD, 10)\n"
    "os.dup2(a2, 3); os.dup2(b2, 4)\n"
    "for fd in {a, b, a2, b2} - {3, 4}: os.close(fd)\n"
    "os.execv(sys.argv[3], sys.argv[3:])\n"
)


def start_chromium(
    chromium: str, profile: Path, width: int, height: int, log_path: Path
) -> tuple[subprocess.Popen[bytes], _DevToolsPipe]:
    """Start headless Chromium with the DevTools protocol on fds 3 (commands in) and 4 (replies out)."""
    cmd_r, cmd_w = os.pipe()  # we write commands -> Chromium reads fd 3
    out_r, out_w = os.pipe()  # Chromium writes fd 4 -> we read
    cmd = [
        sys.executable,
        "-c",
        _FD_TRAMPOLINE,
        str(cmd_r),
        str(out_w),
        chromium,
        *_CHROMIUM_FLAGS,
        f"--user-data-dir={profile}",
        f"--window-size={width},{height}",
        "about:blank",
    ]
    try:
        with open(log_path, "wb") as log:
            proc: subprocess.Popen[bytes] = subprocess.Popen(
                cmd,
                stdin=subprocess.DEVNULL,
                stdout=log,
                stderr=subprocess.STDOUT,
                pass_fds=(cmd_r, out_w),
                env=private_env(profile.parent),
                start_new_session=True,
            )
    except OSError as exc:
        for fd in (cmd_r, cmd_w, out_r, out_w):
            os.close(fd)
        raise ScreenshotError(f"Could not start Chromium at {chromium}: {exc}.") from exc
    os.close(cmd_r)
    os.close(out_w)
    return proc, _DevToolsPipe(cmd_w, out_r)


def check_capture(width: int, height: int, settle_s: float, timeout_s: float) -> None:
    if width <= 0 or height <= 0:
        raise ScreenshotError(f"Screenshot size must be positive, got {width}x{height}.")
    if settle_s < 0 or settle_s >= timeout_s:
        raise ScreenshotError(f"settle_s={settle_s:g} must be non-negative and below timeout_s={timeout_s:g}.")
    if find_chromium() is None:
        raise ScreenshotError("Chromium is not installed (apt-get install chromium, or set $CHROMIUM).")


def _open_page(pipe: _DevToolsPipe, url: str, width: int, height: int, left: Callable[[], float]) -> str:
    """Open ``url`` in a new tab of width x height and wait for its load event; return the session."""
    target = pipe.call("Target.createTarget", {"url": "about:blank"}, timeout=min(30.0, left()))["targetId"]
    session: str = pipe.call("Target.attachToTarget", {"targetId": target, "flatten": True}, timeout=min(30.0, left()))[
        "sessionId"
    ]
    pipe.call("Page.enable", session=session, timeout=min(30.0, left()))
    pipe.call(
        "Emulation.setDeviceMetricsOverride",
        {"width": width, "height": height, "deviceScaleFactor": 1, "mobile": False},
        session=session,
        timeout=min(30.0, left()),
    )
    nav = pipe.call("Page.navigate", {"url": url}, session=session, timeout=min(30.0, left()))
    if nav.get("errorText"):
        raise ScreenshotError(f"Chromium could not open {url}: {nav['errorText']}.")
    if not pipe.wait_event("Page.loadEventFired", session=session, timeout=min(60.0, left())):
        left()  # raises on overall timeout
        raise ScreenshotError(f"The page at {url} did not finish loading.")
    return session


def _settle(
    settle_s: float, chrome_proc: subprocess.Popen[bytes], alive: Callable[[], None] | None, left: Callable[[], float]
) -> None:
    """Wait ``settle_s`` for the page to render, checking that Chromium (and ``alive()``) still run."""
    if settle_s > left():
        raise ScreenshotError(f"settle_s={settle_s:g} does not fit in the time left.")
    end_settle = time.monotonic() + settle_s
    while time.monotonic() < end_settle:
        if alive is not None:
            alive()
        if chrome_proc.poll() is not None:
            raise ScreenshotError(f"Chromium exited early with code {chrome_proc.returncode}.")
        time.sleep(min(0.5, max(0.0, end_settle - time.monotonic())))


def _stop_chromium(proc: subprocess.Popen[bytes] | None, pipe: _DevToolsPipe | None) -> None:
    """Close Chromium politely (Browser.close), then stop its process group and the pipe."""
    if pipe is not None:
        with contextlib.suppress(ScreenshotError, OSError):
            if proc is not None and proc.poll() is None:
                pipe.call("Browser.close", timeout=3.0)
    kill_group(proc)
    if pipe is not None:
        pipe.close()


def capture(
    url: str,
    png_path: Path,
    workdir: Path,
    *,
    width: int,
    height: int,
    settle_s: float,
    deadline: float,
    what: str,
    alive: Callable[[], None] | None = None,
    wait: Callable[[Callable[[], bytes]], bytes] | None = None,
) -> None:
    """Headless Chromium (profile inside ``workdir``) opens ``url``, waits ``settle_s`` after the
    load event (calling ``alive()`` to check a server it depends on), and writes ``png_path``.

    Without ``wait`` the PNG is the one screenshot taken then. With it, ``wait(take)`` decides:
    ``take()`` returns a fresh PNG of the page (checking Chromium and ``alive()`` first) and ``wait``
    returns the PNG to save once the page looks ready, polling as often as it likes until the
    deadline (see :func:`geocon_viewer.capture.screenshot.poll_until_ready`)."""
    chromium = find_chromium()
    if chromium is None:
        raise ScreenshotError("Chromium is not installed (apt-get install chromium, or set $CHROMIUM).")
    chrome_proc: subprocess.Popen[bytes] | None = None
    pipe: _DevToolsPipe | None = None
    chrome_log = workdir / "chromium.log"

    def left() -> float:
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            raise ScreenshotError(f"Screenshot of {what} timed out.")
        return remaining

    try:
        profile = workdir / "chromium-profile"
        profile.mkdir()
        chrome_proc, pipe = start_chromium(chromium, profile, width, height, chrome_log)
        try:
            pipe.call("Browser.getVersion", timeout=min(30.0, left()))
        except ScreenshotError as exc:
            raise ScreenshotError(f"Chromium did not answer on the DevTools pipe: {log_tail(chrome_log)}") from exc
        session = _open_page(pipe, url, width, height, left)
        _settle(settle_s, chrome_proc, alive, left)
        running_pipe, running_proc = pipe, chrome_proc

        def take() -> bytes:
            if alive is not None:
                alive()
            if running_proc.poll() is not None:
                raise ScreenshotError(f"Chromium exited early with code {running_proc.returncode}.")
            shot = running_pipe.call(
                "Page.captureScreenshot",
                {
                    "format": "png",
                    "fromSurface": True,
                    "clip": {"x": 0, "y": 0, "width": width, "height": height, "scale": 1},
                },
                session=session,
                timeout=min(60.0, left()),
            )
            png = base64.b64decode(shot["data"])
            if not png.startswith(b"\x89PNG"):
                raise ScreenshotError("Chromium returned something that is not a PNG.")
            return png

        data = take() if wait is None else wait(take)
        save_png(data, png_path)
    except ScreenshotError:
        raise
    except (OSError, KeyError, ValueError) as exc:
        raise ScreenshotError(f"Screenshot of {what} failed: {exc}.") from exc
    finally:
        _stop_chromium(chrome_proc, pipe)


class Page:
    """A page open in headless Chromium, driven as a user drives it: JavaScript to read what the
    page shows, key presses and typed text to change it, screenshots. Made by :func:`open_page`."""

    def __init__(self, pipe: _DevToolsPipe, session: str, proc: subprocess.Popen[bytes], width: int, height: int):
        self._pipe, self._session, self._proc = pipe, session, proc
        self.width, self.height = width, height

    def _call(self, method: str, params: dict[str, Any] | None = None, timeout: float = 30.0) -> dict[str, Any]:
        if self._proc.poll() is not None:
            raise ScreenshotError(f"Chromium exited early with code {self._proc.returncode}.")
        return self._pipe.call(method, params, session=self._session, timeout=timeout)

    def evaluate(self, expression: str, timeout: float = 30.0) -> Any:
        """The value of a JavaScript ``expression`` in the page (JSON-serialisable values only)."""
        reply = self._call(
            "Runtime.evaluate", {"expression": expression, "returnByValue": True, "awaitPromise": True}, timeout
        )
        if "exceptionDetails" in reply:
            raise ScreenshotError(f"JavaScript failed in the page: {reply['exceptionDetails'].get('text', '?')}.")
        return reply.get("result", {}).get("value")

    def wait_for(self, expression: str, timeout: float = 30.0, poll_s: float = 0.1) -> Any:
        """Poll ``expression`` until it is truthy and return its value; ScreenshotError on timeout."""
        end = time.monotonic() + timeout
        while True:
            value = self.evaluate(expression)
            if value:
                return value
            if time.monotonic() > end:
                raise ScreenshotError(f"The page never satisfied {expression!r} within {timeout:g} s.")
            time.sleep(poll_s)

    def type_text(self, text: str) -> None:
        """Type ``text`` into the focused element."""
        self._call("Input.insertText", {"text": text})

    def press(self, key: str, code: str | None = None, key_code: int = 0) -> None:
        """Press and release one key (``"Enter"``, ``"Tab"``, ``"ArrowRight"``...) on the focused element."""
        params = {"key": key, "code": code or key, "windowsVirtualKeyCode": key_code, "nativeVirtualKeyCode": key_code}
        self._call("Input.dispatchKeyEvent", {"type": "keyDown", **params})
        self._call("Input.dispatchKeyEvent", {"type": "keyUp", **params})

    def screenshot(self) -> bytes:
        """A PNG of the page as it is now."""
        shot = self._call(
            "Page.captureScreenshot",
            {
                "format": "png",
                "fromSurface": True,
                "clip": {"x": 0, "y": 0, "width": self.width, "height": self.height, "scale": 1},
            },
        )
        return base64.b64decode(shot["data"])


@contextlib.contextmanager
def open_page(url: str, *, width: int = 1600, height: int = 1000, timeout_s: float = 60.0):
    """Open ``url`` in headless Chromium (a private profile, removed afterwards) and yield a
    :class:`Page` once it has loaded; Chromium is stopped on exit."""
    import tempfile

    chromium = find_chromium()
    if chromium is None:
        raise ScreenshotError("Chromium is not installed (apt-get install chromium, or set $CHROMIUM).")
    deadline = time.monotonic() + timeout_s

    def left() -> float:
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            raise ScreenshotError(f"Opening {url} timed out.")
        return remaining

    workdir = Path(tempfile.mkdtemp(prefix="geocon-page-"))
    proc: subprocess.Popen[bytes] | None = None
    pipe: _DevToolsPipe | None = None
    try:
        profile = workdir / "chromium-profile"
        profile.mkdir()
        proc, pipe = start_chromium(chromium, profile, width, height, workdir / "chromium.log")
        pipe.call("Browser.getVersion", timeout=min(30.0, left()))
        session = _open_page(pipe, url, width, height, left)
        pipe.call("Runtime.enable", session=session, timeout=min(30.0, left()))
        yield Page(pipe, session, proc, width, height)
    finally:
        _stop_chromium(proc, pipe)
        shutil.rmtree(workdir, ignore_errors=True)
