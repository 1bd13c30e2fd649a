"""Benchmark datasets (SPEC section 6): the clips of ``geocon bench`` and their metadata, read from
one of three layouts (``docs/datasets.md``).

**Sidecars.** Every ``<name>.meta.json`` below the dataset folder (any depth) describes one clip::

    {"clip_id": "sora-0007", "prompt": "...", "model": "sora", "model_version": "2025-03",
     "seed": 7, "resolution": [1280, 720], "fps": 24, "duration": 5.0,
     "masks_path": "sora-0007.masks" | null, "category": "C3" | null, "scene_id": "kitchen-07",
     "video": "sora-0007.mp4"}

``video`` is optional: without it the clip is ``<name>.<ext>`` (:data:`VIDEO_SUFFIXES`) or a
folder ``<name>/`` of PNG/JPEG frames next to the sidecar. ``masks_path`` (external object masks,
see :mod:`geocon_core.masks`) and ``video`` are relative to the sidecar's folder. ``category`` is the
expected family C1-C6, or null: not given, the scorer's category stands in and the clip has no
expected gate; ``prompt`` is null for a clip without one, ``duration`` null when unknown; ``model``
is the platform; ``scene_id`` is shared by the clips of one seed/scene across platforms. Extra keys
are kept and ignored.

**Manifest.** ``manifest.csv`` or ``manifest.jsonl`` in the dataset folder, or the path of any
``.csv`` / ``.jsonl`` file: one row per clip, a ``path`` (or ``video``) column relative to the
manifest and optional ``clip_id``, ``model`` (or ``platform``; default: the name of the folder
holding the clip file), ``prompt``, ``category``, ``seed``, ``scene_id``, ``masks_path``,
``model_version``; other columns are kept as extra keys. A malformed row (an unclosed CSV quote, a
JSONL line that is not one object) is refused with its line.

**Plain folder.** No sidecar and no manifest: every video file below the folder is a clip, its
platform the sub-folder it lies in (:func:`platform_of`), its id ``<platform>-<file stem>``
(:func:`clip_ids`), its prompt the file name where that reads as one (:func:`prompt_from_name`),
its scene shared with the other platforms' clips of the same prompt and index (:func:`scene_ids`).
Every other file it holds is named in a note with the reason it is not a clip.

**Paths.** A clip or masks path of a sidecar or a manifest must lie inside the dataset folder (a
manifest's: its folder) or a folder given as ``roots`` (``--root``); any other is refused.

Whatever a manifest or a plain folder does not give is filled by these stated rules or left
empty, and each entry records where every field came from (:data:`SOURCES`); a category is never
guessed. When sidecars exist they describe the dataset and a manifest beside them is ignored (with
a note). :func:`scan_dataset` validates everything up front and raises :class:`DatasetError`
listing every problem at once, each with its file (and manifest line); :func:`write_sidecars`
writes the sidecars of a manifest or a plain folder, for people who want to edit them.
"""

from __future__ import annotations

import csv
import io
import json
import os
import re
from collections import defaultdict
from contextlib import suppress
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable

from ..files import MANIFEST, SIDECAR, FileKind, ReadRefused, read_text, special_file
from ..media import ClipError, check_clip
from .layout import MANIFEST_NAME as RESULTS_MANIFEST  # marks a results folder of `geocon bench`

__all__ = [
    "CATEGORIES",
    "EXPECTED_MODEL",
    "LAYOUTS",
    "MANIFEST_NAMES",
    "REQUIRED_FIELDS",
    "SOURCES",
    "VIDEO_SUFFIXES",
    "ClipEntry",
    "Dataset",
    "DatasetError",
    "SidecarsWritten",
    "clip_ids",
    "expected_model",
    "load_dataset",
    "platform_of",
    "prompt_from_name",
    "sanitise_clip_id",
    "scan_dataset",
    "scene_ids",
    "write_sidecars",
]

CATEGORIES = ("C1", "C2", "C3", "C4", "C5", "C6")
"""The scene categories of SPEC section 5 a dataset may give."""
EXPECTED_MODEL = {"C1": "H", "C2": "H", "C4": "H", "C3": "F", "C5": "F", "C6": "F"}
"""The expected rule (SPEC section 6): the background model each category should gate to."""


def expected_model(category: object) -> str | None:
    """The family a clip of ``category`` should be gated to (:data:`EXPECTED_MODEL`), or None for
    a missing or unknown category."""
    return EXPECTED_MODEL.get(category) if isinstance(category, str) else None


REQUIRED_FIELDS = (
    "clip_id",
    "prompt",
    "model",
    "model_version",
    "seed",
    "resolution",
    "fps",
    "duration",
    "masks_path",
    "category",
    "scene_id",
)
"""The fields of a clip's metadata (a sidecar, a manifest row); those not given get stated defaults."""
VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".webm", ".gif", ".mkv", ".m4v", ".mpg", ".mpeg", ".ts", ".mts", ".m2ts")
"""File suffixes (lower case) a plain folder is scanned for (a ``.ts`` / ``.mts`` / ``.m2ts`` file
only when it is an MPEG transport stream)."""
_CLIP_ID = re.compile(r"[A-Za-z0-9][A-Za-z0-9._+=-]{0,199}")
"""A clip id names its results folder: a letter or digit, then letters, digits and ``. _ + = -``
(never ``.`` or ``..``, nor a line break), at most 200 characters (matched whole: ``fullmatch``)."""
_ID_RULE = (
    "must start with a letter or a digit and hold only letters, digits and . _ + = - (at most 200 characters; it "
    "names the result folder)"
)
NAME_MAX = 255
"""Bytes in a file name on common file systems; a sidecar's name is kept within it."""
MAX_FIELD_CHARS = 65_536
"""A field of a clip's metadata (a prompt, a path, an extra column) or a column's name holds at
most this many characters (the longest prompts of today's generators hold a few thousand): a
longer one is refused with its file and line, before anything is checked or shown."""
MAX_ROW_CHARS = 1 << 20
"""A line of a manifest (a CSV row, a JSONL object) holds at most this many characters."""
_SHORTEN = f"shorten its fields (each holds at most {MAX_FIELD_CHARS} characters)"
LAYOUTS = ("sidecars", "manifest", "folder")
"""How a dataset describes its clips: a sidecar per clip, one manifest, or nothing but the files."""
MANIFEST_NAMES = ("manifest.csv", "manifest.jsonl")
"""The manifest a dataset folder without sidecars is read from."""
SOURCES = ("sidecar", "manifest", "folder", "file name", "clip file", "default")
"""Where a field's value came from: the clip's sidecar, the manifest, the platform folder, the
clip's file name, the clip file itself (resolution, frame rate, duration), or a stated default."""


class DatasetError(ValueError):
    """A dataset that cannot be benchmarked; ``problems`` lists every problem, one line each (the
    message is that line when there is one, else a count followed by the list)."""

    def __init__(self, root: Path, problems: list[str]) -> None:
        self.problems = problems
        if len(problems) == 1:
            super().__init__(f"the dataset cannot be benchmarked: {problems[0]}")
            return
        head = f"{root}: {len(problems)} problems in the dataset"
        super().__init__(head + ":\n" + "\n".join(f"  - {p}" for p in problems))


