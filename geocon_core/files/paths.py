"""Output folders: checked before any work, and replaced whole.

:func:`check_out_dir` says in one sentence why a folder cannot take a command's output before the
command starts (``geocon bench --out``, ``geocon report --out``, ``geocon score --out``);
:func:`replace_dir` builds a folder in a temporary sibling and moves it into place only when it is
complete, so a run that fails or is killed leaves the previous folder exactly as it was. Nothing
is written or renamed onto a device, a FIFO or a socket (:func:`special_file`; the null device is
refused too): :func:`check_out_file` refuses one before any work, :func:`replace_file` and
:func:`replace_dir` at the rename.
"""

from __future__ import annotations

import hashlib
import os
import secrets
import shutil
import signal
import stat
import threading
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import Iterator, Sequence

from .procs import pid_alive

__all__ = [
    "OutPathError",
    "PROTECTED_PARTS",
    "check_apart",
    "deferred_signals",
    "record_parts",
    "check_out_dir",
    "check_out_file",
    "clear_stale_parts",
    "parents_made",
    "part_path",
    "part_prefix",
    "remove_path",
    "replace_dir",
    "refuse_special",
    "replace_file",
    "short_name",
    "special_file",
]

_PSEUDO_FS = (Path("/proc"), Path("/sys"))
"""Kernel file systems: a folder there cannot hold a command's output."""


class OutPathError(ValueError):
    """An output folder that cannot be used (one sentence naming the option and the path)."""


_SPECIAL_KINDS = (
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISFIFO, "a FIFO (named pipe)"),
    (stat.S_ISSOCK, "a socket"),
)


def _null_rdev() -> int | None:
    """The device numbers of the null device (read from its metadata, never opened)."""
    try:
        return os.stat(os.devnull).st_rdev
    except OSError:
        return None


def special_file(path: Path) -> str | None:
    """What ``path`` (or what a link there points to) is when it is neither a regular file, a
    folder nor absent: ``"the null device"``, ``"a character device"``, ``"a block device"``,
    ``"a FIFO (named pipe)"`` or ``"a socket"``; else None. The null device is told by its device
    numbers, wherever its node lies."""
    try:
        st = os.stat(path)
    except (OSError, ValueError):
        return None
    if stat.S_ISCHR(st.st_mode) and st.st_rdev == _null_rdev():
        return "the null device"
    return special_kind(st.st_mode)


def special_kind(mode: int) -> str | None:
    """What a file of ``mode`` is when it is a device, a FIFO or a socket, in words; else None."""
    return next((kind for test, kind in _SPECIAL_KINDS if test(mode)), None)


def refuse_special(path: Path, option: str | None = None) -> None:
    """Raise :class:`OutPathError` when ``path`` is a device, a FIFO or a socket: GeoCon writes
    only regular files and replaces them by renaming, which would put a file in the device's place."""
    kind = special_file(path)
    if kind is None:
        return
    keeps = ", which keeps nothing" if kind == "the null device" else ", not a regular file"
    if option:
        raise OutPathError(
            f"{option} {path} is {kind}{keeps}; GeoCon writes its outputs only to regular files: give a file name"
        )
    raise OutPathError(
        f"{path} is {kind}{keeps}; GeoCon replaces only regular files: move it away or choose another path"
    )


def _read_only(folder: Path) -> bool:
    """``folder`` lies on a file system mounted read-only (no write for anyone, root included)."""
    try:
        return bool(os.statvfs(folder).f_flag & os.ST_RDONLY)
    except OSError:
        return False


def check_out_dir(path: Path, option: str = "--out") -> Path:
    """Check that ``path`` can be (or already is) a writable folder, without creating anything.

    Raises :class:`OutPathError` (a ``ValueError``) with one sentence naming ``option`` and ``path``
    when ``path`` is under ``/proc`` or ``/sys``, exists and is not a folder, is a broken
    link, is a folder that is not writable, or cannot be created (an ancestor is a file, or the
    nearest existing ancestor is not writable). Returns ``path`` unchanged.

    Permission checks use :func:`os.access`, so they say nothing for root (who may write anywhere
    but on a read-only file system)."""
    full = Path(os.path.abspath(path))
    if not full.name:
        raise OutPathError(f"{option} {path} is the root folder; choose a folder of its own")
    for pseudo in _PSEUDO_FS:
        if full == pseudo or pseudo in full.parents:
            raise OutPathError(f"{option} {path} is under {pseudo}, which cannot hold files; choose a folder on disk")
    if path.is_symlink() and not path.exists():
        raise OutPathError(f"{option} {path} is a broken link (to {os.readlink(path)}); choose another folder")
    if path.exists():
        if not path.is_dir():
            raise OutPathError(
                f"{option} {path} exists and is not a folder; choose a folder (it is created if missing)"
            )
        if not os.access(path, os.W_OK | os.X_OK):
            if _read_only(path):
                raise OutPathError(f"{option} {path} is on a read-only file system; choose a folder on a writable one")
            raise OutPathError(f"{option} {path} is a folder without write permission; choose another folder")
        return path
    ancestor = full.parent
    while not ancestor.exists() and not ancestor.is_symlink():
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        raise OutPathError(f"{option} {path} cannot be created: {ancestor} is not a folder")
    if not os.access(ancestor, os.W_OK | os.X_OK):
        if _read_only(ancestor):
            raise OutPathError(
                f"{option} {path} cannot be created: {ancestor} is on a read-only file system; choose a writable folder"
            )
        raise OutPathError(f"{option} {path} cannot be created: no write permission in {ancestor}")
    return path


