"""Reading the files people give: one rule for every reader.

A file GeoCon reads where a file is expected (a sidecar, a manifest, a record's parts, a results
folder's ``bench.json`` and ``status.json``, a ground truth, an annotation file, the clip model, a
pose log, masks) must be a regular file, and no larger than the bound of its kind
(:class:`FileKind`, one constant each below). Both are checked before a byte is read:

- the path is looked up with ``stat`` first, so a FIFO, a device or a socket is refused without
  being opened (opened, a FIFO blocks until a writer comes, ``/dev/zero`` never ends, ``/dev/stdin``
  takes the terminal); the file is then opened with ``O_NONBLOCK`` and checked again on its
  descriptor, so a file swapped for a FIFO in between cannot block either;
- its size is compared with the bound of its kind, and at most one byte more than the bound is
  ever read, so a file that grows while it is read (or whose size the system does not know) stops
  there too.

Every refusal is one sentence (:class:`ReadRefused`, a ``ValueError``) naming the file, what it
should be and, for a size, the bound:

>>> from pathlib import Path
>>> import os, tempfile
>>> folder = Path(tempfile.mkdtemp())
>>> os.mkfifo(folder / "a.meta.json")
>>> try:
...     read_bytes(folder / "a.meta.json", SIDECAR, "a.meta.json")
... except ReadRefused as exc:
...     print(exc.why)
a FIFO (named pipe), not a regular file
"""

from __future__ import annotations

import os
import stat
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO, Literal

from .paths import special_kind

__all__ = [
    "ANNOTATIONS",
    "BENCH_MANIFEST",
    "CLIP",
    "CLIP_MODEL",
    "COLMAP_TEXT",
    "FRAME_IMAGE",
    "GROUND_TRUTH",
    "LOCK_FILE",
    "MANIFEST",
    "MASKS_ARCHIVE",
    "MATCHES",
    "OVERLAYS_INDEX",
    "OVERLAY_IMAGE",
    "PARQUET_TABLE",
    "POSE_LOG",
    "POSE_SCENE",
    "RECORD_JSON",
    "RECORDING",
    "SIDECAR",
    "SMALL_STATE",
    "STATUS",
    "FileKind",
    "ReadRefused",
    "byte_size",
    "open_regular",
    "read_bytes",
    "read_text",
    "regular_file",
]

Reason = Literal["missing", "folder", "special", "size", "unreadable", "encoding"]


@dataclass(frozen=True)
class FileKind:
    """What a file GeoCon reads is expected to be, and the most bytes it reads of one.

    ``what``: the file in words with its article (``"a sidecar"``), as the refusals say it;
    ``limit``: the bound in bytes, generous (many times the largest real file of the kind) so that
    no real input is refused; ``advice``: what to do when a file is larger (``"score the clip
    again"``); ``own``: GeoCon writes files of this kind itself (a record's parts, a results
    folder's), so one that is a FIFO or a device is answered with ``advice`` too, where a file a
    person gives is answered with "save it to a file"."""

    what: str
    limit: int
    advice: str = "check that it is the file meant"
    own: bool = False

    def __post_init__(self) -> None:
        if self.limit <= 0:
            raise ValueError(f"the bound of {self.what} must be positive, got {self.limit}")


_MiB = 1 << 20
_GiB = 1 << 30