@dataclass(frozen=True)
class ClipEntry:
    """One validated clip of a dataset: absolute paths and its metadata in the sidecar's form.

    ``sidecar``: the sidecar it was read from, or where :func:`write_sidecars` writes it.
    ``sources``: field name -> where its value came from (:data:`SOURCES`)."""

    clip_id: str
    video: Path
    masks: Path | None
    sidecar: Path
    meta: dict[str, Any]
    sources: dict[str, str] = field(default_factory=dict)

    @property
    def model(self) -> str:
        return str(self.meta["model"])

    @property
    def category(self) -> str | None:
        """The expected family C1-C6, or None where none was given (the scorer's stands in)."""
        cat = self.meta.get("category")
        return None if cat is None else str(cat)

    @property
    def scene_id(self) -> str:
        return str(self.meta["scene_id"])


@dataclass(frozen=True)
class Dataset:
    """The clips of a dataset (sorted by clip id), how it was laid out (:data:`LAYOUTS`) and the
    sentences that state the defaults and renamings applied."""

    root: Path
    layout: str
    entries: tuple[ClipEntry, ...]
    notes: tuple[str, ...] = ()


# ---- naming rules (plain folders and manifests) ------------------------------------------------

_NOT_ID = re.compile(r"[^A-Za-z0-9._+=-]+")
_MAX_ID = 190
"""Generated ids stop here, leaving room for a collision number within the 200 characters allowed."""
_TRAILING_INDEX = re.compile(r"^(.*?)[-_ ]+(\d+)$")
_WORD_EDGE = ",.;:!?\"'()[]"
_LETTERS = re.compile(r"[^\W\d_]+(?:['\u2019-][^\W\d_]+)*")
"""A word of letters; an apostrophe or a hyphen may join two (``dog's``, ``close-up``)."""
MIN_PROMPT_WORDS = 3
"""A file name reads as a prompt with at least this many words of letters (``clip_0007`` does not)."""


def sanitise_clip_id(text: str) -> str:
    """``text`` made a valid clip id: every run of characters other than letters, digits and
    ``. _ + = -`` becomes one ``-`` (and so does a run of ``-``), leading punctuation and trailing
    ``-`` are dropped, and at most :data:`_MAX_ID` characters are kept; ``clip`` when nothing is left.

    >>> sanitise_clip_id("modelA-A cat playing piano, at night-0")
    'modelA-A-cat-playing-piano-at-night-0'
    """
    out = re.sub(r"-{2,}", "-", _NOT_ID.sub("-", text))
    out = re.sub(r"^[^A-Za-z0-9]+", "", out)[:_MAX_ID].rstrip("-")
    return out or "clip"


def prompt_from_name(stem: str) -> tuple[str | None, int | None]:
    """The prompt a file name (without suffix) spells, and its trailing index: the number after a
    last ``-``, ``_`` or space, stripped. The rest reads as a prompt when its words (split at
    spaces, or at ``-`` and ``_`` where it has no space) are letters or numbers, at least
    :data:`MIN_PROMPT_WORDS` of them letters; otherwise the clip has no prompt (None).

    >>> prompt_from_name("a-cat-playing-piano-0")
    ('a cat playing piano', 0)
    >>> prompt_from_name("A close-up of a dog, running-3")
    ('A close-up of a dog, running', 3)
    >>> prompt_from_name("clip_0007")
    (None, 7)
    >>> prompt_from_name("00012")
    (None, None)
    """
    m = _TRAILING_INDEX.match(stem)
    body, index = (m[1], int(m[2])) if m else (stem, None)
    text = body if " " in body else re.sub(r"[-_]+", " ", body)
    text = " ".join(text.split())
    words = [w.strip(_WORD_EDGE) for w in text.split(" ")]
    letters = sum(1 for w in words if _LETTERS.fullmatch(w))
    numbers = sum(1 for w in words if w.isdigit())
    if letters < MIN_PROMPT_WORDS or letters + numbers < len([w for w in words if w]):
        return None, index
    return text, index


def platform_of(rel: Path, default: str) -> tuple[str, str]:
    """The platform of the clip at ``rel`` (relative to the dataset folder) and its source: the
    top folder it lies in (``folder``), or ``default`` for a clip directly in the dataset folder."""
    return (rel.parts[0], "folder") if len(rel.parts) > 1 else (default, "default")


def clip_ids(names: list[str], taken: Iterable[str] = ()) -> list[str]:
    """Valid, unique clip ids for ``names`` (each ``<platform>-<stem>``), in order: sanitised
    (:func:`sanitise_clip_id`), and an id met before (in ``taken`` or earlier in ``names``, letter
    case aside: results folders may live on a file system that ignores it) numbered ``_2``, ``_3``..."""
    seen = {t.casefold() for t in taken}
    out = []
    for name in names:
        base = sanitise_clip_id(name)
        cid, k = base, 1
        while cid.casefold() in seen:
            k += 1
            cid = f"{base}_{k}"
        seen.add(cid.casefold())
        out.append(cid)
    return out


def scene_ids(clips: list[tuple[str, str, str | None, object]]) -> list[str]:
    """The scene of each clip ``(clip_id, platform, prompt, index)``: clips of several platforms
    with the same prompt and index are one scene, ``<prompt> #<index>`` (``<prompt>`` without an
    index); any other clip is a scene of its own, named by its clip id."""
    platforms: dict[tuple[str, object], set[str]] = defaultdict(set)
    for _, platform, prompt, index in clips:
        if prompt is not None:
            platforms[(prompt, index)].add(platform)
    out = []
    for cid, _, prompt, index in clips:
        if prompt is not None and len(platforms[(prompt, index)]) > 1:
            out.append(prompt if index is None else f"{prompt} #{index}")
        else:
            out.append(cid)
    return out


# ---- sidecars ----------------------------------------------------------------------------------


def _find_video(sidecar: Path, meta: dict[str, Any]) -> Path | None:
    if meta.get("video"):
        return sidecar.parent / str(meta["video"])
    stem = sidecar.name[: -len(".meta.json")]
    for suffix in VIDEO_SUFFIXES:
        cand = sidecar.parent / f"{stem}{suffix}"
        if cand.exists() and not cand.is_dir():  # a FIFO or a device is the clip meant, refused when checked
            return cand
    folder = sidecar.parent / stem
    return folder if folder.is_dir() else None


def _long_fields(where: str, meta: dict[str, Any]) -> list[str]:
    """The problems of a sidecar's or a manifest row's fields (names and text values) longer than
    :data:`MAX_FIELD_CHARS`."""
    problems = []
    for key, value in meta.items():
        if len(str(key)) > MAX_FIELD_CHARS:
            problems.append(
                f"{where}: a field name of {len(str(key))} characters ({str(key)[:20]}...) is longer than the "
                f"{MAX_FIELD_CHARS} characters a field of a clip may hold"
            )
        elif isinstance(value, str) and len(value) > MAX_FIELD_CHARS:
            problems.append(
                f"{where}: {key} holds {len(value)} characters, more than the {MAX_FIELD_CHARS} a field of a clip may "
                "hold; shorten it"
            )
    return problems


