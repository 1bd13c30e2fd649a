"""What a path holds, and the one rule every writer follows: a command writes only the files it
owns in this run, and replaces a file only when it is its own kind made by GeoCon for the same
input.

:func:`held` says what a path holds, told by names and bytes, never by trust: nothing, a folder
(one of GeoCon's, :data:`FOLDER_KINDS`: a record, the results of ``geocon bench``, a report, a
validation; or another), a file GeoCon made (a Rerun recording whose application id is GeoCon's,
a PNG carrying GeoCon's ``Software`` text, a JSON file of a ``geocon-*`` format, :data:`FORMATS`,
a Markdown page under one of GeoCon's titles), a device or a user's file; and which GeoCon folders
it lies in (:func:`folders_above`).

:func:`claim` is what every writer calls on each output path before any work: it refuses, in one
sentence naming the option and the path, an output that would land on a part of another GeoCon
folder (a record's ``record.json``, ``matches.npz``, ``overlays/``, ``audit.rrd``; a results
folder's ``bench.json``, ``clips/``, ``tables/``, its report; anything in a report folder, which
is replaced whole; a validation's reports, cases, cache and fitted model), a folder of GeoCon's of
another kind, a folder that holds a user's files under the names of the parts it would write, and
an existing file that is not the output's own kind made by GeoCon; and, through the writer's
``mine`` callback, GeoCon's own kind made for another input (the record of another clip, the
clean twin of another source). Re-running a command on the same input replaces its earlier
output, which is what ``claim`` lets through.
"""

from __future__ import annotations

import json
import os
import re
import stat
import struct
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Literal, Sequence

from .paths import OutPathError, refuse_special

__all__ = [
    "FOLDER_KINDS",
    "FORMATS",
    "GEOCON_PNG_TEXT",
    "SNIFF_BYTES",
    "FolderKind",
    "Held",
    "OutputKind",
    "claim",
    "folder_kind",
    "folders_above",
    "held",
    "stamp_png",
]

SNIFF_BYTES = 1 << 20
"""At most this many bytes of a file are read to tell what it holds (its head: a Rerun
recording's store info, a PNG's text chunks, a JSON file's ``format``); a JSON file longer than
this is told by a ``"format"`` within its head."""
RRD_HEAD_BYTES = 4096
"""A Rerun recording names its application in its first message, within this many bytes."""
RRD_MAGIC = (b"RRF0", b"RRF1", b"RRF2")
"""The first four bytes of a Rerun recording (``.rrd``), of its encoder versions so far."""
GEOCON_APP_ID = b"\n\x06geocon"
"""GeoCon's application id as a Rerun recording's store info encodes it (a field of 6 bytes)."""
CASES_LOOKED_AT = 64
"""At most this many entries of a ``cases/`` folder are looked at for a scored case's
``case.json`` (a validation still running, before its ``validation.json``)."""
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
GEOCON_PNG_TEXT = b"Software\x00GeoCon"
"""The ``tEXt`` chunk every PNG GeoCon saves as a screenshot carries (:func:`stamp_png`)."""

FORMATS = {
    "geocon-record": "record.json of a record",
    "geocon-overlays": "overlays index of a record",
    "geocon-bench": "manifest of benchmark results",
    "geocon-bench-clip": "status of a benchmark clip",
    "geocon-pose": "pose log",
    "geocon-synth-gt": "ground truth of a synthetic clip",
    "geocon-plant-gt": "ground truth of a planted clip",
    "geocon-validation": "validation report",
    "geocon-clip-model": "clip model",
}
"""GeoCon's JSON files by their ``format`` (the part before the ``/version``), and what each is."""


@dataclass(frozen=True)
class FolderKind:
    """A folder GeoCon writes as one output: the file that marks it, the names of its parts (the
    entries no other output may replace or go into; None: every entry, as the folder is replaced
    whole), and what it is called in a sentence."""

    marker: str
    parts: tuple[str, ...] | None
    phrase: str


OutputKind = Literal["record", "results", "report", "validation"]
"""A folder of GeoCon's (:data:`FOLDER_KINDS`)."""

FOLDER_KINDS: dict[str, FolderKind] = {
    "record": FolderKind(
        "record.json", ("record.json", "matches.npz", "overlays", "audit.rrd"), "a record folder of `geocon score`"
    ),
    "results": FolderKind(
        "bench.json", ("bench.json", "bench.lock", "clips", "tables", "report"), "the results of a `geocon bench` run"
    ),
    "report": FolderKind("report.html", None, "a report of `geocon report`"),
    "validation": FolderKind(
        "validation.json",
        ("validation.md", "validation.json", "cases", "clip_model.json", "fit.md"),
        "a validation folder of `geocon validate`",
    ),
}
"""GeoCon's output folders, by kind. A record is marked by its ``record.json``, results by their
``bench.json`` (written first), a report by a ``report.html`` that GeoCon wrote, a validation by
its ``validation.json`` or, before that is written, a ``cases/`` folder of scored cases. A
validation's ``cache/`` is no part: its entries are keyed by what they hold, and another
validation may share it (``--cache OTHER/cache``)."""

