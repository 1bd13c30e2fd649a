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
import stat
import time
from pathlib import Path
from types import TracebackType

from .bounded import LOCK_FILE, read_text
from .procs import pid_alive

__all__ = ["FolderLock", "LockHeld", "NotALockFile", "check_lock_path", "lock_holder"]


class LockHeld(Exception):
    """The lock file ``path`` is held by another process: ``pid`` (None when it did not say) on ``host``."""

    def __init__(self, path: Path, pid: int | None, host: str | None) -> None:
        super().__init__(f"{path} is held by PID {pid} on {host}")
        self.path, self.pid, self.host = path, pid, host


class NotALockFile(ValueError):
    """The lock file's path holds something GeoCon never made there: a link, a folder, a FIFO or
    a device (opened, a FIFO blocks and a link would have another file truncated)."""


_OPEN_FLAGS = os.O_CLOEXEC | os.O_NOFOLLOW | os.O_NONBLOCK
"""How a lock file is opened: never through a link, never blocking on a FIFO."""


def check_lock_path(path: Path) -> None:
    """Raise :class:`NotALockFile` when something is at ``path`` that is not a regular file (a link
    too, followed nowhere): checked before a command starts, as :meth:`FolderLock.acquire` checks it
    again on the file it opens."""
    try:
        mode = os.lstat(path).st_mode
    except FileNotFoundError:
        return
    if not stat.S_ISREG(mode):
        what = "a link" if stat.S_ISLNK(mode) else "not a regular file"
        raise NotALockFile(
            f"{path} is {what}, so it is not GeoCon's lock file: remove it (a running geocon bench keeps its lock "
            "there)"
        )


def _check_node(path: Path, fd: int) -> None:
    """Raise :class:`NotALockFile` (closing ``fd``) when ``fd`` is not a regular file."""
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        os.close(fd)
        raise NotALockFile(
            f"{path} is not a regular file, so it is not GeoCon's lock file: remove it (a running geocon bench keeps "
            "its lock there)"
        )


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
            try:
                fd = os.open(self.path, os.O_RDWR | os.O_CREAT | _OPEN_FLAGS, 0o644)
            except OSError as exc:
                if exc.errno not in (errno.ELOOP, errno.EISDIR, errno.ENXIO):  # a link, a folder, a socket
                    raise
                raise NotALockFile(
                    f"{self.path} is a link, a folder or a socket, so it is not GeoCon's lock file: remove it (a "
                    "running geocon bench keeps its lock there)"
                ) from None
            _check_node(self.path, fd)
            os.set_blocking(fd, True)
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
                info = json.loads(read_text(self.path, LOCK_FILE))
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
        fd = os.open(path, os.O_RDONLY | _OPEN_FLAGS)
    except OSError:
        return None
    if not stat.S_ISREG(os.fstat(fd).st_mode):  # a FIFO or a device: no process holds it
        os.close(fd)
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