def _field_problems(name: str, meta: dict[str, Any]) -> list[str]:
    long = _long_fields(name, meta)
    if long:
        return long
    problems = []
    missing = [k for k in REQUIRED_FIELDS if k not in meta]
    if missing:
        problems.append(f"{name}: missing field{'s' if len(missing) > 1 else ''} {', '.join(missing)}")
    cid = meta.get("clip_id")
    if "clip_id" in meta and not isinstance(cid, str):
        problems.append(f"{name}: clip_id {cid!r} must be text: {_ID_RULE.removeprefix('must ')}")
    elif isinstance(cid, str) and not _CLIP_ID.fullmatch(cid):
        problems.append(f"{name}: clip_id {cid!r} {_ID_RULE}")
    for key in ("model", "scene_id"):
        if key in meta and (meta[key] is None or str(meta[key]).strip() == ""):
            problems.append(f"{name}: {key} is empty")
    if "prompt" in meta and meta["prompt"] is not None and not isinstance(meta["prompt"], str):
        problems.append(f"{name}: prompt must be text or null, got {meta['prompt']!r}")
    elif "prompt" in meta and meta["prompt"] is not None and str(meta["prompt"]).strip() == "":
        problems.append(f"{name}: prompt is empty (write null for a clip without a prompt)")
    if meta.get("category") is not None and meta["category"] not in CATEGORIES:
        problems.append(
            f"{name}: unknown category {meta['category']!r} (expected one of {', '.join(CATEGORIES)}, or null for "
            "the scorer's)"
        )
    if "fps" in meta and not (
        isinstance(meta["fps"], (int, float)) and not isinstance(meta["fps"], bool) and meta["fps"] > 0
    ):
        problems.append(f"{name}: fps must be a positive number, got {meta['fps']!r}")
    dur = meta.get("duration")
    if dur is not None and not (isinstance(dur, (int, float)) and not isinstance(dur, bool) and dur >= 0):
        problems.append(f"{name}: duration must be a non-negative number (seconds) or null, got {dur!r}")
    res = meta.get("resolution")
    if "resolution" in meta and not (
        isinstance(res, list) and len(res) == 2 and all(isinstance(v, int) and v > 0 for v in res)
    ):
        problems.append(f"{name}: resolution must be [width, height] in pixels, got {res!r}")
    if "seed" in meta and meta["seed"] is not None and not isinstance(meta["seed"], (int, str)):
        problems.append(f"{name}: seed must be an integer or a string, got {meta['seed']!r}")
    if "masks_path" in meta and meta["masks_path"] is not None and not isinstance(meta["masks_path"], str):
        problems.append(f"{name}: masks_path must be a path or null, got {meta['masks_path']!r}")
    return problems


def _read_text(path: Path, name: str, kind: FileKind, what: str) -> tuple[str | None, str]:
    """The text of a sidecar or a manifest at ``path`` (``name``: how problems name it; ``kind``:
    its size bound; ``what``: what it should be, for a folder in its place), a byte-order mark
    dropped (:func:`geocon_core.files.read_text`: a regular file no larger than the bound of its
    kind); or None and the problem: a folder, a FIFO or a device or a link to nothing in its place,
    a file past the bound, or bytes that are not UTF-8 text."""
    try:
        return read_text(path, kind, name), ""
    except ReadRefused as exc:
        if exc.reason == "folder":
            return None, f"{name}: is a folder, not {what}; rename it"
        return None, str(exc)


def _read_sidecar(sidecar: Path, name: str) -> tuple[dict[str, Any] | None, str]:
    """The parsed sidecar, or None and the problem with it."""
    from ..files import strict_json

    text, problem = _read_text(
        sidecar,
        name,
        SIDECAR,
        "a sidecar file (every *.meta.json below the dataset folder is read as a clip's sidecar)",
    )
    if text is None:
        return None, problem
    try:
        meta = strict_json(text, name, constants=False)
    except json.JSONDecodeError as exc:
        return None, f"{name}: not valid JSON ({exc.msg} at line {exc.lineno})"
    except ValueError as exc:
        return None, str(exc)
    if not isinstance(meta, dict):
        return None, f"{name}: must hold a JSON object"
    return meta, ""


def _video_problems(
    name: str, sidecar: Path, meta: dict[str, Any], video: Path | None, check_clips: bool, allowed: tuple[Path, ...]
) -> list[str]:
    """What is wrong with a sidecar's clip file (outside the ``allowed`` folders, missing, or with
    ``check_clips`` unreadable)."""
    if video is None:
        return [
            f"{name}: no clip file next to it (expected {sidecar.name[: -len('.meta.json')]}.mp4 or another "
            "video, or a 'video' field)"
        ]
    outside = _outside_problem(name, f"clip file {meta.get('video')}", video, allowed)
    if outside is not None:
        return [outside]
    if not video.exists():
        return [_missing(name, "clip file", meta.get("video"))]
    if check_clips:
        try:
            check_clip(video)
        except ClipError as exc:
            return [f"{name}: unreadable clip ({exc})"]
    return []


def _missing(where: str, what: str, value: object) -> str:
    """The problem of a clip or masks path (``what``) that names nothing, saying what a path
    written for another machine looks like: a URL, or Windows separators."""
    text = str(value)
    hint = ""
    if re.match(r"[A-Za-z][A-Za-z0-9+.-]*://", text):
        hint = " (it is a URL; GeoCon reads local files only: download the clips and name the files)"
    elif "\\" in text:
        hint = f" (paths are written with /; this one has \\ as on Windows: {text.replace(chr(92), '/')})"
    return f"{where}: {what} {text} does not exist{hint}"


def _allowed_folders(own: Path, roots: Iterable[str | Path]) -> tuple[Path, ...]:
    """The folders a dataset's paths may point into: its ``own`` folder first, then ``roots``
    (absolute and normalised, links not followed)."""
    return tuple(Path(os.path.normpath(os.path.abspath(p))) for p in (own, *roots))


def _outside_problem(where: str, what: str, path: Path, allowed: tuple[Path, ...]) -> str | None:
    """The problem of a clip or masks ``path`` (``what``: how the row names it) that lies outside
    every ``allowed`` folder, or None. Judged by the path as written, so a link inside the dataset
    folder to a clip elsewhere is inside: the rule keeps a mistyped or hostile path (``/etc``) from
    being read, not a dataset from linking to its files."""
    at = Path(os.path.normpath(os.path.abspath(path)))
    if any(at == folder or folder in at.parents for folder in allowed):
        return None
    roots = f" or the --root folder(s) {', '.join(map(str, allowed[1:]))}" if len(allowed) > 1 else ""
    return (
        f"{where}: {what} lies outside the dataset folder {allowed[0]}{roots}; move it inside, or name the folder it "
        "lies in with --root"
    )


def _masks_problems(where: str, value: str, masks: Path, allowed: tuple[Path, ...], check: bool) -> list[str]:
    """What is wrong with the masks a row names as ``value`` (at ``masks``): outside the
    ``allowed`` folders, missing, or with ``check`` not a masks layout
    (:func:`geocon_core.masks.check_masks_path`)."""
    outside = _outside_problem(where, f"masks_path {value}", masks, allowed)
    if outside is not None:
        return [outside]
    if not masks.exists():
        return [_missing(where, "masks_path", value)]
    if check:
        from ..masks import check_masks_path

        try:
            check_masks_path(masks)
        except (ValueError, OSError) as exc:
            return [f"{where}: masks_path {value} is not usable ({exc})"]
    return []


