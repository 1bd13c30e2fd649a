"""Worker processes that do not outlive their parent.

A ``ProcessPoolExecutor`` worker blocks reading its task queue, and the queue's write end is held by
the workers themselves, so a parent killed with ``kill -9`` leaves its workers alive (re-parented to
PID 1), finishing clips nobody will read, or waiting forever. :func:`die_with_parent`, given as the
pool's ``initializer``, makes a worker exit as soon as its parent is gone:

- on Linux, ``prctl(PR_SET_PDEATHSIG, SIGKILL)``: the kernel kills the worker when the thread
  that started it exits (the thread that submitted to the pool; keep it alive while the pool is);
- everywhere, a daemon thread that polls ``os.getppid()`` every :data:`PARENT_POLL_S` seconds and
  exits the process when the parent changed (the fallback where ``prctl`` is missing).

The multiprocessing resource tracker exits by itself once the last process holding its pipe (the
parent and the workers) is gone. Killed with the workers (``pkill -f multiprocessing``), it is
started again by :func:`quiet_resource_tracker`, silently: multiprocessing would start it again
itself, with a warning and a traceback for every semaphore of the old pool it is told to forget.
A pool forgets its semaphores as it shuts down, so a tracker killed after the last check (the
clips all scored) is started again there: :func:`quiet_tracker_restarts` keeps that start quiet too.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import subprocess
import sys
import threading
import time
import warnings
from collections.abc import Iterator
from typing import Any

__all__ = [
    "PARENT_POLL_S",
    "die_with_parent",
    "pid_alive",
    "quiet_resource_tracker",
    "quiet_tracker_restarts",
    "reap_when_gone",
    "start_reaper",
]

PARENT_POLL_S = 0.5
"""Seconds between two checks of the watchdog thread that the parent is still alive."""

_PR_SET_PDEATHSIG = 1  # <linux/prctl.h>


def die_with_parent(parent_pid: int, poll_s: float = PARENT_POLL_S, pdeathsig: bool = True) -> None:
    """Make the calling process exit when the process ``parent_pid`` (its parent) dies, ``kill -9``
    included. Meant as the ``initializer`` of a worker pool, called with the pool owner's PID
    (``initargs=(os.getpid(),)``). ``pdeathsig=False`` leaves out the ``prctl`` call (the watchdog
    thread alone, exiting within ``poll_s`` seconds)."""
    if pdeathsig:
        _set_pdeathsig(signal.SIGKILL)
    if os.getppid() != parent_pid:  # the parent died before the death signal was armed
        os._exit(1)
    threading.Thread(target=_watch_parent, args=(parent_pid, poll_s), name="geocon-parent-watch", daemon=True).start()


def _set_pdeathsig(sig: int) -> bool:
    """Ask the kernel to send ``sig`` to this process when its parent exits (Linux); whether it did."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        return int(libc.prctl(_PR_SET_PDEATHSIG, int(sig), 0, 0, 0)) == 0
    except (OSError, AttributeError):
        return False


def _watch_parent(parent_pid: int, poll_s: float) -> None:
    while os.getppid() == parent_pid:
        time.sleep(poll_s)
    os._exit(1)  # the parent is gone: nobody reads this process's results


def quiet_resource_tracker() -> bool:
    """Make sure multiprocessing's resource tracker runs, starting it (again, when it died) with
    its stderr on the null device; whether a tracker that had been running was found dead. Call it
    before a process pool starts: a tracker started again by multiprocessing itself prints a
    warning, and a traceback for each semaphore of the old pool it is told to forget, on the
    terminal of a run that recovered. A no-op where multiprocessing has no resource tracker
    (Windows)."""
    tracker = _tracker()
    if tracker is None:
        return False
    was_started = getattr(tracker, "_fd", None) is not None
    if was_started and tracker._check_alive():
        return False
    with _stderr_on_null():
        tracker.ensure_running()
    return was_started