SIDECAR = FileKind("a sidecar", 1 * _MiB, "a clip's sidecar holds a few fields; check that it is one")
"""A clip's ``<name>.meta.json`` (a few hundred bytes; each field is bounded too:
:data:`geocon_core.bench.dataset.MAX_FIELD_CHARS`)."""
MANIFEST = FileKind(
    "a manifest", 256 * _MiB, "split the dataset into several manifests, or check that it is a manifest"
)
"""A dataset's CSV or JSONL manifest: at 1 KB a row, a quarter of a million clips."""
RECORD_JSON = FileKind("a GeoCon record", 512 * _MiB, "score the clip again", own=True)
"""A record's ``record.json`` (a 480-frame clip's is a few MB)."""
MATCHES = FileKind("a record's matches (matches.npz)", 8 * _GiB, "score the clip again", own=True)
"""A record's ``matches.npz`` (a 480-frame clip's is tens of MB)."""
OVERLAYS_INDEX = FileKind("a GeoCon overlays index", 64 * _MiB, "score the clip again", own=True)
"""A record's ``overlays/index.json`` (a long clip's index is a few MB)."""
OVERLAY_IMAGE = FileKind("an overlay of a record", 256 * _MiB, "score the clip again", own=True)
"""One PNG of a record's ``overlays/`` (a label or flow picture of one frame: a few hundred KB)."""
RECORDING = FileKind("a Rerun recording", 16 * _GiB, "score the clip again with --rrd", own=True)
"""A record's ``audit.rrd``, sent whole by ``geocon serve`` to a browser that downloads it."""
BENCH_MANIFEST = FileKind(
    "the manifest of GeoCon benchmark results (bench.json)", 256 * _MiB, "choose another --out", own=True
)
"""A results folder's ``bench.json`` (its dataset, options and clips: a few KB per clip)."""
STATUS = FileKind("a clip's status in the results (status.json)", 16 * _MiB, "the clip is scored again", own=True)
"""A results folder's ``clips/<id>/status.json`` (a few hundred bytes; an error message at most)."""
SMALL_STATE = FileKind("a state file of GeoCon", 16 * _MiB, "remove it, and it is made again", own=True)
"""The small JSON files GeoCon keeps beside its own outputs (a validation case's ``case.json``,
``done.json``, the peer's readings): a few KB each."""
PARQUET_TABLE = FileKind(
    "a Parquet table of benchmark results", 16 * _GiB, "run the same geocon bench command again", own=True
)
"""A results folder's ``tables/*.parquet`` (a few KB per clip)."""
GROUND_TRUTH = FileKind("a ground truth (.gt.json)", 256 * _MiB, "make the clip again", own=True)
"""The ``.gt.json`` of a synthetic or planted clip (a planted clip's is about 100 KB)."""
ANNOTATIONS = FileKind("an annotation file", 64 * _MiB, "check that it is an annotation CSV")
"""``validate --annotations`` (the project's own is about 220 KB for some hundred clips)."""
CLIP_MODEL = FileKind("a clip model", 16 * _MiB, "give the clip model file (a small JSON file)")
"""The clip model of ``signals.model`` (the shipped one is under 2 KB)."""
POSE_LOG = FileKind("a pose log", 1 * _MiB, "a pose log is a small JSON file")
"""A ``geocon-pose/1`` JSON file (a few KB for hundreds of frames)."""
POSE_SCENE = FileKind("a DUSt3R scene", 16 * _GiB, "check that it is a DUSt3R scene (.npz)")
"""A DUSt3R scene ``.npz`` given to ``geocon pose-log`` (dense points: hundreds of MB)."""
COLMAP_TEXT = FileKind("a COLMAP text model file", 4 * _GiB, "check that it is a COLMAP text model")
"""``images.txt`` / ``cameras.txt`` of a COLMAP text model (a line per image)."""
MASKS_ARCHIVE = FileKind("a masks archive (.npz)", 16 * _GiB, "check that it is a masks archive")
"""A ``--masks`` ``.npz`` of label masks (compressed: a few MB for hundreds of frames)."""
FRAME_IMAGE = FileKind("an image file", 2 * _GiB, "check that it is an image")
"""One frame of a folder of frames or one label mask PNG (an 8K 16-bit PNG is about 400 MB)."""
CLIP = FileKind("a clip", 1 << 40, "check that it is a clip")
"""A clip file (streamed by its decoder, never read whole: the bound, 1 TiB, only keeps out a
sparse file of absurd size)."""
LOCK_FILE = FileKind("a lock file of GeoCon", 64 * 1024, "remove it when no geocon bench runs", own=True)
"""A results folder's lock file (a PID and a host name: under 100 bytes)."""


class ReadRefused(ValueError):
    """A file that is not read: one sentence naming it, what it should be and why. ``reason``:
    ``missing``, ``folder``, ``special``, ``size``, ``unreadable`` or ``encoding``; ``why``: the
    reason in a few words without the file's name or advice (``"a FIFO (named pipe), not a regular
    file"``, ``"3 GiB, more than the 256 MiB GeoCon reads of a manifest"``), for a caller that
    frames the sentence itself."""

    def __init__(self, sentence: str, path: Path, reason: Reason, why: str) -> None:
        super().__init__(sentence)
        self.path = path
        self.reason = reason
        self.why = why


def byte_size(n: int) -> str:
    """``n`` bytes in words (``"1 MiB"``, ``"3.2 GiB"``, ``"512 bytes"``)."""
    for unit, size in (("GiB", _GiB), ("MiB", _MiB), ("KiB", 1024)):
        if n >= size:
            value = n / size
            return f"{value:.0f} {unit}" if value == int(value) or value >= 100 else f"{value:.1f} {unit}"
    return f"{n} bytes"


def _refused(path: Path, name: str, reason: Reason, why: str, then: str = "") -> ReadRefused:
    """The refusal ``{name} is {why}{then}``."""
    return ReadRefused(f"{name} is {why}{then}", path, reason, why)


