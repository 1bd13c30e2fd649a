"""Headless screenshots of Rerun ``.rrd`` recordings, as a user sees them.

Two ways, both on 127.0.0.1 only and always cleaned up:

- native (preferred): the ``rerun`` executable shipped in the rerun-sdk wheel runs ``--headless``
  (needs a Vulkan driver: a GPU's or Mesa's software one), ``rerun.experimental.ViewerClient`` opens
  the file, moves the time cursor and takes the screenshot;
- web (fallback): the same executable serves the recording and the web viewer, headless Chromium
  opens it and is driven through the DevTools protocol over ``--remote-debugging-pipe`` (no websocket
  library needed), and ``Page.captureScreenshot`` writes the PNG. Chromium resolves no host but
  127.0.0.1; its profile, config, cache and crash-report dirs live in one temp dir that is removed.

Every child runs in its own process group and is killed at the end.
"""

from __future__ import annotations

import base64
import contextlib
import importlib.util
import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import urllib.parse
import urllib.request
from pathlib import Path
from typing import Any

__all__ = [
    "ScreenshotError",
    "find_chromium",
    "find_rerun_binary",
    "screenshot_native",
    "screenshot_rrd",
    "screenshot_web",
    "screenshot_url",
]

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


_ANSI = re.compile(r"\x1b\[[0-9;]*m")
_NO_PROXY = urllib.request.build_opener(urllib.request.ProxyHandler({}))


class ScreenshotError(RuntimeError):
    """Chromium or the rerun executable is missing, or the capture failed."""


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


def find_rerun_binary() -> str | None:
    """Path of the real ``rerun`` binary inside the rerun-sdk wheel (``rerun_cli/rerun``), or None.

    ``$RERUN_CLI_PATH`` wins when set; a ``rerun`` on ``PATH`` is the fallback."""
    env = os.environ.get("RERUN_CLI_PATH")
    if env and os.access(env, os.X_OK):
        return env
    spec = importlib.util.find_spec("rerun_cli")
    for folder in (spec.submodule_search_locations or []) if spec is not None else []:
        candidate = Path(folder) / "rerun"
        if candidate.is_file() and os.access(candidate, os.X_OK):
            return str(candidate)
    # Last resort: the `rerun` console script, a wrapper around the real binary (its whole process group is
    # killed on clean-up, so the binary goes too).
    return shutil.which("rerun")


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def _private_env(workdir: Path, **extra: str) -> dict[str, str]:
    """The environment for a child, with config/cache/data dirs inside ``workdir`` (nothing lands in $HOME)."""
    env = dict(os.environ, **extra)
    for var in ("XDG_CONFIG_HOME", "XDG_CACHE_HOME", "XDG_DATA_HOME"):
        folder = workdir / "xdg" / var.lower()
        folder.mkdir(parents=True, exist_ok=True)
        env[var] = str(folder)
    return env


def _kill_by_marker(marker: str) -> None:
    """SIGKILL processes whose command line mentions ``marker`` (our unique temp dir): Chromium's crashpad
    handlers leave its process group, but their ``--database`` lies inside our private config dir."""
    needle = marker.encode()
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit() or int(entry.name) == os.getpid():
            continue
        try:
            cmdline = (entry / "cmdline").read_bytes()
        except OSError:
            continue
        if needle in cmdline:
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.kill(int(entry.name), signal.SIGKILL)


def _kill_group(proc: subprocess.Popen[bytes] | None) -> None:
    """Stop ``proc`` and everything in its process group (it was started with a new session)."""
    if proc is None:
        return
    for sig, wait_s in ((signal.SIGTERM, 5.0), (signal.SIGKILL, 5.0)):
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(proc.pid, sig)
        try:
            proc.wait(timeout=wait_s)
        except subprocess.TimeoutExpired:
            continue
        # The leader is gone; make sure no child of it lingers in the group.
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(proc.pid, signal.SIGKILL)
        return


def _log_tail(path: Path, n_chars: int = 600) -> str:
    try:
        text = path.read_text(errors="replace")
    except OSError:
        return ""
    return " ".join(text[-n_chars:].split())


def _import_error(log_path: Path) -> str | None:
    """The rerun server's complaint about the recording (e.g. not an RRD file), if it logged one."""
    try:
        text = _ANSI.sub("", log_path.read_text(errors="replace"))
    except OSError:
        return None
    for line in text.splitlines():
        if "Failed to import" in line or "Not an RRD file" in line:
            return " ".join(line.split())[-300:]
    return None


