"""A lock file that lets one process at a time use a folder.

:class:`FolderLock` holds an exclusive ``flock`` on a file inside the folder and writes its PID and
host into it, so a second process learns who holds the folder. The kernel drops the lock when its
holder dies (``kill -9`` included), so a lock file left by a dead process is taken over; on a file
system without ``flock`` a lock file whose process is gone (same host, no such PID) is taken over.
A clean release removes the file.
"""

from __future__ import annotations

import errno
import fcntl
import json
import os
import socket
import time
from pathlib import Path
from types import TracebackType

from .procs import pid_alive

__all__ = ["FolderLock", "LockHeld", "lock_holder"]


class LockHeld(Exception):
    """The lock file ``path`` is held by another process: ``pid`` (None when it did not say) on ``host``."""

    def __init__(self, path: Path, pid: int | None, host: str | None) -> None:
        super().__init__(f"{path} is held by PID {pid} on {host}")
        self.path, self.pid, self.host = path, pid, host


class FolderLock:
    """``with FolderLock(path):`` holds the lock file ``path`` (created) or raises :class:`LockHeld`
    at once, without waiting."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._fd: int | None = None

    def __enter__(self) -> FolderLock:
        self.acquire()
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        self.release()

    def acquire(self) -> None:
        """Take the lock or raise :class:`LockHeld`."""
        while True:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                os.close(fd)
                raise LockHeld(self.path, *self._holder(wait_s=1.0)) from None
            except OSError as exc:
                if exc.errno not in (errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOSYS, errno.EINVAL):
                    os.close(fd)
                    raise
                self._check_pid(fd)  # no flock here: the holder's PID decides
            if self._same_file(fd):  # not a file its last holder removed while we opened it
                break
            os.close(fd)
        payload = json.dumps({"pid": os.getpid(), "host": socket.gethostname()}).encode()
        os.ftruncate(fd, 0)
        os.pwrite(fd, payload, 0)
        self._fd = fd

    def release(self) -> None:
        """Remove the lock file and drop the lock (removed first, while still held)."""
        if self._fd is None:
            return
        try:
            if self._same_file(self._fd):
                self.path.unlink()
        finally:
            os.close(self._fd)
            self._fd = None

    def _same_file(self, fd: int) -> bool:
        try:
            st = os.stat(self.path)
        except FileNotFoundError:
            return False
        own = os.fstat(fd)
        return (st.st_dev, st.st_ino) == (own.st_dev, own.st_ino)

    def _holder(self, wait_s: float = 0.0) -> tuple[int | None, str | None]:
        """The PID and host written in the lock file; waits up to ``wait_s`` for a holder that has
        just taken the lock to write them."""
        deadline = time.monotonic() + wait_s
        while True:
            try:
                info = json.loads(self.path.read_text())
                return int(info["pid"]), str(info["host"])
            except (OSError, ValueError, KeyError, TypeError):
                if time.monotonic() >= deadline:
                    return None, None
                time.sleep(0.05)

    def _check_pid(self, fd: int) -> None:
        """Without ``flock``: raise :class:`LockHeld` unless the file names no process, this one, or
        a process of this host that is gone (two processes starting at the same instant can both
        pass; ``flock`` has no such gap)."""
        pid, host = self._holder()
        if pid is None or pid == os.getpid() or (host == socket.gethostname() and not pid_alive(pid)):
            return
        os.close(fd)
        raise LockHeld(self.path, pid, host)


def lock_holder(path: Path) -> LockHeld | None:
    """Who holds the lock file ``path`` now (a :class:`LockHeld` naming the PID and host), or None
    when no process does (no file, or one its dead holder left), without taking the lock: a shared
    ``flock`` is tried and dropped at once. On a file system without ``flock`` the file's PID
    decides, as in :meth:`FolderLock.acquire`."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_CLOEXEC)
    except OSError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        return LockHeld(path, *FolderLock(path)._holder(wait_s=1.0))
    except OSError:
        pid, host = FolderLock(path)._holder()
        mine = pid is None or pid == os.getpid() or (host == socket.gethostname() and not pid_alive(pid))
        return None if mine else LockHeld(path, pid, host)
    else:
        fcntl.flock(fd, fcntl.LOCK_UN)
        return None
    finally:
        os.close(fd)
