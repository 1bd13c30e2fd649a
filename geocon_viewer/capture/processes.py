"""The child processes behind the viewers: the ``rerun`` executable serving a recording on
127.0.0.1, free loopback ports, the check of an address a server is asked to bind
(:func:`check_bind`), private config dirs, and clean-up. Every child is started in its own session
(process group) and stopped with its whole group (:func:`kill_group`)."""

from __future__ import annotations

import contextlib
import errno
import importlib.util
import os
import re
import shutil
import signal
import socket
import subprocess
import threading
import time
import urllib.parse
import urllib.request
from pathlib import Path

__all__ = [
    "ScreenshotError",
    "BindError",
    "ViewerUrlError",
    "ViewerUnreachable",
    "check_viewer_url",
    "find_rerun_binary",
    "free_port",
    "check_bind",
    "private_env",
    "kill_group",
    "log_tail",
    "rerun_import_error",
    "start_rerun",
]

_ANSI = re.compile(r"\x1b\[[0-9;]*m")


_NO_PROXY = urllib.request.build_opener(urllib.request.ProxyHandler({}))


class ScreenshotError(RuntimeError):
    """Chromium or the rerun executable is missing, or the capture failed."""


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


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


class BindError(ValueError):
    """A ``--host`` or ``--port`` a server cannot bind to (one sentence naming the option)."""


RESOLVE_TIMEOUT_S = 10.0
"""How long :func:`check_bind` waits for ``--host`` to resolve before refusing it."""
PORT_SEARCH = 100
"""How many ports above a busy ``--port`` :func:`check_bind` tries."""


def _lookup(host: str, port: int, timeout_s: float, flags: int = 0) -> list | BaseException | None:
    """``socket.getaddrinfo`` of ``host`` in a thread of its own, waited for at most ``timeout_s``:
    its answer, the exception it raised, or None when it did not answer in time (a resolver that
    hangs must not hang the command)."""
    found: list = []

    def lookup() -> None:
        try:
            found.append(socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=flags))
        except (OSError, UnicodeError) as exc:
            found.append(exc)

    thread = threading.Thread(target=lookup, name="geocon-resolve", daemon=True)
    thread.start()
    thread.join(timeout_s)
    return found[0] if found else None


def _ip_addresses(answer: list) -> list[tuple[int, tuple]]:
    """(family, socket address) of every IPv4/IPv6 entry of a ``getaddrinfo`` answer, once each."""
    addrs = [(fam, sockaddr) for fam, _, _, _, sockaddr in answer if fam in (socket.AF_INET, socket.AF_INET6)]
    return list(dict.fromkeys(addrs))


def _resolve(host: str) -> list[tuple[int, tuple]]:
    """(family, socket address) of every address ``host`` binds to, as a server binding ``host``
    would see them, within :data:`RESOLVE_TIMEOUT_S`."""
    found = _lookup(host, 0, RESOLVE_TIMEOUT_S, socket.AI_PASSIVE)
    if found is None:
        raise BindError(f"--host {host} did not resolve within {RESOLVE_TIMEOUT_S:g} s: give an IP address")
    if isinstance(found, BaseException):
        why = getattr(found, "strerror", None) or found
        raise BindError(f"--host {host} is neither an IP address nor a name that resolves ({why})")
    addrs = _ip_addresses(found)
    if not addrs:
        raise BindError(f"--host {host} resolves to no IPv4 or IPv6 address")
    return addrs


def _try_bind(addrs: list[tuple[int, tuple]], port: int) -> int:
    """0 when every address binds on ``port`` (as asyncio's server binds them), else the errno."""
    with contextlib.ExitStack() as stack:
        for fam, sockaddr in addrs:
            sock = stack.enter_context(socket.socket(fam, socket.SOCK_STREAM))
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            if fam == socket.AF_INET6:
                sock.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY, 1)
            try:
                sock.bind((sockaddr[0], port, *sockaddr[2:]))
            except OSError as exc:
                return exc.errno or -1
    return 0