def _start_rerun(
    rerun_bin: str, rrd: Path, workdir: Path, deadline: float
) -> tuple[subprocess.Popen[bytes], str, Path]:
    """Serve ``rrd`` on loopback; return the process, the viewer URL that opens the recording and the log."""
    last_error = "no attempt"
    for attempt in range(3):
        grpc_port, web_port = _free_port(), _free_port()
        while web_port == grpc_port:
            web_port = _free_port()
        log_path = workdir / f"rerun-{attempt}.log"
        env = _private_env(workdir, RERUN_ANALYTICS="0", RUST_LOG=os.environ.get("RUST_LOG", "warn,re_sdk=info"))
        env.pop("RERUN_CLI_PATH", None)  # a wrapper must not be sent back to itself
        cmd = [
            rerun_bin,
            "--serve-web",
            "--bind",
            "127.0.0.1",
            "--port",
            str(grpc_port),
            "--web-viewer-port",
            str(web_port),
            "--hide-welcome-screen",
            str(rrd),
        ]
        with open(log_path, "wb") as log:
            proc: subprocess.Popen[bytes] = subprocess.Popen(
                cmd, stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT, env=env, start_new_session=True
            )
        web_url = f"http://127.0.0.1:{web_port}/"
        try:
            while time.monotonic() < deadline:
                if proc.poll() is not None:
                    last_error = f"rerun exited with code {proc.returncode}: {_log_tail(log_path)}"
                    break
                try:
                    with _NO_PROXY.open(web_url, timeout=2) as resp:
                        ready = resp.status == 200
                    with socket.create_connection(("127.0.0.1", grpc_port), timeout=2):
                        pass
                except OSError:
                    ready = False
                if ready:
                    proxy = f"rerun+http://127.0.0.1:{grpc_port}/proxy"
                    return proc, f"{web_url}?url={urllib.parse.quote(proxy, safe='')}", log_path
                time.sleep(0.2)
            else:
                last_error = f"rerun did not start serving in time: {_log_tail(log_path)}"
        except BaseException:
            _kill_group(proc)
            raise
        _kill_group(proc)
        if time.monotonic() >= deadline:
            break
    raise ScreenshotError(f"Could not serve the recording with the rerun executable ({last_error}).")


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


def _start_chromium(
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
                env=_private_env(profile.parent),
                start_new_session=True,
            )
    except OSError as exc:
        for fd in (cmd_r, cmd_w, out_r, out_w):
            os.close(fd)
        raise ScreenshotError(f"Could not start Chromium at {chromium}: {exc}.") from exc
    os.close(cmd_r)
    os.close(out_w)
    return proc, _DevToolsPipe(cmd_w, out_r)


def _raise_on_import_error(rrd: Path, rerun_log: Path) -> None:
    problem = _import_error(rerun_log)
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
    port = _free_port()
    env = _private_env(workdir, RERUN_ANALYTICS="0", RUST_LOG=os.environ.get("RUST_LOG", "warn"))
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
                    f"The headless viewer exited with code {proc.returncode}: {_log_tail(log_path, 300)}"
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
            tail = _log_tail(log_path, 300)
            raise ScreenshotError(f"The headless viewer could not take the screenshot ({exc}). {tail}".strip()) from exc
        if not data.startswith(b"\x89PNG"):
            raise ScreenshotError("The headless viewer returned something that is not a PNG.")
        png_path.parent.mkdir(parents=True, exist_ok=True)
        png_path.write_bytes(data)
        return png_path
    finally:
        _kill_group(proc)
        shutil.rmtree(workdir, ignore_errors=True)


def screenshot_rrd(
    rrd: str | Path,
    png: str | Path,
    *,
    at: str | None = None,
    width: int = 1600,
    height: int = 1000,
    settle_s: float = 20.0,
    timeout_s: float = 120.0,
    backend: str = "auto",
) -> Path:
    """Screenshot ``rrd``: ``backend="native"`` (headless native viewer, needs Vulkan), ``"web"`` (the web
    viewer in headless Chromium, width x height) or ``"auto"`` (native, then web if that fails)."""
    if backend not in ("auto", "native", "web"):
        raise ScreenshotError(f"Unknown screenshot backend {backend!r}: use auto, native or web.")
    _parse_at(at)
    if backend in ("auto", "native"):
        try:
            return screenshot_native(rrd, png, at=at, timeout_s=min(90.0, timeout_s))
        except ScreenshotError:
            if backend == "native" or find_chromium() is None:
                raise
    return screenshot_web(rrd, png, at=at, width=width, height=height, settle_s=settle_s, timeout_s=timeout_s)