_REPORT_TITLE = b"<title>GeoCon benchmark report</title>"


def _stat(path: Path) -> os.stat_result | None:
    try:
        return os.stat(path)
    except (OSError, ValueError):
        return None


def _head(path: Path, limit: int) -> bytes:
    """The first ``limit`` bytes of the regular file ``path`` (b"" when it cannot be read)."""
    try:
        with open(path, "rb") as f:
            return f.read(limit)
    except OSError:
        return b""


def _regular(path: Path) -> bool:
    st = _stat(path)
    return st is not None and stat.S_ISREG(st.st_mode)


def folder_kind(folder: Path) -> str | None:
    """The kind of GeoCon folder ``folder`` is (a key of :data:`FOLDER_KINDS`), or None (also for
    a folder that does not exist). Told by its marker: a record's ``record.json``, results'
    ``bench.json``, a report's ``report.html`` made by GeoCon, a validation's ``validation.json``
    of GeoCon's format or its ``cases/`` of scored cases."""
    st = _stat(folder)
    if st is None or not stat.S_ISDIR(st.st_mode):
        return None
    if _regular(folder / "bench.json"):
        return "results"
    if _regular(folder / "record.json"):
        return "record"
    if _regular(folder / "report.html") and _REPORT_TITLE in _head(folder / "report.html", 4096):
        return "report"
    if _regular(folder / "validation.json") and b'"geocon-validation/' in _head(folder / "validation.json", 4096):
        return "validation"
    cases = folder / "cases"
    if cases.is_dir():
        try:
            with os.scandir(cases) as it:
                for _, entry in zip(range(CASES_LOOKED_AT), it, strict=False):
                    if entry.is_dir() and _regular(Path(entry.path) / "case.json"):
                        return "validation"
        except OSError:
            pass
    return None


def folders_above(path: Path) -> list[tuple[str, Path]]:
    """Every GeoCon folder (kind, folder) that ``path`` lies in, the innermost first (``path``
    itself not included); folders are compared resolved, so a link into a record is inside it."""
    full = Path(os.path.realpath(path))
    return [(kind, at) for at in full.parents if (kind := folder_kind(at)) is not None]


@dataclass(frozen=True)
class Held:
    """What a path holds: ``kind`` is ``"nothing"``, ``"special"`` (a device, a FIFO, a socket),
    ``"folder"`` (``folder`` then names its GeoCon kind, or None), ``"recording"`` (a Rerun
    recording), ``"png"``, ``"json"``, ``"video"`` or ``"file"``; ``geocon``: GeoCon made it (its
    bytes say so: a recording's application id, a PNG's text, a JSON ``format`` of :data:`FORMATS`);
    ``format``: a JSON file's ``format``; ``data``: its object, when it is no larger than
    :data:`SNIFF_BYTES`."""

    path: Path
    kind: str
    geocon: bool = False
    folder: str | None = None
    format: str | None = None
    data: dict | None = None

    def describe(self) -> str:
        """What the path holds, for a sentence (``a Rerun recording made by another program``)."""
        if self.kind == "folder":
            return FOLDER_KINDS[self.folder].phrase if self.folder else "a folder"
        if self.kind == "recording":
            return "a Rerun recording made by GeoCon" if self.geocon else "a Rerun recording made by another program"
        if self.kind == "png":
            return "a PNG image GeoCon saved" if self.geocon else "a PNG image GeoCon did not make"
        if self.kind == "markdown":
            return "a Markdown page GeoCon wrote" if self.geocon else "a Markdown page GeoCon did not write"
        if self.kind == "json" and self.format is not None:
            what = FORMATS.get(self.format.split("/")[0])
            return f"GeoCon's {what} ({self.format})" if what else f"a JSON file of the format {self.format}"
        return {
            "json": "a JSON file GeoCon did not make",
            "video": "a video",
            "special": "not a regular file",
            "nothing": "nothing",
        }.get(self.kind, "a file GeoCon did not make")


_FORMAT = re.compile(rb'"format"\s*:\s*"([^"\\]{1,64})"')
MARKDOWN_TITLES = (b"# GeoCon validation report\n", b"# Clip model ")
"""The first line of each Markdown page GeoCon writes (``validation.md``, ``fit.md``)."""
_VIDEO_MAGIC = (b"\x1aE\xdf\xa3", b"RIFF", b"GIF8", b"\x00\x00\x01\xba", b"\x00\x00\x01\xb3")


