"""Processes of a test's subprocess tree, read from ``/proc`` (Linux): whether they still run."""

from __future__ import annotations

import os
import signal
import subprocess
import time
from pathlib import Path
from typing import Callable

__all__ = ["running", "live_group", "wait_gone", "kill_parent_alone"]

_EXITED = ("Z", "X")
"""Process states of a process that has exited (a zombie waits only for its parent to reap it)."""


def _stat(pid: int | str) -> list[str] | None:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None


def running(pid: int) -> bool:
    """Whether the process ``pid`` exists and has not exited."""
    fields = _stat(pid)
    return fields is not None and fields[0] not in _EXITED


def live_group(pgid: int) -> list[int]:
    """The processes of process group ``pgid`` that still run."""
    found = []
    for entry in Path("/proc").iterdir():
        fields = _stat(entry.name) if entry.name.isdigit() else None
        if fields is not None and int(fields[2]) == pgid and fields[0] not in _EXITED:
            found.append(int(entry.name))
    return found


def wait_gone(alive: Callable[[], object], limit_s: float) -> float:
    """Seconds until ``alive()`` is falsy, polled every 20 ms, at most ``limit_s``."""
    start = time.monotonic()
    while alive() and time.monotonic() - start < limit_s:
        time.sleep(0.02)
    return time.monotonic() - start


def kill_parent_alone(proc: subprocess.Popen, limit_s: float = 5.0) -> None:
    """``kill -9`` of ``proc`` alone (started with ``start_new_session=True``, so its group is its
    own), as a user's kill does; asserts that every process of its group is gone within
    ``limit_s`` seconds, and kills any that is not."""
    try:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        seconds = wait_gone(lambda: live_group(proc.pid), limit_s)
        assert live_group(proc.pid) == [], f"processes of the killed run still alive after {seconds:.1f} s"
    finally:
        for pid in live_group(proc.pid):
            os.kill(pid, signal.SIGKILL)
        proc.wait()