Progress = Callable[[int, int], None]
"""Called as ``progress(checked, total)`` after each clip is checked."""


def _from_sidecars(
    base: Path, sidecars: list[Path], check_clips: bool, progress: Progress | None, allowed: tuple[Path, ...]
) -> Dataset:
    problems: list[str] = []
    entries: list[ClipEntry] = []
    seen: dict[str, Path] = {}
    videos: dict[tuple[int, int], Path] = {}
    for i, sidecar in enumerate(sidecars):
        name = str(sidecar.relative_to(base))
        meta, problem = _read_sidecar(sidecar, name)
        if meta is None:
            problems.append(problem)
            continue
        mine = _field_problems(name, meta)
        cid = meta.get("clip_id")
        if isinstance(cid, str) and cid.casefold() in seen:  # results folders may ignore letter case
            mine.append(f"{name}: clip_id {cid!r} is also used by {seen[cid.casefold()].relative_to(base)}")
        video = _find_video(sidecar, meta)
        mine += _video_problems(name, sidecar, meta, video, check_clips, allowed)
        if progress is not None:
            progress(i + 1, len(sidecars))
        if video is not None and video.exists():
            st = video.stat()
            first = videos.setdefault((st.st_dev, st.st_ino), sidecar)
            if first != sidecar:
                mine.append(
                    f"{name}: names the same clip file as {first.relative_to(base)} ({video.name}); one clip, one "
                    "sidecar (a clip scored twice would count twice in every table)"
                )
        masks = None
        if isinstance(meta.get("masks_path"), str):
            masks = sidecar.parent / meta["masks_path"]
            mine += _masks_problems(name, meta["masks_path"], masks, allowed, check_clips)
        if mine:
            problems.extend(mine)
            continue
        assert isinstance(cid, str) and video is not None  # checked by _field_problems and above
        seen[cid.casefold()] = sidecar
        entries.append(
            ClipEntry(
                clip_id=cid,
                video=video.resolve(),
                masks=None if masks is None else masks.resolve(),
                sidecar=sidecar.resolve(),
                meta=meta,
                sources=dict.fromkeys(meta, "sidecar"),
            )
        )
    if problems:
        raise DatasetError(base, problems)
    notes = []
    known = {e.video.resolve() for e in entries}
    masks = {e.masks.resolve() for e in entries if e.masks is not None}
    loose = []
    for p in _clip_files(base)[0]:
        at = p.resolve()
        if at not in known and masks.isdisjoint((at, *at.parents)):  # a masks folder is no clip
            loose.append(p)
    if loose:
        notes.append(
            f"{len(loose)} clip(s) below {base} have no sidecar and are not part of the dataset (e.g. "
            f"{loose[0].relative_to(base)}); give them sidecars to include them"
        )
    return Dataset(base, "sidecars", tuple(sorted(entries, key=lambda e: e.clip_id)), tuple(notes))


# ---- manifests ---------------------------------------------------------------------------------

_ALIASES = {"path": "video", "video": "video", "platform": "model", "model": "model"}
"""Manifest columns and the sidecar field they fill (``path`` or ``video``, ``model`` or ``platform``)."""
_TEXT_FIELDS = ("clip_id", "model", "prompt", "scene_id", "model_version", "category", "masks_path", "video")


def _jsonl_rows(text: str, name: str) -> tuple[list[tuple[str, dict[str, Any]]], list[str]]:
    """``(where, object)`` per non-blank line of a JSONL manifest, and the lines that are not one."""
    from ..files import strict_json

    rows, problems = [], []
    for n, line in enumerate(text.splitlines(), 1):
        if not line.strip():
            continue
        where = f"{name} line {n}"
        if len(line) > MAX_ROW_CHARS:
            problems.append(
                f"{where}: holds {len(line)} characters, more than the {MAX_ROW_CHARS} a row may hold; {_SHORTEN}"
            )
            continue
        try:
            row = strict_json(line, where, constants=False)
        except json.JSONDecodeError as exc:
            problems.append(f"{where}: not valid JSON ({exc.msg})")
            continue
        except ValueError as exc:
            problems.append(str(exc))
            continue
        if not isinstance(row, dict):
            problems.append(f"{where}: must hold a JSON object (one clip per line)")
            continue
        rows.append((where, row))
    return rows, problems


def _csv_rows(text: str, name: str) -> tuple[list[tuple[str, dict[str, Any]]], list[str]]:
    """``(where, cells)`` per row of a CSV manifest (column names stripped and lower-cased), and
    the problems of its form; a manifest without a path column is refused as a whole. A quote
    that is never closed (it would swallow the rows after it into one cell) or text after a
    closing quote is refused with the line the row starts on, and so is a row that runs over
    several lines (a quoted cell may hold line breaks) but has fewer cells than columns: the mark
    of a quote closed rows later. A line longer than :data:`MAX_ROW_CHARS` is refused before the
    rows are read."""
    lines = text.split("\n")  # as the reader counts them
    long = next((n for n, line in enumerate(lines, 1) if len(line) > MAX_ROW_CHARS), None)
    if long is not None:
        held = len(lines[long - 1])
        return [], [
            f"{name} line {long}: holds {held} characters, more than the {MAX_ROW_CHARS} a row may hold; {_SHORTEN}"
        ]
    reader = csv.DictReader(io.StringIO(text), strict=True)
    try:
        fieldnames = reader.fieldnames
    except csv.Error as exc:
        return [], [_csv_problem(f"{name} line 1", exc)]
    columns = [c.strip().lower() for c in fieldnames or []]
    named = _long_fields(f"{name} line 1", dict.fromkeys(columns))
    if named:
        return [], named[:1]
    if not any(columns):
        return [], [f"{name}: is empty (expected a header row with a 'path' column, then one row per clip)"]
    if "path" not in columns and "video" not in columns:
        other = next((f" (the header is separated by {sep!r}: save the file with commas)" for sep in (";", "\t", "|")
                      if len(columns) == 1 and sep in columns[0]), "")  # fmt: skip
        return [], [
            f"{name}: no 'path' column naming the clip files (or 'video'); its columns are {', '.join(columns)}{other}"
        ]
    dups = sorted({c for c in columns if columns.count(c) > 1})
    if dups:
        return [], [f"{name}: column{'s' if len(dups) > 1 else ''} {', '.join(dups)} given twice"]
    reader.fieldnames = columns
    rows, problems = [], []
    end = reader.line_num  # the last line of the row before
    try:
        for row in reader:
            first = _row_start(lines, end)
            where = f"{name} line {first}"
            end = reader.line_num
            if None in row:
                problems.append(f"{where}: more cells than the {len(columns)} columns")
            elif end > first and any(v is None for v in row.values()):
                problems.append(
                    f"{where}: a quoted cell runs on to line {end} and the row has fewer cells than the "
                    f"{len(columns)} columns (a quote that is not closed where it should be?); close the quote"
                )
            rows.append((where, {k: v for k, v in row.items() if k is not None}))
    except csv.Error as exc:
        problems.append(_csv_problem(f"{name} line {_row_start(lines, end)}", exc))
    return rows, problems