def held(path: Path) -> Held:
    """What ``path`` holds (:class:`Held`; a link is followed). A file's kind is told from at most
    :data:`SNIFF_BYTES` of its head; a device, a FIFO or a socket is never opened."""
    path = Path(path)
    st = _stat(path)
    if st is None:
        return Held(path, "nothing")
    if stat.S_ISDIR(st.st_mode):
        return Held(path, "folder", folder=folder_kind(path))
    if not stat.S_ISREG(st.st_mode):
        return Held(path, "special")
    head = _head(path, SNIFF_BYTES)
    if head[:4] in RRD_MAGIC:
        return Held(path, "recording", geocon=GEOCON_APP_ID in head[:RRD_HEAD_BYTES])
    if head.startswith(PNG_MAGIC):
        return Held(path, "png", geocon=GEOCON_PNG_TEXT in head[:RRD_HEAD_BYTES])
    if head[4:8] == b"ftyp" or head.startswith(_VIDEO_MAGIC):
        return Held(path, "video")
    if head.startswith(b"# "):
        return Held(path, "markdown", geocon=head.startswith(MARKDOWN_TITLES))
    if head.lstrip()[:1] == b"{":
        data = None
        if len(head) < SNIFF_BYTES:
            try:
                loaded = json.loads(head.decode("utf-8"))
                data = loaded if isinstance(loaded, dict) else None
            except (UnicodeError, ValueError, RecursionError):
                data = None
        if data is not None:
            fmt = data.get("format") if isinstance(data.get("format"), str) else None
        else:
            found = _FORMAT.search(head[:4096])
            fmt = found.group(1).decode("ascii", "replace") if found else None
        geocon = fmt is not None and fmt.split("/")[0] in FORMATS
        return Held(path, "json", geocon=geocon, format=fmt, data=data)
    return Held(path, "file")


def _within(path: Path, folder: Path) -> bool:
    p, f = Path(os.path.realpath(path)), Path(os.path.realpath(folder))
    return p == f or f in p.parents


def _shown(folder: Path, path: Path) -> str:
    """``folder`` (resolved) as the user wrote it: the ancestor of ``path`` as given that is it."""
    for at in Path(os.path.normpath(path)).parents:
        if str(at) not in ("", ".") and os.path.realpath(at) == str(folder):
            return str(at)
    return str(folder)


def _part_of(option: str, path: Path, own: Sequence[Path]) -> None:
    """Refuse ``path`` when it is, or lies inside, a part of a GeoCon folder the command does not
    own. Inside an ``own`` folder only GeoCon folders below that one are looked at."""
    full = Path(os.path.realpath(path))
    mine = [Path(os.path.realpath(o)) for o in own if _within(full, o)]
    for kind, folder in folders_above(path):
        if any(folder == o or folder in o.parents for o in mine):
            return  # the command's own folder, or one above it: the rest is the owner's business
        first = full.relative_to(folder).parts[0]
        parts = FOLDER_KINDS[kind].parts
        if parts is None or first in parts:
            name = _shown(folder, path)
            if parts is None:
                where = f"lies inside {name}, {FOLDER_KINDS[kind].phrase}, which is replaced whole"
            else:
                where = f"{'is' if full.parent == folder else 'lies inside'} the {first} of {name}, "
                where += FOLDER_KINDS[kind].phrase
            raise _refusal(
                f"{option} {path} {where}; GeoCon never writes over or into another output's files: choose a path "
                "outside it"
            )


def _refusal(sentence: str) -> ValueError:
    return OutPathError(sentence)


Mine = Callable[[Held], "str | None"]
"""A writer's test of an existing output of its own kind: None when it was made for the same
input (so it may be replaced), else a phrase saying what it was made for (``the record of
a.mp4, not of b.mp4``)."""


