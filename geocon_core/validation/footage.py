"""The footage cache: clips of public repositories that the annotation file names (root
``footage``) and the project never commits.

Each annotated row says where its clip comes from (``repo``, ``commit``, ``path``, and ``pose_path``
for a pose file) and what its bytes hash to (``sha256``). :func:`fill_footage` copies every
missing clip out of a local clone of its repository (``git show COMMIT:PATH``; nothing is
downloaded here), checks the hash and moves the file into place, so a cache is either right or
says what is wrong with it (:func:`footage_status`). Clones are looked up in a folder of bare or
ordinary clones named ``owner+name`` (or ``owner+name/repo``), ``owner/name`` or ``owner+name.git``; a missing clone is
reported with the ``git clone`` line that makes it.
"""

from __future__ import annotations

import hashlib
import os
import subprocess
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from .cases import Annotation

__all__ = ["DEFAULT_FOOTAGE", "FootageState", "FootageItem", "footage_status", "fill_footage", "clone_for"]


def _home() -> Path:
    """The user's home folder: ``$HOME`` when it is an absolute path, else (unset, empty or
    relative, where ``~`` would mean ``/`` or the current folder) the user database's entry."""
    home = os.environ.get("HOME", "")
    if os.path.isabs(home):
        return Path(home)
    try:
        import pwd

        return Path(pwd.getpwuid(os.getuid()).pw_dir)
    except (ImportError, KeyError):  # no user database entry: as Python's own lookup
        return Path.home()


DEFAULT_FOOTAGE = (
    Path(os.environ["GEOCON_FOOTAGE"]).expanduser()
    if os.environ.get("GEOCON_FOOTAGE")  # an empty value is no folder (it would mean the current one)
    else _home() / ".cache" / "geocon" / "footage"
)
"""The footage cache unless ``--footage`` (or ``GEOCON_FOOTAGE``) names another folder."""

FootageState = Literal["present", "missing", "wrong bytes", "filled", "no clone", "not in clone"]


@dataclass(frozen=True)
class FootageItem:
    """One annotated clip of the cache and what is known of it: ``present`` (its bytes hash as
    annotated), ``missing``, ``wrong bytes``; after a fill also ``filled``, ``no clone`` (no clone
    of its repository in the sources folder) or ``not in clone`` (the clone lacks the commit or
    the path). ``detail`` says what to do."""

    annotation: Annotation
    state: FootageState
    detail: str = ""


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with path.open("rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _rows(annotations: dict[str, Annotation] | Iterable[Annotation]) -> list[Annotation]:
    notes = annotations.values() if isinstance(annotations, dict) else annotations
    return sorted((a for a in notes if a.root == "footage"), key=lambda a: a.key)


def footage_status(annotations: dict[str, Annotation] | Iterable[Annotation], cache: Path) -> list[FootageItem]:
    """The state of every annotated clip of root ``footage`` in ``cache`` (and of its pose file)."""
    out = []
    for a in _rows(annotations):
        path = cache / a.clip
        if not path.is_file():
            out.append(FootageItem(a, "missing", f"{path} is missing"))
        elif a.sha256 and _sha256(path) != a.sha256:
            out.append(FootageItem(a, "wrong bytes", f"{path} does not hash to the annotated sha256"))
        elif a.pose_file and not (cache / a.pose_file).is_file():
            out.append(FootageItem(a, "missing", f"its pose file {cache / a.pose_file} is missing"))
        else:
            out.append(FootageItem(a, "present"))
    return out


def clone_for(repo: str, sources: Path) -> Path | None:
    """A clone of ``repo`` (``owner/name``) in ``sources``, bare or not, or None."""
    owner, _, name = repo.partition("/")
    for cand in (
        sources / f"{owner}+{name}",
        sources / f"{owner}+{name}" / "repo",
        sources / owner / name,
        sources / f"{owner}+{name}.git",
    ):
        if (cand / "HEAD").is_file() or (cand / ".git").exists():
            return cand
    return None


GIT_TIMEOUT_S = 120.0
"""How long ``git show`` may take to give one file of a local clone (a clip of a few hundred MB
takes seconds); a git that has not answered by then (a clone on a file system that stopped
answering, an ``alternates`` file that is a FIFO) is stopped, and the clip is named as not filled."""


class GitStuck(RuntimeError):
    """``git`` did not give a file within :data:`GIT_TIMEOUT_S`, or cannot be run."""


def _git_show(clone: Path, commit: str, path: str) -> bytes | None:
    """The bytes of ``path`` at ``commit`` in ``clone``, or None when the clone lacks either;
    :class:`GitStuck` when git does not answer within :data:`GIT_TIMEOUT_S` or is not installed."""
    git_dir = clone / ".git" if (clone / ".git").exists() else clone
    try:
        res = subprocess.run(
            ["git", f"--git-dir={git_dir}", "show", f"{commit}:{path}"],
            capture_output=True,
            check=False,
            timeout=GIT_TIMEOUT_S,
            stdin=subprocess.DEVNULL,
        )
    except subprocess.TimeoutExpired:
        raise GitStuck(
            f"git did not give {path} of {clone} within {GIT_TIMEOUT_S:g} s (a clone on a file system that stopped "
            "answering?); it was stopped"
        ) from None
    except OSError as exc:
        raise GitStuck(f"git cannot be run ({exc.strerror or exc}); install git") from None
    return res.stdout if res.returncode == 0 else None


def _install(data: bytes, target: Path) -> None:
    """Write ``data`` to ``target`` through a temporary file in its folder (a half-written clip is
    never left under the clip's name)."""
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = target.with_name(f".{target.name}.part")
    tmp.write_bytes(data)
    os.replace(tmp, target)


def fill_footage(
    annotations: dict[str, Annotation] | Iterable[Annotation], cache: Path, sources: Path
) -> list[FootageItem]:
    """Copy every missing or wrong clip of root ``footage`` (and its pose file) from a clone of its
    repository in ``sources`` into ``cache``; returns the state of each annotated clip after the
    fill. A clip whose bytes do not hash as annotated is not installed."""
    out = []
    for item in footage_status(annotations, cache):
        a = item.annotation
        if item.state == "present":
            out.append(item)
            continue
        clone = clone_for(a.repo, sources)
        if clone is None:
            owner, _, name = a.repo.partition("/")
            hint = f"git clone --bare https://github.com/{a.repo} {sources / f'{owner}+{name}'}"
            out.append(FootageItem(a, "no clone", f"no clone of {a.repo} in {sources} (make one: {hint})"))
            continue
        try:
            data = _git_show(clone, a.commit, a.path)
            pose = _git_show(clone, a.commit, a.pose_path) if a.pose_file and a.pose_path else None
        except GitStuck as exc:
            out.append(FootageItem(a, "not in clone", str(exc)))
            continue
        if data is None:
            out.append(FootageItem(a, "not in clone", f"{clone} has no {a.path} at {a.commit[:12]}"))
            continue
        if a.sha256 and hashlib.sha256(data).hexdigest() != a.sha256:
            out.append(FootageItem(a, "wrong bytes", f"{a.path} at {a.commit[:12]} does not hash as annotated"))
            continue
        if a.pose_file:
            if pose is None:
                out.append(FootageItem(a, "not in clone", f"{clone} has no pose file {a.pose_path!r}"))
                continue
            _install(pose, cache / a.pose_file)
        _install(data, cache / a.clip)
        out.append(FootageItem(a, "filled", str(cache / a.clip)))
    return out