def _row_start(lines: list[str], after: int) -> int:
    """The number of the first line after line ``after`` that is not blank (the CSV reader skips
    blank lines before a row)."""
    k = after
    while k < len(lines) - 1 and not lines[k].strip():
        k += 1
    return k + 1


def _csv_reason(exc: csv.Error) -> str:
    """What a CSV error means, in words."""
    msg = str(exc)
    if "unexpected end of data" in msg:
        return "a quote is opened and never closed, which would read every line after it into one cell"
    if "expected after" in msg:
        return "text follows a closing quote within a cell"
    return msg


def _csv_problem(where: str, exc: csv.Error) -> str:
    """The problem of a CSV error met at ``where`` (a cell past the CSV reader's own bound, which
    lies above :data:`MAX_FIELD_CHARS`, is named as a field too long)."""
    if "field larger than field limit" in str(exc):
        return (
            f"{where}: a cell holds more than the {MAX_FIELD_CHARS} characters a field of a clip may hold; shorten it"
        )
    return f"{where}: not valid CSV ({_csv_reason(exc)})"


def _manifest_rows(path: Path, name: str) -> tuple[list[tuple[str, dict[str, Any]]], list[str]]:
    """``(where, fields)`` per clip of a manifest, the aliases mapped to sidecar fields
    (:data:`_ALIASES`) and empty cells None, and the problems of its form."""
    text, problem = _read_text(path, name, MANIFEST, "a manifest file")
    if text is None:
        return [], [problem]
    raw, problems = (_jsonl_rows if path.suffix.lower() == ".jsonl" else _csv_rows)(text, name)
    rows = []
    for where, row in raw:
        long = _long_fields(where, row)
        if long:
            problems += long
            continue
        fields: dict[str, Any] = {}
        for key, value in row.items():
            canon = _ALIASES.get(key, key)
            if canon in fields and key in _ALIASES:
                problems.append(f"{where}: gives both {'path and video' if canon == 'video' else 'model and platform'}")
            fields[canon] = value.strip() or None if isinstance(value, str) else value
        rows.append((where, fields))
    if not raw and not problems:
        problems.append(f"{name}: lists no clips")
    return rows, problems


def _manifest_field_problems(where: str, fields: dict[str, Any]) -> list[str]:
    """What is wrong with the values of one manifest row (files are checked later); numbers given
    for text fields become text, a seed written as digits an integer."""
    problems = []
    if fields.get("video") is None:
        problems.append(f"{where}: no path (the clip file, relative to the manifest)")
    for key in _TEXT_FIELDS:
        value = fields.get(key)
        if isinstance(value, (int, float)) and not isinstance(value, bool) and key not in ("video", "masks_path"):
            fields[key] = str(value)
        elif value is not None and not isinstance(value, str):
            problems.append(f"{where}: {key} must be text, got {value!r}")
    cid = fields.get("clip_id")
    if isinstance(cid, str) and not _CLIP_ID.fullmatch(cid):
        problems.append(f"{where}: clip_id {cid!r} {_ID_RULE}, or be empty for one made from the file name")
    cat = fields.get("category")
    if isinstance(cat, str) and cat not in CATEGORIES:
        problems.append(
            f"{where}: unknown category {cat!r} (expected one of {', '.join(CATEGORIES)}, or empty for the scorer's)"
        )
    seed = fields.get("seed")
    if isinstance(seed, str) and seed.isdigit() and str(int(seed)) == seed:
        fields["seed"] = int(seed)
    elif seed is not None and (isinstance(seed, bool) or not isinstance(seed, (int, str))):
        problems.append(f"{where}: seed must be an integer or text, got {seed!r}")
    return problems


# ---- plain folders -----------------------------------------------------------------------------


def _clip_files(base: Path) -> tuple[list[Path], list[str]]:
    """The clips below ``base`` in path order: video files, and folders of frames (a sub-folder
    holding two or more PNG/JPEG images and no video file; read as one clip, not searched further).
    Hidden files and folders, and ``geocon bench`` results folders, are left out. Also the notes on
    what was left out or read as frames: every other file is named with the reason it is not a
    clip (:func:`_skipped_note`)."""
    from ..media import IMAGE_SUFFIXES

    files: list[Path] = []
    frame_dirs: list[str] = []
    results: list[str] = []
    skipped: list[tuple[str, str]] = []
    for folder, dirs, names in os.walk(base):
        here = Path(folder)
        if RESULTS_MANIFEST in names and here != base:
            results.append(here.relative_to(base).as_posix())
            dirs[:] = []
            continue
        rel = here.relative_to(base)
        for d in sorted(dirs):
            if d.startswith("."):
                skipped.append(((rel / d).as_posix(), "hidden folder"))
            elif (here / d).is_symlink():  # os.walk does not follow links to folders
                skipped.append(((rel / d).as_posix(), "a link to a folder, not followed"))
        dirs[:] = sorted(d for d in dirs if not d.startswith(".") and not (here / d).is_symlink())
        visible = sorted(n for n in names if not n.startswith("."))
        skipped += [((rel / n).as_posix(), "hidden") for n in sorted(names) if n.startswith(".")]
        videos: list[tuple[str, str | None]] = []
        others: list[tuple[str, str | None]] = []
        for n in visible:
            why = _not_a_video(here / n)
            (videos if why is None else others).append((n, why))
        images = sum(Path(n).suffix.lower() in IMAGE_SUFFIXES for n in visible)
        if here != base and images >= 2 and not videos:
            files.append(here)
            frame_dirs.append(rel.as_posix())
            skipped += [((rel / d).as_posix(), "a folder inside a folder of frames") for d in dirs]
            skipped += [
                ((rel / n).as_posix(), "not a frame (a folder of frames is read as one clip)")
                for n in visible
                if Path(n).suffix.lower() not in IMAGE_SUFFIXES
            ]
            dirs[:] = []
            continue
        files += [here / n for n, _ in videos]
        skipped += [((rel / n).as_posix(), str(why)) for n, why in others]
    notes = []
    if results:
        notes.append(f"left out {len(results)} results folder(s) of `geocon bench`: {', '.join(results)}")
    if frame_dirs:
        notes.append(
            f"{len(frame_dirs)} folder(s) of PNG/JPEG frames read as one clip each (e.g. {frame_dirs[0]}), "
            "its id and prompt from the folder's name"
        )
    if skipped:
        notes.append(_skipped_note(sorted(skipped)))
    return sorted(files, key=lambda p: p.relative_to(base).as_posix()), notes