@contextlib.contextmanager
def quiet_tracker_restarts() -> Iterator[list[bool]]:
    """For the block: a resource tracker that multiprocessing starts again, finding the one it had
    dead (to forget the semaphores of a pool that shuts down, say), starts with its stderr on the
    null device and without multiprocessing's warning, so the tracebacks it prints for semaphores
    it never knew go nowhere. Yields a list that holds True after the block when a tracker was
    started again. Everything this process writes to its stderr (descriptor 2) meanwhile goes to
    the null device too: keep the block to the calls that forget semaphores (a pool's
    ``shutdown``), which print nothing of their own."""
    tracker = _tracker()
    restarted: list[bool] = []
    before = getattr(tracker, "_pid", None)
    with _stderr_on_null():
        yield restarted
    after = getattr(tracker, "_pid", None)
    if before is not None and after != before:
        restarted.append(True)


def _tracker() -> Any:
    """multiprocessing's resource tracker of this process; None where there is none (Windows)."""
    try:
        from multiprocessing import resource_tracker
    except ImportError:
        return None
    return resource_tracker._resource_tracker


@contextlib.contextmanager
def _stderr_on_null() -> Iterator[None]:
    """For the block, descriptor 2 (which a started process inherits as its stderr) on the null
    device, and warnings not shown."""
    with contextlib.suppress(ValueError, OSError):
        sys.stderr.flush()
    saved = os.dup(2)
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 2)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            yield
    finally:
        with contextlib.suppress(ValueError, OSError):
            sys.stderr.flush()
        os.dup2(saved, 2)
        os.close(saved)
        os.close(devnull)


def pid_alive(pid: int) -> bool:
    """Whether a process ``pid`` exists on this host (a signal-0 probe; a zombie counts as alive)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # alive, owned by another user
        return True
    return True


def start_reaper(roots: list[int]) -> subprocess.Popen:
    """Start a watchdog process (in a session of its own, so it outlives this one) that kills
    ``roots`` and every process they start once this process dies, ``kill -9`` included, or once
    the roots are gone. For services that outlive a killed owner: Ray's node processes die with the
    driver that started them, but the agents they started are left running."""
    return subprocess.Popen(
        [sys.executable, "-m", "geocon_core.files.procs", str(os.getpid()), *map(str, roots)],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )


def reap_when_gone(owner_pid: int, roots: list[int], poll_s: float = PARENT_POLL_S) -> int:
    """Body of :func:`start_reaper`'s watchdog: remember ``roots`` and their descendants (pid and
    start time) while ``owner_pid`` and a root live, then kill those still running. Returns how
    many it killed."""
    import psutil

    seen: dict[int, float] = {}

    def remember(proc) -> None:
        try:
            seen[proc.pid] = proc.create_time()
            for child in proc.children(recursive=True):
                seen[child.pid] = child.create_time()
        except psutil.Error:
            pass

    def alive(proc) -> bool:
        try:
            return proc.is_running() and proc.status() != psutil.STATUS_ZOMBIE
        except psutil.Error:
            return False

    try:
        owner = psutil.Process(owner_pid)
    except psutil.Error:
        owner = None
    tracked = []
    for pid in roots:
        try:
            tracked.append(psutil.Process(pid))
        except psutil.Error:
            pass
    while owner is not None and alive(owner) and any(alive(p) for p in tracked):
        for proc in tracked:
            remember(proc)
        time.sleep(poll_s)
    killed = 0
    for pid, created in seen.items():
        try:
            proc = psutil.Process(pid)
            if proc.create_time() == created and alive(proc):
                proc.kill()
                killed += 1
        except psutil.Error:
            pass
    return killed


if __name__ == "__main__":  # the watchdog of start_reaper: OWNER_PID ROOT_PID...
    reap_when_gone(int(sys.argv[1]), [int(v) for v in sys.argv[2:]])