def check_out_file(path: Path, option: str, example: str = "audit.rrd") -> Path:
    """Check that a file can be written at ``path`` (``geocon score --rrd``): not a folder, and its
    folder can be (or is) a writable folder (:func:`check_out_dir`). Raises :class:`OutPathError`
    with one sentence naming ``option`` (a folder is answered with ``path / example`` as the name to
    give); returns ``path`` unchanged.

    A device, a FIFO or a socket (the null device too, found by its device numbers) is refused:
    outputs are written beside their place and renamed into it, which would replace the node."""
    refuse_special(path, option)
    if path.is_dir():
        raise OutPathError(f"{option} {path} is a folder; give a file name (e.g. {path / example})")
    try:
        check_out_dir(path.parent, option)
    except OutPathError as exc:
        raise OutPathError(f"{option} {path} cannot be written: {str(exc).removeprefix(f'{option} ')}") from None
    return path


PROTECTED_PARTS = ("record.json", "matches.npz", "overlays")
"""The parts of a record folder no output may replace (the record itself; its recording
``audit.rrd``, also one of :data:`geocon_core.bench.staging.RECORD_PARTS`, is re-rendered in place)."""


def _real(path: Path) -> Path:
    return Path(os.path.realpath(path))


def _same_file(a: Path, b: Path) -> bool:
    """The same file or folder, by resolved path or (both existing) by device and inode: a hard
    link or a bind mount of an input is that input too."""
    if _real(a) == _real(b):
        return True
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def _within(path: Path, folder: Path) -> bool:
    """``path`` is ``folder`` or lies inside it (resolved; a folder reached through a link counts)."""
    p, f = _real(path), _real(folder)
    if p == f or f in p.parents:
        return True
    return any(_same_file(a, folder) for a in [path, *path.parents][:64] if a.exists())


def record_parts(folder: Path) -> list[Path]:
    """The paths of a record folder no output may replace (:data:`PROTECTED_PARTS`)."""
    return [folder / name for name in PROTECTED_PARTS]


def check_apart(
    outputs: Sequence[tuple[str, Path]],
    inputs: Sequence[tuple[str, Path]],
    records: Sequence[Path] = (),
) -> None:
    """Refuse, before any work, an output that would write over an input or into a record.

    ``outputs``: (option, path) of every file or folder a command writes; ``inputs``: (what, path)
    of everything it reads (the clip, its frame folder, masks, a pose log, the record viewed);
    ``records``: record folders an output may sit beside but never inside of (their
    :data:`PROTECTED_PARTS`). Compared by resolved path and by inode, so links and hard links are
    seen through. Raises :class:`OutPathError` with one sentence naming the option, the path and
    the input it would destroy; two outputs that are one path are refused too."""
    for i, (option, out) in enumerate(outputs):
        for other, second in outputs[:i]:
            if _same_file(out, second):
                raise OutPathError(f"{option} {out} is also the {other} path; give each output a path of its own")
        for what, src in inputs:
            if _same_file(out, src):
                raise OutPathError(
                    f"{option} {out} is the {what}; GeoCon never writes over its inputs, choose another path"
                )
            if src.is_dir() and _within(out, src):
                raise OutPathError(
                    f"{option} {out} lies inside the {what} {src}; GeoCon never writes into its inputs, "
                    "choose another path"
                )
            if out.is_dir() and _within(src, out) and any(_within(src, part) for part in record_parts(out)):
                raise OutPathError(
                    f"{option} {out} would replace the {what} {src} (a record's own file); choose another folder"
                )
        for folder in records:
            for part in record_parts(folder):
                if _within(out, part) and not _same_file(out, folder):
                    raise OutPathError(
                        f"{option} {out} is inside the record {folder} ({part.name}), which it would destroy; "
                        "choose a path outside the record's own files"
                    )