def _checked(path: Path, st: os.stat_result, kind: FileKind, name: str, linked: bool) -> None:
    """Refuse a file of metadata ``st`` that is a folder, a device, a FIFO or a socket, or larger
    than ``kind.limit``."""
    via = "a link to " if linked else ""
    if stat.S_ISDIR(st.st_mode):
        raise _refused(path, name, "folder", f"{via}a folder, not {kind.what}", "; give the file")
    node = special_kind(st.st_mode)
    if node is not None or not stat.S_ISREG(st.st_mode):
        raise _refused(
            path,
            name,
            "special",
            f"{via}{node or 'not a regular file'}, not a regular file",
            f": GeoCon reads {kind.what} only from a regular file (a pipe or a device can block or never end); "
            f"{kind.advice if kind.own else 'save it to a file'}",
        )
    if st.st_size > kind.limit:
        raise _too_large(path, st.st_size, kind, name)


def _too_large(path: Path, size: int | None, kind: FileKind, name: str) -> ReadRefused:
    held = byte_size(size) if size is not None else "larger than that"
    why = f"{held}, more than the {byte_size(kind.limit)} GeoCon reads of {kind.what}"
    return _refused(path, name, "size", why, f"; {kind.advice}")


def _unreadable(path: Path, name: str, exc: BaseException) -> ReadRefused:
    why = getattr(exc, "strerror", None) or str(exc) or type(exc).__name__
    return ReadRefused(f"{name} cannot be read ({why})", path, "unreadable", f"unreadable ({why})")


def regular_file(path: str | os.PathLike[str], kind: FileKind, name: str | None = None) -> os.stat_result:
    """The metadata of the regular file at ``path`` (links followed), checked without opening it:
    :class:`ReadRefused` naming ``name`` (the path as the user gave it; ``path`` itself by
    default) when it is missing, a link to nothing, a folder, a device, a FIFO or a socket, or
    larger than the bound of ``kind``."""
    p = Path(path)
    where = str(p) if name is None else name
    try:
        st = os.stat(p)
    except FileNotFoundError:
        if os.path.islink(p):
            raise _refused(p, where, "missing", f"a link to nothing ({os.readlink(p)})") from None
        raise ReadRefused(f"{where} does not exist", p, "missing", "missing") from None
    except (OSError, ValueError) as exc:
        raise _unreadable(p, where, exc) from None
    _checked(p, st, kind, where, os.path.islink(p))
    return st


def open_regular(path: str | os.PathLike[str], kind: FileKind, name: str | None = None) -> BinaryIO:
    """The regular file at ``path`` opened for reading in binary, checked as :func:`regular_file`
    says before it is opened and again on the open descriptor (opened with ``O_NONBLOCK``, so a
    file swapped for a FIFO in between does not block). For readers that take a file object
    (``np.load``, Pillow, pyarrow); the caller closes it."""
    p = Path(path)
    where = str(p) if name is None else name
    regular_file(p, kind, where)
    try:
        fd = os.open(p, os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY | os.O_CLOEXEC)
    except OSError as exc:
        raise _unreadable(p, where, exc) from None
    try:
        _checked(p, os.fstat(fd), kind, where, os.path.islink(p))
        os.set_blocking(fd, True)
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def read_bytes(path: str | os.PathLike[str], kind: FileKind, name: str | None = None) -> bytes:
    """The bytes of the regular file at ``path`` (:func:`open_regular`), at most the bound of
    ``kind``: a file that holds more once read (it grew, or its size was not known) is refused
    as a larger one is."""
    p = Path(path)
    where = str(p) if name is None else name
    with open_regular(p, kind, where) as f:
        try:
            data = f.read(kind.limit + 1)
        except OSError as exc:
            raise _unreadable(p, where, exc) from None
    if len(data) > kind.limit:
        raise _too_large(p, None, kind, where)
    return data


def read_text(path: str | os.PathLike[str], kind: FileKind, name: str | None = None) -> str:
    """The UTF-8 text of the regular file at ``path`` (:func:`read_bytes`; a byte-order mark is
    dropped). Bytes that are not UTF-8 are refused naming the first one (UTF-16, which editors on
    Windows save, by name)."""
    p = Path(path)
    where = str(p) if name is None else name
    data = read_bytes(p, kind, where)
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        if data[:2] in (b"\xff\xfe", b"\xfe\xff"):
            found = "UTF-16 text, not UTF-8"
        else:
            found = f"not UTF-8 text (byte 0x{data[exc.start]:02x} at offset {exc.start})"
        raise _refused(p, where, "encoding", found, "; save it as UTF-8") from None