def check_bind(host: str, port: int) -> int:
    """The port a server asked for ``host`` and ``port`` can bind: ``port`` itself, or when it is
    in use the next free one above it (0 stays 0: any free port). Checked before anything starts,
    so that no server thread fails where nobody sees it. Raises :class:`BindError` for a port
    outside 0-65535, a host that does not resolve or is not an address of this machine, and a
    port that cannot be bound for another reason."""
    if not 0 <= port <= 65535:
        raise BindError(f"--port must be between 0 and 65535 (0 picks any free port), got {port}")
    if not host.strip():
        raise BindError("--host is empty: give 127.0.0.1 (this machine only) or 0.0.0.0 (every interface)")
    addrs = _resolve(host)
    last = port if port == 0 else min(65535, port + PORT_SEARCH)
    for candidate in range(port, last + 1):
        code = _try_bind(addrs, candidate)
        if code == 0:
            return candidate
        if code == errno.EADDRNOTAVAIL:
            raise BindError(
                f"--host {host} is not an address of this machine: give 127.0.0.1 (this machine only), "
                "0.0.0.0 (every interface) or one of its own addresses"
            )
        if code == errno.EACCES:
            raise BindError(f"--port {candidate} needs privileges this user lacks: use 1024 or above, or 0 (any)")
        if code != errno.EADDRINUSE:
            raise BindError(f"--host {host} --port {candidate} cannot be bound ({os.strerror(code)})")
    raise BindError(f"--port {port} and the {last - port} ports above it are in use on {host}: give another --port")


class ViewerUrlError(ValueError):
    """A ``--connect`` value that is not the URL of a Rerun viewer (one sentence naming it)."""


class ViewerUnreachable(RuntimeError):
    """No Rerun viewer answers at a well-formed ``--connect`` URL (one sentence naming it)."""


VIEWER_SCHEMES = ("rerun+http", "rerun+https", "rerun")
"""The schemes of a Rerun viewer's gRPC URL (``rerun://`` is TLS, like ``rerun+https://``)."""
VIEWER_DEFAULT_PORT = 9876
"""The port Rerun connects to when a viewer URL names none (the viewer's default)."""
CONNECT_TIMEOUT_S = 5.0
"""How long :func:`check_viewer_url` waits for the viewer's host to resolve, and for the viewer to
accept a connection and answer as a gRPC (HTTP/2) server (a port that accepts and never answers
would have the recording wait for ever)."""
_EXAMPLE_URL = "rerun+http://127.0.0.1:9876/proxy"


def check_viewer_url(url: str, *, timeout_s: float = CONNECT_TIMEOUT_S) -> tuple[str, int]:
    """(host, port) of the Rerun viewer at ``url`` (``rerun+http://HOST:PORT/proxy``), checked
    before anything is rendered: :class:`ViewerUrlError` when ``url`` is not such a URL,
    :class:`ViewerUnreachable` when its host does not resolve or nothing accepts a connection on
    its port and answers as an HTTP/2 (gRPC) server within ``timeout_s`` seconds
    (:func:`geocon_core.files.answers.http2_answer`; the streaming itself would only fail after the
    whole recording was rendered, with a traceback of Rerun's, or wait for ever on a port that
    accepts and never answers)."""
    where = f"--connect {url!r}"
    parts = urllib.parse.urlsplit(url)
    if url.partition("://")[0] not in VIEWER_SCHEMES:  # case and spaces matter to Rerun
        raise ViewerUrlError(
            f"{where} is not a Rerun viewer URL (it must start with rerun+http://, rerun+https:// or rerun://); "
            f"give one like {_EXAMPLE_URL}"
        )
    try:
        host, port = parts.hostname, parts.port
    except ValueError:  # a port that is not a number from 0 to 65535
        raise ViewerUrlError(
            f"{where} has no valid port (a number from 1 to 65535); give one like {_EXAMPLE_URL}"
        ) from None
    if not host:
        raise ViewerUrlError(f"{where} names no host; give one like {_EXAMPLE_URL}")
    if parts.path.rstrip("/") != "/proxy" or parts.query or parts.fragment:
        raise ViewerUrlError(f"{where} must end in /proxy, as a Rerun viewer's URL does: e.g. {_EXAMPLE_URL}")
    port = VIEWER_DEFAULT_PORT if port is None else port
    if port == 0:
        raise ViewerUrlError(f"{where} has no valid port (a number from 1 to 65535); give one like {_EXAMPLE_URL}")
    from geocon_core.files import http2_answer

    addrs = _resolve_for_connect(host, port, url, timeout_s)
    tls = url.partition("://")[0] != "rerun+http"
    whys = []
    for family, sockaddr in addrs:
        why = http2_answer(family, sockaddr, timeout_s, tls=tls, host=host)
        if why is None:
            return host, port
        whys.append(why)
    if whys and all(w == "connection refused" for w in whys):
        raise ViewerUnreachable(
            f"no Rerun viewer listens at {url} (connection refused on {host} port {port}); start one with `rerun` "
            f"(it listens on {_EXAMPLE_URL}) or give the URL it prints"
        )
    why = next((w for w in whys if w != "connection refused"), "no address")
    raise ViewerUnreachable(
        f"the Rerun viewer at {url} cannot be reached ({why}); check that it runs and that this machine can reach "
        f"{host} port {port}"
    )