@contextmanager
def deferred_signals(signals: Sequence[int] = (signal.SIGINT, signal.SIGTERM)) -> Iterator[None]:
    """Hold Ctrl-C and ``kill`` for the length of the block (a commit of several renames must not
    stop halfway), then deliver the first one that arrived, exactly as if it came after the block.
    Outside the main thread (where handlers cannot be set) the block runs as it is."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[int] = []
    previous = {s: signal.getsignal(s) for s in signals}

    def hold(signum: int, _frame: object) -> None:
        caught.append(signum)

    for s in signals:
        signal.signal(s, hold)
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
        if caught:
            os.kill(os.getpid(), caught[0])


NAME_ROOM = 180
"""Bytes of a target's name kept in its temporary siblings' names; a longer name is cut and
marked with a hash of the whole, so ``.NAME.part-<pid>-<token>`` stays within the 255-byte name
limit of common file systems (a legal 251-byte file name must not make its temporary name illegal)."""


def short_name(name: str) -> str:
    """``name`` when it fits :data:`NAME_ROOM` bytes, else its start and a hash of the whole."""
    raw = os.fsencode(name)
    if len(raw) <= NAME_ROOM:
        return name
    digest = hashlib.sha256(raw).hexdigest()[:12]
    return os.fsdecode(raw[: NAME_ROOM - 13]) + "~" + digest


def _named(target: Path) -> Path:
    """``target`` with a last name of its own: ``.`` and ``..`` are made absolute (the current
    folder is built beside itself, in its parent, like any other)."""
    return target if target.name not in ("", "..") else Path(os.path.abspath(target))


def part_prefix(target: Path) -> str:
    """Name prefix of the temporary siblings in which ``target`` is built (``.NAME.part-``,
    followed by the writer's pid); a long NAME is shortened (:func:`short_name`)."""
    return f".{short_name(_named(target).name)}.part-"


def part_path(target: Path) -> Path:
    """This process's temporary sibling of ``target`` (``.NAME.part-<pid>``)."""
    return _named(target).with_name(f"{part_prefix(target)}{os.getpid()}")


def remove_path(path: Path) -> None:
    """Remove a file, a link or a folder with its contents; nothing if it is absent."""
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        path.unlink(missing_ok=True)


def clear_stale_parts(target: Path) -> None:
    """Remove the temporary siblings of ``target`` left by runs that were killed (their process
    is gone); those of running processes stay."""
    stem = part_prefix(target)
    with suppress(OSError):
        for stale in _named(target).parent.glob(f"{stem}*"):
            pid = stale.name[len(stem) :].split("-", 1)[0]
            if pid.isdigit() and int(pid) != os.getpid() and not pid_alive(int(pid)):
                remove_path(stale)


def replace_file(tmp: Path, target: Path) -> None:
    """Move the finished file ``tmp`` onto ``target`` (one rename, atomic on one file system). A
    ``target`` that is a device, a FIFO or a socket (:func:`special_file`) is never replaced:
    ``tmp`` is removed and :class:`OutPathError` raised."""
    try:
        refuse_special(target)
    except OutPathError:
        tmp.unlink(missing_ok=True)
        raise
    os.replace(tmp, target)


@contextmanager
def parents_made(folder: Path) -> Iterator[None]:
    """Create ``folder`` and its missing parents for the length of the block; when the block
    fails (or is interrupted), the folders it created are removed again where they hold no file
    (nor do the folders made inside them during the block), so a failed run leaves no empty
    output folder behind (``geocon-out/`` of a clip that is missing)."""
    made = []
    probe = Path(os.path.abspath(folder))
    while not probe.exists() and not probe.is_symlink():
        made.append(probe)
        probe = probe.parent
    folder.mkdir(parents=True, exist_ok=True)
    try:
        yield
    except BaseException:
        inside = [Path(root) for root, _, _ in os.walk(made[0], topdown=False)] if made else []
        for path in inside + made[1:]:  # the deepest first
            with suppress(OSError):
                path.rmdir()
        raise


@contextmanager
def replace_dir(target: Path) -> Iterator[Path]:
    """Yield a new, empty temporary sibling of ``target`` to write into. When the block ends without
    an error, it replaces ``target`` (a previous ``target`` is removed only then); on an error it is
    removed and ``target`` is left exactly as it was. Temporary siblings left by killed runs (their
    process is gone) are removed first.

    The replacement is two renames on one file system: a reader sees the old folder, for an instant
    no folder, then the new one; never a partial one."""
    if target.is_symlink():  # replace the folder the link points to, keep the link
        target = Path(os.path.realpath(target))
    if target.exists() and not target.is_dir():  # only a folder is replaced, never a file or a device
        raise OutPathError(f"{target} exists and is not a folder; choose a folder (it is created if missing)")
    parent = target.parent
    with parents_made(parent):
        clear_stale_parts(target)
        tmp = parent / f"{part_prefix(target)}{os.getpid()}-{secrets.token_hex(4)}"
        tmp.mkdir()  # honours the umask, unlike tempfile.mkdtemp (0700)
        try:
            yield tmp
            if target.exists() or target.is_symlink():
                old = parent / f".{short_name(target.name)}.old-{os.getpid()}-{secrets.token_hex(4)}"
                target.rename(old)
                try:
                    tmp.rename(target)
                except BaseException:
                    old.rename(target)
                    raise
                shutil.rmtree(old, ignore_errors=True)
            else:
                tmp.rename(target)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
