"""Outputs of several files, committed together: every target is checked before the first one
moves, the finished parts are renamed into place as one unit (Ctrl-C and ``kill`` held), and a
failure midway puts every earlier file back, so the folder is as it was or holds the new set
whole (:func:`commit_together`)."""

from __future__ import annotations

import os
import secrets
import shutil
from contextlib import suppress
from pathlib import Path
from typing import Sequence

from .paths import OutPathError, deferred_signals, refuse_special, short_name

__all__ = ["check_targets", "commit_together"]


def check_targets(targets: Sequence[tuple[Path, bool]]) -> None:
    """Refuse (:class:`~geocon_core.files.paths.OutPathError`, one sentence) a set of outputs
    that cannot be committed whole, before anything is made: ``targets`` are (path, is a folder);
    refused are a path that is a device, a FIFO or a socket, a folder where a file goes, a file
    where a folder goes, and two outputs on one path."""
    seen: set[str] = set()
    for target, folder in targets:
        key = os.path.realpath(target)
        if key in seen:
            raise OutPathError(f"{target} would be written twice by one run; give each output a name of its own")
        seen.add(key)
        refuse_special(target)
        if not os.path.lexists(target):
            continue
        if target.is_dir() and not folder:
            raise OutPathError(
                f"{target} is a folder, where this run writes a file; move it away or choose another path"
            )
        if folder and not target.is_dir():
            raise OutPathError(
                f"{target} is a file, where this run writes a folder; move it away or choose another path"
            )


def _aside(target: Path) -> Path:
    return target.with_name(f".{short_name(target.name)}.old-{os.getpid()}-{secrets.token_hex(4)}")


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        with suppress(OSError):
            path.unlink()


def commit_together(moves: Sequence[tuple[Path, Path]]) -> None:
    """Move each finished ``part`` (a file or a folder, beside its ``target`` on one file system)
        onto its ``target``, all or none. :func:`check_targets` runs first (a writer calls it before its
    work too, so that a refusal costs nothing); then, with signals held,
        each existing target is renamed aside, each part renamed into place, and the set aside removed.
        When a rename fails, the parts already in place are removed and every target set aside is put
        back before the error is raised; the parts not moved are removed too."""
    try:
        check_targets([(target, part.is_dir()) for part, target in moves])
    except BaseException:
        for part, _ in moves:
            _remove(part)
        raise
    placed: list[Path] = []
    aside: list[tuple[Path, Path]] = []
    with deferred_signals():
        try:
            for part, target in moves:
                if os.path.lexists(target):
                    old = _aside(target)
                    os.rename(target, old)
                    aside.append((old, target))
                os.rename(part, target)
                placed.append(target)
        except BaseException:
            for target in placed:
                _remove(target)
            for old, target in reversed(aside):
                with suppress(OSError):
                    os.rename(old, target)
            for part, _ in moves:
                _remove(part)
            raise
        for old, _ in aside:
            _remove(old)