def _resolve_for_connect(host: str, port: int, url: str, timeout_s: float) -> list[tuple[int, tuple]]:
    """(family, socket address) of every IPv4/IPv6 address of ``host``, within ``timeout_s``."""
    found = _lookup(host, port, timeout_s)
    if found is None:
        raise ViewerUnreachable(
            f"the host of the Rerun viewer at {url} did not resolve within {timeout_s:g} s; give the viewer's IP "
            "address (127.0.0.1 for this machine)"
        )
    if isinstance(found, BaseException):
        why = getattr(found, "strerror", None) or found
        raise ViewerUnreachable(
            f"the host {host} of the Rerun viewer at {url} does not resolve ({str(why).lower()}); check the name or "
            "give the viewer's IP address (127.0.0.1 for this machine)"
        )
    addrs = _ip_addresses(found)
    if not addrs:
        raise ViewerUnreachable(f"the host {host} of the Rerun viewer at {url} has no IPv4 or IPv6 address")
    return addrs


def private_env(workdir: Path, **extra: str) -> dict[str, str]:
    """The environment for a child, with config/cache/data dirs inside ``workdir`` (nothing lands in $HOME)."""
    env = dict(os.environ, **extra)
    for var in ("XDG_CONFIG_HOME", "XDG_CACHE_HOME", "XDG_DATA_HOME"):
        folder = workdir / "xdg" / var.lower()
        folder.mkdir(parents=True, exist_ok=True)
        env[var] = str(folder)
    return env


def kill_group(proc: subprocess.Popen[bytes] | None) -> None:
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


def log_tail(path: Path, n_chars: int = 600) -> str:
    try:
        text = path.read_text(errors="replace")
    except OSError:
        return ""
    return " ".join(text[-n_chars:].split())


def rerun_import_error(log_path: Path) -> str | None:
    """The rerun server's complaint about the recording (e.g. not an RRD file), if it logged one."""
    try:
        text = _ANSI.sub("", log_path.read_text(errors="replace"))
    except OSError:
        return None
    for line in text.splitlines():
        if "Failed to import" in line or "Not an RRD file" in line:
            return " ".join(line.split())[-300:]
    return None


def start_rerun(rerun_bin: str, rrd: Path, workdir: Path, deadline: float) -> tuple[subprocess.Popen[bytes], str, Path]:
    """Serve ``rrd`` on loopback; return the process, the viewer URL that opens the recording and the log."""
    last_error = "no attempt"
    for attempt in range(3):
        grpc_port, web_port = free_port(), free_port()
        while web_port == grpc_port:
            web_port = free_port()
        log_path = workdir / f"rerun-{attempt}.log"
        env = private_env(workdir, RERUN_ANALYTICS="0", RUST_LOG=os.environ.get("RUST_LOG", "warn,re_sdk=info"))
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
                    last_error = f"rerun exited with code {proc.returncode}: {log_tail(log_path)}"
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
                last_error = f"rerun did not start serving in time: {log_tail(log_path)}"
        except BaseException:
            kill_group(proc)
            raise
        kill_group(proc)
        if time.monotonic() >= deadline:
            break
    raise ScreenshotError(f"Could not serve the recording with the rerun executable ({last_error}).")
