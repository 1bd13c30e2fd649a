"""Benchmark datasets: a folder of clips, each with a sidecar metadata JSON (SPEC section 6).

Layout: every ``<name>.meta.json`` below the dataset folder (any depth) describes one clip::

    {"clip_id": "sora-0007", "prompt": "...", "model": "sora", "model_version": "2025-03",
     "seed": 7, "resolution": [1280, 720], "fps": 24, "duration": 5.0,
     "masks_path": "sora-0007.masks" | null, "category": "C3", "scene_id": "kitchen-07",
     "video": "sora-0007.mp4"}

``video`` is optional: without it the clip is ``<name>.<ext>`` (mp4, avi, mov, webm, gif, mkv) or a
folder ``<name>/`` of PNG/JPEG frames next to the sidecar. ``masks_path`` (external object masks,
see :mod:`geocon_core.masks`) and ``video`` are relative to the sidecar's folder. ``category`` is the
expected family C1-C6; ``model`` is the platform; ``scene_id`` is shared by the clips of one
seed/scene across platforms. Extra keys are kept and ignored.

:func:`load_dataset` validates everything up front and raises :class:`DatasetError` listing
every problem at once, each with its file name.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .reader import ClipError, check_clip

__all__ = [
    "CATEGORIES",
    "EXPECTED_MODEL",
    "REQUIRED_FIELDS",
    "ClipEntry",
    "DatasetError",
    "expected_model",
    "load_dataset",
]

CATEGORIES = ("C1", "C2", "C3", "C4", "C5", "C6")
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
VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".webm", ".gif", ".mkv")
_CLIP_ID = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._+=-]{0,199}$")


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
    """One validated clip of a dataset: absolute paths and the sidecar as read."""

    clip_id: str
    video: Path
    masks: Path | None
    sidecar: Path
    meta: dict[str, Any]

    @property
    def model(self) -> str:
        return str(self.meta["model"])

    @property
    def category(self) -> str:
        return str(self.meta["category"])

    @property
    def scene_id(self) -> str:
        return str(self.meta["scene_id"])


def _find_video(sidecar: Path, meta: dict[str, Any]) -> Path | None:
    if meta.get("video"):
        return sidecar.parent / str(meta["video"])
    stem = sidecar.name[: -len(".meta.json")]
    for suffix in VIDEO_SUFFIXES:
        cand = sidecar.parent / f"{stem}{suffix}"
        if cand.is_file():
            return cand
    folder = sidecar.parent / stem
    return folder if folder.is_dir() else None


def _field_problems(name: str, meta: dict[str, Any]) -> list[str]:
    problems = []
    missing = [k for k in REQUIRED_FIELDS if k not in meta]
    if missing:
        problems.append(f"{name}: missing field{'s' if len(missing) > 1 else ''} {', '.join(missing)}")
    cid = meta.get("clip_id")
    if "clip_id" in meta and (not isinstance(cid, str) or not _CLIP_ID.match(cid)):
        problems.append(
            f"{name}: clip_id {cid!r} must be a string of letters, digits and . _ + = - (it names the result folder)"
        )
    for key in ("model", "scene_id", "prompt"):
        if key in meta and (meta[key] is None or str(meta[key]).strip() == ""):
            problems.append(f"{name}: {key} is empty")
    if "category" in meta and meta["category"] not in CATEGORIES:
        problems.append(f"{name}: unknown category {meta['category']!r} (expected one of {', '.join(CATEGORIES)})")
    if "fps" in meta and not (
        isinstance(meta["fps"], (int, float)) and not isinstance(meta["fps"], bool) and meta["fps"] > 0
    ):
        problems.append(f"{name}: fps must be a positive number, got {meta['fps']!r}")
    if "duration" in meta and not (
        isinstance(meta["duration"], (int, float)) and not isinstance(meta["duration"], bool) and meta["duration"] >= 0
    ):
        problems.append(f"{name}: duration must be a non-negative number (seconds), got {meta['duration']!r}")
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


def _read_sidecar(sidecar: Path, name: str) -> tuple[dict[str, Any] | None, str]:
    """The parsed sidecar, or None and the problem with it."""
    from .jsonin import strict_json

    try:
        meta = strict_json(sidecar.read_text(), name)
    except (OSError, UnicodeDecodeError) as exc:
        return None, f"{name}: cannot be read ({exc})"
    except json.JSONDecodeError as exc:
        return None, f"{name}: not valid JSON ({exc.msg} at line {exc.lineno})"
    except ValueError as exc:
        return None, str(exc)
    if not isinstance(meta, dict):
        return None, f"{name}: must hold a JSON object"
    return meta, ""


def _video_problems(name: str, sidecar: Path, meta: dict[str, Any], video: Path | None, check_clips: bool) -> list[str]:
    """What is wrong with a sidecar's clip file (missing, or with ``check_clips`` unreadable)."""
    if video is None:
        return [
            f"{name}: no clip file next to it (expected {sidecar.name[: -len('.meta.json')]}.mp4 or another "
            "video, or a 'video' field)"
        ]
    if not video.exists():
        return [f"{name}: clip file {meta.get('video')} does not exist"]
    if check_clips:
        try:
            check_clip(video)
        except ClipError as exc:
            return [f"{name}: unreadable clip ({exc})"]
    return []


def load_dataset(root: str | Path, *, check_clips: bool = True) -> list[ClipEntry]:
    """Every clip of the dataset at ``root``, sorted by clip_id, after validating all sidecars:
    required fields and their types, known categories, unique clip ids, the clip file present
    (and, with ``check_clips``, its first two frames decodable) and masks paths present. Raises
    :class:`DatasetError` with every problem found."""
    base = Path(root)
    if not base.is_dir():
        raise DatasetError(base, [f"{base}: not a folder"])
    sidecars = sorted(base.rglob("*.meta.json"))
    if not sidecars:
        raise DatasetError(base, [f"{base}: no clip metadata (*.meta.json) found"])
    problems: list[str] = []
    entries: list[ClipEntry] = []
    seen: dict[str, Path] = {}
    videos: dict[tuple[int, int], Path] = {}
    for sidecar in sidecars:
        name = str(sidecar.relative_to(base))
        meta, problem = _read_sidecar(sidecar, name)
        if meta is None:
            problems.append(problem)
            continue
        mine = _field_problems(name, meta)
        cid = meta.get("clip_id")
        if isinstance(cid, str) and cid in seen:
            mine.append(f"{name}: clip_id {cid!r} is also used by {seen[cid].relative_to(base)}")
        video = _find_video(sidecar, meta)
        mine += _video_problems(name, sidecar, meta, video, check_clips)
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
            if not masks.exists():
                mine.append(f"{name}: masks_path {meta['masks_path']} does not exist")
        if mine:
            problems.extend(mine)
            continue
        assert isinstance(cid, str) and video is not None  # checked by _field_problems and above
        seen[cid] = sidecar
        entries.append(
            ClipEntry(
                clip_id=cid,
                video=video.resolve(),
                masks=None if masks is None else masks.resolve(),
                sidecar=sidecar.resolve(),
                meta=meta,
            )
        )
    if problems:
        raise DatasetError(base, problems)
    return sorted(entries, key=lambda e: e.clip_id)