def screenshot_web(
    rrd: str | Path,
    png: str | Path,
    *,
    at: str | None = None,
    width: int = 1600,
    height: int = 1000,
    settle_s: float = 20.0,
    timeout_s: float = 120.0,
) -> Path:
    """Serve `rrd` with the `rerun` executable shipped in the rerun-sdk wheel (web viewer bound to 127.0.0.1,
    free ports), open it in headless Chromium (the web viewer takes no time cursor from its page URL, so
    ``at`` is accepted for symmetry and not applied: the viewer follows the data to its last frame), wait until the viewer has rendered (settle_s after load), save a
    PNG of width x height to `png` and return its path. Raises ScreenshotError (a RuntimeError subclass, with one
    clear sentence) when Chromium or the rerun executable is missing or the capture fails. Always cleans up both
    processes (including the real rerun binary behind any wrapper) and temp profile dirs."""
    rrd_path = Path(rrd).resolve()
    if not rrd_path.is_file():
        raise ScreenshotError(f"Recording {rrd_path} does not exist.")
    _check_capture(width, height, settle_s, timeout_s)
    rerun_bin = find_rerun_binary()
    if rerun_bin is None:
        raise ScreenshotError("The rerun executable (rerun_cli/rerun from the rerun-sdk wheel) was not found.")
    deadline = time.monotonic() + timeout_s
    workdir = Path(tempfile.mkdtemp(prefix="geocon-rrdshot-"))
    rerun_proc: subprocess.Popen[bytes] | None = None
    try:
        rerun_proc, viewer_url, rerun_log = _start_rerun(rerun_bin, rrd_path, workdir, deadline)
        # The web viewer has no way to take a time cursor from its page URL: ``at`` is not applied here.
        _raise_on_import_error(rrd_path, rerun_log)

        def alive() -> None:
            if rerun_proc is not None and rerun_proc.poll() is not None:
                raise ScreenshotError(f"The rerun server exited early with code {rerun_proc.returncode}.")

        _capture(
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
        _kill_group(rerun_proc)
        if Path("/proc/self").exists():
            _kill_by_marker(str(workdir))
        shutil.rmtree(workdir, ignore_errors=True)


def screenshot_url(
    url: str, png: str | Path, *, width: int = 1600, height: int = 1000, settle_s: float = 8.0, timeout_s: float = 90.0
) -> Path:
    """Open ``url`` (a page served on this machine, e.g. ``geocon serve``) in headless Chromium, wait
    ``settle_s`` after it loads, and save a PNG of width x height to ``png``. Raises ScreenshotError
    with one clear sentence when Chromium is missing or the capture fails; cleans up after itself."""
    _check_capture(width, height, settle_s, timeout_s)
    deadline = time.monotonic() + timeout_s
    workdir = Path(tempfile.mkdtemp(prefix="geocon-pageshot-"))
    try:
        _capture(url, Path(png), workdir, width=width, height=height, settle_s=settle_s, deadline=deadline, what=url)
        return Path(png)
    finally:
        if Path("/proc/self").exists():
            _kill_by_marker(str(workdir))
        shutil.rmtree(workdir, ignore_errors=True)


def _check_capture(width: int, height: int, settle_s: float, timeout_s: float) -> None:
    if width <= 0 or height <= 0:
        raise ScreenshotError(f"Screenshot size must be positive, got {width}x{height}.")
    if settle_s < 0 or settle_s >= timeout_s:
        raise ScreenshotError(f"settle_s={settle_s:g} must be non-negative and below timeout_s={timeout_s:g}.")
    if find_chromium() is None:
        raise ScreenshotError("Chromium is not installed (apt-get install chromium, or set $CHROMIUM).")


def _capture(
    url: str,
    png_path: Path,
    workdir: Path,
    *,
    width: int,
    height: int,
    settle_s: float,
    deadline: float,
    what: str,
    alive: Any = None,
) -> None:
    """Headless Chromium (profile inside ``workdir``) opens ``url``, waits ``settle_s`` after the
    load event (calling ``alive()`` to check a server it depends on), and writes ``png_path``."""
    chromium = find_chromium()
    assert chromium is not None
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
        chrome_proc, pipe = _start_chromium(chromium, profile, width, height, chrome_log)
        try:
            pipe.call("Browser.getVersion", timeout=min(30.0, left()))
        except ScreenshotError as exc:
            raise ScreenshotError(f"Chromium did not answer on the DevTools pipe: {_log_tail(chrome_log)}") from exc
        target = pipe.call("Target.createTarget", {"url": "about:blank"}, timeout=min(30.0, left()))["targetId"]
        session = pipe.call("Target.attachToTarget", {"targetId": target, "flatten": True}, timeout=min(30.0, left()))[
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
        if settle_s > left():
            raise ScreenshotError(f"settle_s={settle_s:g} does not fit in the time left.")
        end_settle = time.monotonic() + settle_s
        while time.monotonic() < end_settle:
            if alive is not None:
                alive()
            if chrome_proc.poll() is not None:
                raise ScreenshotError(f"Chromium exited early with code {chrome_proc.returncode}.")
            time.sleep(min(0.5, max(0.0, end_settle - time.monotonic())))
        shot = pipe.call(
            "Page.captureScreenshot",
            {
                "format": "png",
                "fromSurface": True,
                "clip": {"x": 0, "y": 0, "width": width, "height": height, "scale": 1},
            },
            session=session,
            timeout=min(60.0, left()),
        )
        data = base64.b64decode(shot["data"])
        if not data.startswith(b"\x89PNG"):
            raise ScreenshotError("Chromium returned something that is not a PNG.")
        png_path.parent.mkdir(parents=True, exist_ok=True)
        png_path.write_bytes(data)
    except ScreenshotError:
        raise
    except (OSError, KeyError, ValueError) as exc:
        raise ScreenshotError(f"Screenshot of {what} failed: {exc}.") from exc
    finally:
        if pipe is not None:
            with contextlib.suppress(ScreenshotError, OSError):
                if chrome_proc is not None and chrome_proc.poll() is None:
                    pipe.call("Browser.close", timeout=3.0)
        _kill_group(chrome_proc)
        if pipe is not None:
            pipe.close()