def claim(
    option: str,
    path: Path,
    want: str,
    *,
    own: Sequence[Path] = (),
    mine: Mine | None = None,
    example: str | None = None,
) -> None:
    """Refuse, before any work, to write output ``want`` at ``path`` (one sentence naming
    ``option``, as :class:`~geocon_core.files.paths.OutPathError`) unless the command owns it.

    ``want`` is a folder kind of :data:`FOLDER_KINDS`, ``"folder"`` (a plain folder that takes
    files of its own: synthetic clips, planted clips, a cache), or a file kind: ``"recording"``
    (a Rerun recording), ``"png"`` (a screenshot) or ``"json:<format>"`` (a GeoCon JSON file of
    that format, e.g. ``json:geocon-pose``), ``"json"`` (a JSON file GeoCon writes without a
    format: a sidecar; ``mine`` says whether one is GeoCon's). Refused:

    - ``path`` is, or lies inside, a part of a GeoCon folder not in ``own`` (the folders the
      command writes as their owner: the record it renders, the results it reports on);
    - a folder ``want`` that is a GeoCon folder of another kind, or a plain folder holding, under
      the names of ``want``'s parts, entries that are not GeoCon's (a user's ``clips/``);
    - an existing file that is not of ``want``'s kind made by GeoCon, a folder where a file goes;
    - an existing output of ``want``'s kind for which ``mine`` returns a phrase (another input)."""
    path = Path(path)
    _part_of(option, path, own)
    there = held(path)
    if there.kind == "nothing" or there.kind == "special":  # a device is refuse_special's to say
        return
    if want in FOLDER_KINDS or want == "folder":
        _claim_folder(option, path, want, there, mine)
        return
    if there.kind == "folder":
        name = example or "out"
        raise _refusal(f"{option} {path} is a folder; give a file name (e.g. {path / name})")
    kind, _, fmt = want.partition(":")
    same_kind = there.kind == kind and (there.geocon or (kind == "json" and not fmt))
    if fmt:
        same_kind = same_kind and there.format is not None and there.format.split("/")[0] == fmt
    if not same_kind:
        raise _refusal(
            f"{option} {path} exists and is {there.describe()}, not {_want_phrase(want)}; GeoCon replaces a file "
            "only with a newer one of its own kind made for the same input: move it away or choose another path"
        )
    other = mine(there) if mine is not None else None
    if other is not None:
        raise _refusal(
            f"{option} {path} holds {other}; GeoCon replaces only its own earlier output for the same input: "
            f"choose another path (or remove {path})"
        )


def _want_phrase(want: str) -> str:
    kind, _, fmt = want.partition(":")
    if kind == "recording":
        return "a Rerun recording made by GeoCon"
    if kind == "png":
        return "a screenshot GeoCon saved"
    if kind == "markdown":
        return "a Markdown page GeoCon wrote"
    if fmt:
        return f"GeoCon's {FORMATS.get(fmt, fmt)}"
    return "a JSON file GeoCon wrote"


def _claim_folder(option: str, path: Path, want: str, there: Held, mine: Mine | None) -> None:
    if there.kind != "folder":
        return  # a file where a folder goes: check_out_dir's sentence
    if there.folder is not None and there.folder != want:
        raise _refusal(
            f"{option} {path} is {FOLDER_KINDS[there.folder].phrase} (it holds {FOLDER_KINDS[there.folder].marker}), "
            f"not {_folder_phrase(want)}, and GeoCon never mixes one output with another's files; choose another "
            f"{option}"
        )
    if there.folder is None and want in FOLDER_KINDS:
        parts = FOLDER_KINDS[want].parts
        try:
            names = os.listdir(path) if parts is None else [n for n in parts if os.path.lexists(path / n)]
        except OSError:
            names = []
        for name in names:  # a device among them has a sentence of its own
            refuse_special(path / name)
        taken = sorted(names)[:3]
        if taken:
            raise _refusal(
                f"{option} {path} holds {', '.join(taken)}, which {_folder_phrase(want)} would write over, and is "
                f"not one of GeoCon's (it holds no {FOLDER_KINDS[want].marker} GeoCon wrote); choose a new or empty "
                "folder"
            )
    if there.folder == want and mine is not None:
        other = mine(there)
        if other is not None:
            raise _refusal(
                f"{option} {path} holds {other}; GeoCon replaces only its own earlier output for the same input: "
                f"choose another {option} (or remove {path})"
            )


def _folder_phrase(want: str) -> str:
    return FOLDER_KINDS[want].phrase if want in FOLDER_KINDS else "a folder for this command's files"


def stamp_png(data: bytes) -> bytes:
    """``data`` (a PNG) with GeoCon's ``tEXt`` chunk (:data:`GEOCON_PNG_TEXT`) after its header,
    so that a later screenshot may replace it and nothing else; ``data`` as it is when it is no
    PNG or already carries the chunk."""
    if not data.startswith(PNG_MAGIC) or GEOCON_PNG_TEXT in data[:RRD_HEAD_BYTES]:
        return data
    (length,) = struct.unpack(">I", data[8:12])
    end = 8 + 12 + length  # the IHDR chunk: length, type, data, CRC
    chunk = b"tEXt" + GEOCON_PNG_TEXT
    text = struct.pack(">I", len(GEOCON_PNG_TEXT)) + chunk + struct.pack(">I", zlib.crc32(chunk) & 0xFFFFFFFF)
    return data[:end] + text + data[end:]