_NOT_CLIP_SUFFIXES = frozenset(
    ".txt .md .rst .json .jsonl .csv .tsv .yaml .yml .toml .xml .html .pdf .log .srt .vtt .npz .npy .parquet "
    ".rrd .pt .pth .ckpt .safetensors .py .sh .ipynb .zip .tar .gz .tgz .7z .wav .mp3 .m4a .aac .flac .ogg".split()
)
"""Suffixes of files that a dataset folder often holds besides its clips (text, data, archives, audio)."""
_TS_SYNC_AT = {".ts": 0, ".mts": 4, ".m2ts": 4}
""".ts / .mts / .m2ts: where an MPEG transport stream's first sync byte (0x47) lies (a .ts file may
as well be TypeScript)."""
SKIPPED_LISTED = 5
"""Up to this many skipped files are named one by one; more are counted by reason, with examples."""


def _not_a_video(path: Path) -> str | None:
    """Why the file at ``path`` is not read as a video clip of a plain folder, or None when it is."""
    from ..media import IMAGE_SUFFIXES

    suffix = path.suffix.lower()
    if not path.is_file():
        return "a link to nothing" if path.is_symlink() and not path.exists() else "not a regular file"
    if suffix in IMAGE_SUFFIXES:
        return "an image, not in a folder of frames"
    if suffix not in VIDEO_SUFFIXES:
        return "not a clip" if suffix in _NOT_CLIP_SUFFIXES else "unknown format"
    at = _TS_SYNC_AT.get(suffix)
    if at is not None:
        try:
            with path.open("rb") as fh:
                head = fh.read(at + 1)
        except OSError as exc:
            return f"cannot be read ({exc.strerror or exc})"
        if len(head) <= at or head[at] != 0x47:
            return "not an MPEG transport stream: no sync byte"
    return None


def _skipped_note(skipped: list[tuple[str, str]]) -> str:
    """The sentence naming the files of a plain folder that are not clips: each with its reason
    when there are few, else a count per reason with two examples each."""
    n = len(skipped)
    head = f"skipped {n} file{'s' if n > 1 else ''}"
    if n <= SKIPPED_LISTED:
        return f"{head}: " + ", ".join(f"{name} ({why})" for name, why in skipped)
    by_reason: dict[str, list[str]] = defaultdict(list)
    for name, why in skipped:
        by_reason[why].append(name)
    parts = [
        f"{len(names)} {why} ({', '.join(names[:2])}{', ...' if len(names) > 2 else ''})"
        for why, names in by_reason.items()
    ]
    return f"{head}: " + "; ".join(parts)


def _clip_stem(path: Path) -> str:
    """What a clip's id and prompt are read from: a file's name without its suffix, or the whole
    name of a folder of frames."""
    return path.name if path.is_dir() else path.stem


# ---- manifests and plain folders: the rules that fill what is not given ------------------------


@dataclass
class _Row:
    """One clip of a manifest or a plain folder before the dataset-wide rules run: where problems
    name it, its clip file, the fields given (a manifest's; none in a plain folder), the platform
    of its folder and that platform's source, and whether its fields passed their checks."""

    where: str
    video: Path
    fields: dict[str, Any]
    platform: str
    platform_source: str
    valid: bool = True


def _clip_facts(video: Path) -> tuple[list[int], float, float | None, str]:
    """``[width, height]``, frame rate and duration in seconds (None when the container states no
    frame count) of a readable clip, and the frame rate's source: the clip file, or the default
    rate for a folder of frames."""
    from ..media import DEFAULT_FPS, container_frame_count, image_frames, open_video, resolve_clip

    name = str(video)
    _, files = resolve_clip(video, name)
    if files is not None:
        h, w = next(image_frames(files[:1], name)).shape[:2]
        return [int(w), int(h)], DEFAULT_FPS, round(len(files) / DEFAULT_FPS, 3), "default"
    fps, frames = open_video(name)
    try:
        h, w = next(iter(frames)).shape[:2]
    finally:
        frames.close()
    count = container_frame_count(name)
    return [int(w), int(h)], float(fps), None if count is None else round(count.frames / fps, 3), "clip file"


def _assign_ids(rows: list[_Row]) -> tuple[list[str], list[str], list[str]]:
    """Each row's clip id (given, or ``<platform>-<stem>`` by :func:`clip_ids`), the problems of
    the given ones (used twice) and the notes on the made ones that were numbered."""
    problems: list[str] = []
    given: dict[str, str] = {}
    for row in rows:
        cid = row.fields.get("clip_id")
        if row.valid and isinstance(cid, str):
            if cid.casefold() in given:
                problems.append(f"{row.where}: clip_id {cid!r} is also used by {given[cid.casefold()]}")
            given.setdefault(cid.casefold(), row.where)
    wanted = [i for i, r in enumerate(rows) if not isinstance(r.fields.get("clip_id"), str)]
    raw = [f"{rows[i].fields.get('model') or rows[i].platform}-{_clip_stem(rows[i].video)}" for i in wanted]
    made = dict(zip(wanted, clip_ids(raw, given), strict=True))
    notes = [
        f"{rows[i].where}: clip id {made[i]} (numbered: another clip's name gives the same id)"
        for i, name in zip(wanted, raw, strict=True)
        if made[i] != sanitise_clip_id(name)
    ]
    return [made[i] if i in made else str(r.fields["clip_id"]) for i, r in enumerate(rows)], problems, notes


def _file_problems(
    row: _Row, masks_base: Path, seen: dict[tuple[int, int], str], allowed: tuple[Path, ...], check_masks: bool
) -> tuple[list[str], Path | None]:
    """What is wrong with a row's clip file and masks (outside the ``allowed`` folders, missing,
    the same file as another row's; with ``check_masks`` masks that are no masks layout), and the
    masks' path."""
    mine = []
    outside = _outside_problem(row.where, f"clip file {row.fields.get('video')}", row.video, allowed)
    if outside is not None:
        mine.append(outside)
    elif not row.video.exists():
        mine.append(_missing(row.where, "clip file", row.fields.get("video")))
    else:
        st = row.video.stat()
        first = seen.setdefault((st.st_dev, st.st_ino), row.where)
        if first != row.where and not row.fields:  # a plain folder: two names of one file
            mine.append(
                f"{row.where}: is the same file as {first} (a hard link or a link to it); one clip, one file: "
                "remove one name (a clip scored twice would count twice in every table)"
            )
        elif first != row.where:
            mine.append(
                f"{row.where}: names the same clip file as {first} ({row.video.name}); one clip, one row (a clip "
                "scored twice would count twice in every table)"
            )
    masks = None
    if isinstance(row.fields.get("masks_path"), str):
        masks = masks_base / row.fields["masks_path"]
        mine += _masks_problems(row.where, row.fields["masks_path"], masks, allowed, check_masks)
    return mine, masks


