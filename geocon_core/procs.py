"""Worker processes that do not outlive their parent.

A ``ProcessPoolExecutor`` worker blocks reading its task queue, and the queue's write end is held by
the workers themselves, so a parent killed with ``kill -9`` leaves its workers alive (re-parented to
PID 1), finishing clips nobody will read, or waiting forever. :func:`die_with_parent`, given as the
pool's ``initializer``, makes a worker exit as soon as its parent is gone:

- on Linux, ``prctl(PR_SET_PDEATHSIG, SIGKILL)``: the kernel kills the worker when the thread
  that started it exits (the thread that submitted to the pool; keep it alive while the pool is);
- everywhere, a daemon thread that polls ``os.getppid()`` every :data:`PARENT_POLL_S` seconds and
  exits the process when the parent changed (the fallback where ``prctl`` is missing).

The multiprocessing resource tracker needs nothing: it exits by itself once the last process holding
its pipe (the parent and the workers) is gone.
"""

from __future__ import annotations

import ctypes
import os
import signal
import sys
import threading
import time

__all__ = ["PARENT_POLL_S", "die_with_parent", "pid_alive"]

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


def pid_alive(pid: int) -> bool:
    """Whether a process ``pid`` exists on this host (a signal-0 probe; a zombie counts as alive)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # alive, owned by another user
        return True
    return True