def _entry(
    row: _Row,
    named: tuple[str, str | None, str | None, str],
    facts: tuple[list[int] | None, float | None, float | None, str],
    masks: Path | None,
    sidecar: Path,
    source: str,
) -> ClipEntry:
    """The entry of a checked row: ``named`` is its clip id, prompt, the prompt its file name
    spells and its scene; ``facts`` what :func:`_clip_facts` read (Nones when clips are not
    checked); ``source`` where the given fields came from."""
    cid, prompt, name_prompt, scene = named
    resolution, fps, duration, fps_source = facts
    f = row.fields
    given = {k for k, v in f.items() if v is not None}
    meta: dict[str, Any] = {
        "clip_id": cid,
        "prompt": prompt,
        "model": f.get("model") or row.platform,
        "model_version": f.get("model_version"),
        "seed": f.get("seed"),
        "resolution": resolution,
        "fps": fps,
        "duration": duration,
        "masks_path": None if masks is None else Path(os.path.relpath(masks, sidecar.parent)).as_posix(),
        "category": f.get("category"),
        "scene_id": f.get("scene_id") or scene,
        "video": Path(os.path.relpath(os.path.abspath(row.video), sidecar.parent)).as_posix(),
    }
    meta.update({k: v for k, v in f.items() if k not in meta})
    fallback = {
        "clip_id": "file name",
        "prompt": "file name" if name_prompt is not None else "default",
        "model": row.platform_source,
        "fps": fps_source if fps is not None else "default",
        "video": source,
    }
    sources = {k: source if k in given else fallback.get(k, "default") for k in meta}
    sources.update({k: "clip file" for k in ("resolution", "duration") if meta[k] is not None})
    return ClipEntry(
        clip_id=cid,
        video=row.video.resolve(),
        masks=None if masks is None else masks.resolve(),
        sidecar=sidecar,
        meta=meta,
        sources=sources,
    )


def _fill(
    rows: list[_Row],
    source: str,
    masks_base: Path,
    check_clips: bool,
    progress: Progress | None,
    allowed: tuple[Path, ...],
) -> tuple[list[ClipEntry], list[str], list[str]]:
    """The entries of ``rows`` (the given fields from ``source``, the rest by the stated rules),
    the problems found, and the notes on the rules applied. A row whose fields failed their checks
    gives only problems (its values of the wrong type take no part in the rules)."""
    ids, problems, notes = _assign_ids(rows)
    named = []
    for row, cid in zip(rows, ids, strict=True):
        given: dict[str, Any] = (
            row.fields if row.valid else {k: v for k, v in row.fields.items() if isinstance(v, (str, int))}
        )
        name_prompt, name_index = prompt_from_name(_clip_stem(row.video))
        prompt = given.get("prompt") or name_prompt
        index = given["seed"] if given.get("seed") is not None else name_index
        named.append((cid, given.get("model") or row.platform, prompt, index, name_prompt))
    scenes = scene_ids([n[:4] for n in named])
    entries: list[ClipEntry] = []
    seen: dict[tuple[int, int], str] = {}
    sidecars: set[Path] = set()
    for k, (row, (cid, _, prompt, _, name_prompt), scene) in enumerate(zip(rows, named, scenes, strict=True)):
        mine, masks = _file_problems(row, masks_base, seen, allowed, check_clips)
        facts: tuple[list[int] | None, float | None, float | None, str] = (None, None, None, "default")
        if check_clips and not mine:
            try:
                check_clip(row.video)
                facts = _clip_facts(row.video)
            except ClipError as exc:
                mine.append(f"{row.where}: unreadable clip ({exc})")
        if progress is not None:
            progress(k + 1, len(rows))
        problems += mine
        if mine or not row.valid:
            continue
        at = Path(os.path.abspath(row.video))
        sidecar = at.parent / _sidecar_name(at.stem)
        if sidecar in sidecars:  # x.mp4 and x.gif side by side
            sidecar = at.parent / _sidecar_name(at.name)
        sidecars.add(sidecar)
        entries.append(_entry(row, (cid, prompt, name_prompt, scene), facts, masks, sidecar, source))
    return entries, problems, notes


def _sidecar_name(stem: str) -> str:
    """``<stem>.meta.json``; for a stem too long for that to be a file name (a legal 250-byte clip
    name) its start and a hash of the whole (the sidecar's ``video`` field names the clip)."""
    from ..files import short_name

    name = f"{stem}.meta.json"
    return name if len(os.fsencode(name)) <= NAME_MAX else f"{short_name(stem)}.meta.json"


def _defaults_notes(entries: list[ClipEntry]) -> list[str]:
    """The sentences that state which defaults the entries took."""
    notes = []
    no_cat = sum(e.category is None for e in entries)
    if no_cat:
        notes.append(
            f"{no_cat} of {len(entries)} clip(s) have no category: the scorer's category stands in for theirs, and "
            "they are left out of the expected-gate statistics (anomaly rates, gate calibration)"
        )
    from_name = sum(e.sources.get("prompt") == "file name" for e in entries)
    no_prompt = sum(e.meta.get("prompt") is None for e in entries)
    if from_name or no_prompt:
        notes.append(f"prompts: {from_name} read from file names, {no_prompt} clip(s) without one")
    shared = {e.scene_id for e in entries if e.sources.get("scene_id") == "default" and e.scene_id != e.clip_id}
    if shared:
        notes.append(f"{len(shared)} scene(s) shared across platforms by prompt and index")
    return notes


def _from_manifest(path: Path, check_clips: bool, progress: Progress | None, roots: Iterable[str | Path]) -> Dataset:
    found, problems = _manifest_rows(path, path.name)
    rows = []
    for where, fields in found:
        mine = _manifest_field_problems(where, fields)
        problems += mine
        if not isinstance(fields.get("video"), str):
            continue
        video = path.parent / fields["video"]
        platform = Path(os.path.abspath(video)).parent.name  # without a model column: the clip's folder
        rows.append(_Row(where, video, fields, platform, "folder", valid=not mine))
    allowed = _allowed_folders(path.parent, roots)
    entries, more, notes = _fill(rows, "manifest", path.parent, check_clips, progress, allowed)
    problems += more
    if problems:
        line = re.compile(r" line (\d+): ")
        raise DatasetError(path, sorted(problems, key=lambda p: int(m[1]) if (m := line.search(p)) else 0))
    ordered = tuple(sorted(entries, key=lambda e: e.clip_id))
    return Dataset(path, "manifest", ordered, tuple(notes + _defaults_notes(entries)))


def _from_folder(base: Path, check_clips: bool, progress: Progress | None) -> Dataset:
    files, notes = _clip_files(base)
    if not files:
        raise DatasetError(
            base,
            [
                f"{base}: no clips found: no clip metadata (*.meta.json), no {' or '.join(MANIFEST_NAMES)}, and no "
                f"video files ({', '.join(VIDEO_SUFFIXES)}) or folders of PNG/JPEG frames in it or its sub-folders"
                + "".join(f" ({n})" for n in notes if n.startswith("skipped"))
            ],
        )
    default = base.resolve().name or "clips"
    rows = [_Row(p.relative_to(base).as_posix(), p, {}, *platform_of(p.relative_to(base), default)) for p in files]
    entries, problems, more = _fill(rows, "folder", base, check_clips, progress, _allowed_folders(base, ()))
    if problems:
        raise DatasetError(base, problems)
    head = [
        f"{base} has no sidecars and no manifest: read as a plain folder of {len(entries)} clip(s), each one's "
        "platform the sub-folder it lies in (`geocon dataset` lists every value and where it came from)"
    ]
    at_root = sum(r.platform_source == "default" for r in rows)
    if at_root:
        head.append(f"{at_root} clip(s) lie directly in {base}, in no platform folder: platform {default!r} (its name)")
    ordered = tuple(sorted(entries, key=lambda e: e.clip_id))
    return Dataset(base, "folder", ordered, tuple(head + notes + more + _defaults_notes(entries)))


# ---- entry points ------------------------------------------------------------------------------


def scan_dataset(
    root: str | Path,
    *,
    check_clips: bool = True,
    progress: Progress | None = None,
    roots: Iterable[str | Path] = (),
) -> Dataset:
    """The dataset at ``root``: a folder with sidecars, a folder with a manifest
    (:data:`MANIFEST_NAMES`), a plain folder of clips, or the path of a ``.csv`` / ``.jsonl``
    manifest. Everything is validated up front: fields and their types, known categories, unique
    clip ids, the clip files present (and, with ``check_clips``, their first two frames
    decodable), masks paths present (with ``check_clips``, a masks layout), and every clip and
    masks path inside the dataset's folder (a manifest's: the manifest's folder) or one of the
    ``roots`` folders. Raises :class:`DatasetError` with every problem found.
    ``progress(checked, total)`` hears each clip checked."""
    base, roots = Path(root), tuple(roots)
    bad_roots = [f"--root {r} is not a folder" for r in roots if not Path(r).is_dir()]
    if bad_roots:
        raise DatasetError(base, [f"{bad_roots[0]}; name a folder the dataset's clips lie in"])
    if base.exists() and not base.is_dir():
        if base.suffix.lower() in (".csv", ".jsonl"):  # a FIFO or a device is refused by the bounded reader
            return _from_manifest(base, check_clips, progress, roots)
        if not base.is_file():
            kind = special_file(base) or "not a regular file"
            raise DatasetError(base, [f"{base}: is {kind}, not a dataset folder nor a manifest file (.csv or .jsonl)"])
        if base.suffix.lower() in VIDEO_SUFFIXES:
            one = f"{base}: is one clip, not a dataset: score it with `geocon score {base}`, or give its folder"
            raise DatasetError(base, [one])
        raise DatasetError(base, [f"{base}: not a folder, nor a manifest (.csv or .jsonl)"])
    if not base.is_dir():
        raise DatasetError(base, [f"{base}: not a folder"])
    sidecars = sorted(base.rglob("*.meta.json"))
    manifests = [base / n for n in MANIFEST_NAMES if (base / n).exists() and not (base / n).is_dir()]
    if sidecars:
        ds = _from_sidecars(base, sidecars, check_clips, progress, _allowed_folders(base, roots))
        if manifests:
            ignored = (
                f"{manifests[0].name} is ignored: the sidecars (*.meta.json) describe the dataset (give the "
                "manifest's path instead of the folder to use it)"
            )
            ds = Dataset(ds.root, ds.layout, ds.entries, (ignored, *ds.notes))
        return ds
    if len(manifests) > 1:
        raise DatasetError(
            base, [f"{base}: holds both {' and '.join(MANIFEST_NAMES)}; keep one (or give the path of the one to use)"]
        )
    if manifests:
        return _from_manifest(manifests[0], check_clips, progress, roots)
    return _from_folder(base, check_clips, progress)


def load_dataset(root: str | Path, *, check_clips: bool = True) -> list[ClipEntry]:
    """Every clip of the dataset at ``root``, sorted by clip_id (:func:`scan_dataset`)."""
    return list(scan_dataset(root, check_clips=check_clips).entries)


def sidecar_text(meta: dict[str, Any], *, ascii_only: bool = False) -> str:
    """A sidecar's text as GeoCon writes it: the object as JSON indented by one space, and a line
    break (``geocon dataset --write`` keeps non-ASCII characters; ``geocon synth`` and ``geocon
    plant`` write them escaped, ``ascii_only``)."""
    return json.dumps(meta, indent=1, ensure_ascii=ascii_only, allow_nan=False) + "\n"


def _sidecar_says(sidecar: Path, meta: dict[str, Any]) -> bool:
    """``sidecar`` exists and holds exactly ``meta`` (read as JSON; nothing to write)."""
    try:
        return sidecar.is_file() and json.loads(read_text(sidecar, SIDECAR)) == meta
    except (OSError, UnicodeError, ValueError, RecursionError):
        return False


def sidecar_owner(entry: ClipEntry) -> Callable[[Any], str | None]:
    """The ``mine`` test (:func:`geocon_core.files.claim`) of an existing sidecar that ``geocon
    dataset --write --force`` may replace: one GeoCon wrote (its text is exactly
    :func:`sidecar_text` of its content: GeoCon's own layout; a sidecar written or reformatted by
    hand is kept from harm) and of ``entry``'s clip (the clip file its ``video`` names, or the clip
    of its stem beside it). A sidecar that already holds ``entry.meta`` is not written at all."""

    def mine(there: Any) -> str | None:
        data = there.data
        if not isinstance(data, dict):
            return "a JSON file that is not a sidecar (no JSON object)"
        if data == entry.meta:
            return None
        try:
            text = there.path.read_text(encoding="utf-8")
        except (OSError, UnicodeError):
            text = ""
        if text not in (sidecar_text(data), sidecar_text(data, ascii_only=True)):
            return "a sidecar written by hand (it is not laid out as GeoCon writes one), which --force does not replace"
        video = data.get("video")
        if isinstance(video, str):
            named = there.path.parent / video
            with suppress(OSError):
                if not (named.exists() and os.path.samefile(named, entry.video)):
                    return f"the sidecar of {video}, not of {entry.video.name}"
        return None

    return mine


@dataclass(frozen=True)
class SidecarsWritten:
    """What :func:`write_sidecars` did: the sidecars written, and those that existed and were kept."""

    written: tuple[Path, ...]
    kept: tuple[Path, ...]


def write_sidecars(dataset: Dataset, *, force: bool = False) -> SidecarsWritten:
    """Write each entry's metadata as its sidecar (``<stem>.meta.json`` beside the clip file); an
    existing sidecar is kept unless ``force`` (and one that already holds the entry's metadata is
    kept even then). All are written or none: each is written beside its
    place first, and they are renamed into place only when every one is complete (a full disk or a
    read-only folder halfway would leave a dataset of some sidecars, which reads as a sidecar
    dataset without the other clips). Reading the dataset again then gives the same entries, now
    from their sidecars."""
    from ..files import commit_together, part_path

    todo: list[Path] = []
    kept: list[Path] = []
    for e in dataset.entries:
        keep = e.sidecar.exists() and (not force or _sidecar_says(e.sidecar, e.meta))
        (kept if keep else todo).append(e.sidecar)
    staged: list[tuple[Path, Path]] = []
    try:
        for e in dataset.entries:
            if e.sidecar in todo:
                staged.append((part_path(e.sidecar), e.sidecar))
                text = sidecar_text(e.meta)
                try:
                    staged[-1][0].write_text(text, encoding="utf-8")
                except OSError as exc:  # named by the sidecar, not its temporary name
                    raise OSError(exc.errno, exc.strerror, str(e.sidecar)) from None
        commit_together(staged)  # a rename that fails midway puts back every sidecar it replaced
    except BaseException:
        for tmp, _ in staged:
            with suppress(OSError):  # a read-only folder has none to remove
                tmp.unlink(missing_ok=True)
        raise
    return SidecarsWritten(tuple(todo), tuple(kept))
