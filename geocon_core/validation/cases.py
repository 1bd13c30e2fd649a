"""The cases of a validation run: synthetic scenes on a grid of heights, codecs and injected
failures, and the real clips of a data folder with a person's annotation of each.

A case names what to score and what is expected of it; :mod:`.prepare` makes its clip and
:mod:`.runner` scores it.
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

__all__ = [
    "ANNOTATIONS_PATH",
    "CODECS",
    "CaseSpec",
    "Annotation",
    "CLEAN_FAMILIES",
    "FAILURE_FAMILY",
    "HEIGHTS",
    "LEVELS",
    "QUICK",
    "SEVERITIES",
    "ValidationPlan",
    "plan_cases",
    "read_annotations",
    "real_clips",
    "width_for",
]

CodecName = Literal["png", "crf18", "crf28"]
CaseKind = Literal["synthetic", "real"]

HEIGHTS: tuple[int, ...] = (256, 384, 512, 720, 1080)
"""Synthetic frame heights, px; widths are 16:9 (:func:`width_for`)."""
CODECS: tuple[str, ...] = ("png", "crf18", "crf28")
"""How synthetic frames are stored: lossless PNG frames, H.264 at CRF 18 and at CRF 28."""
CODEC_CRF: dict[str, int] = {"crf18": 18, "crf28": 28}
CLEAN_FAMILIES: tuple[str, ...] = ("C1", "C2", "C3", "C4", "C5", "C6")
LEVELS: tuple[str, ...] = ("low", "middle", "high")
SEVERITIES: dict[str, tuple[float, float, float]] = {
    "breathing": (1.0, 2.0, 4.0),
    "slide": (4.0, 8.0, 16.0),
    "elastic": (2.0, 4.0, 8.0),
}
"""Severity per failure at the low, middle and high level, in the failure's unit (source px: peak
breathing displacement, slide drift at the last frame, peak elastic displacement). The same source
pixels at every height: a generator's defect of a few pixels does not grow with the frame, and
the issue's targets are stated in source pixels."""
FAILURE_FAMILY: dict[str, str] = {"breathing": "C2", "slide": "C3", "elastic": "C4"}
"""The scene family each failure is injected into (elastic needs moving objects)."""
ANNOTATIONS_PATH = Path(__file__).resolve().parents[2] / "assets" / "validation" / "annotations.csv"
"""The annotation file kept in the project (one row per real clip, made by looking at frames)."""


@dataclass(frozen=True)
class QuickSettings:
    heights: tuple[int, ...] = (256, 720)
    codecs: tuple[str, ...] = ("png", "crf28")
    frames: int = 24
    max_frames: int = 16


QUICK = QuickSettings()
"""What ``--quick`` reduces the grid to (a smoke run). Synthetic clips keep 24 frames: a mover is
tracked once the segmentation has seen it for several frames and AdaDFRC scores frames
``object_gap`` apart, so 12-frame clips left the object rows without meaning (no mover tracked
for most of its frames)."""


def width_for(height: int) -> int:
    """The even 16:9 width for ``height`` (px)."""
    return int(round(height * 16 / 9 / 2)) * 2


@dataclass(frozen=True)
class Annotation:
    """A person's expectations for one real clip (see the header of the annotation file)."""

    clip: str
    regime: str
    gate: str | None
    movers: int | None
    static_camera: bool | None
    source: str
    stable_scene: bool | None
    category: str | None
    artifacts: str
    note: str


@dataclass(frozen=True)
class CaseSpec:
    """One case. Synthetic: ``family``, ``failure`` / ``level`` / ``severity`` (None when clean),
    ``height`` (px) and ``codec``. Real: ``source`` is the clip's path and ``annotation`` what a
    person expects (None when the clip is not annotated)."""

    case_id: str
    kind: CaseKind
    family: str | None = None
    failure: str | None = None
    level: str | None = None
    severity: float | None = None
    height: int | None = None
    codec: str | None = None
    source: str | None = None
    annotation: Annotation | None = None

    @property
    def width(self) -> int | None:
        return None if self.height is None else width_for(self.height)


@dataclass(frozen=True)
class ValidationPlan:
    """What a run covers. ``frames``: frames per synthetic clip; ``max_frames``: real clips are
    cut to their first frames; ``data``: the folder of real clips (None: no real clips)."""

    heights: tuple[int, ...] = HEIGHTS
    codecs: tuple[str, ...] = CODECS
    families: tuple[str, ...] = CLEAN_FAMILIES
    failures: tuple[str, ...] = tuple(SEVERITIES)
    levels: tuple[str, ...] = LEVELS
    frames: int = 24
    max_frames: int = 48
    seed: int = 0
    data: Path | None = None
    synthetic: bool = True

    def __post_init__(self) -> None:
        for name, values, valid in (
            ("codec", self.codecs, CODECS),
            ("family", self.families, CLEAN_FAMILIES),
            ("failure", self.failures, tuple(SEVERITIES)),
            ("level", self.levels, LEVELS),
        ):
            bad = [v for v in values if v not in valid]
            if bad:
                raise ValueError(f"unknown {name} {bad[0]!r}; valid: {', '.join(valid)}")
        if any(h < 16 or h % 2 for h in self.heights):
            raise ValueError(f"heights must be even and at least 16 px, got {list(self.heights)}")
        if self.frames < 2 or self.max_frames < 2:
            raise ValueError("a clip needs at least 2 frames")


def _synthetic_cases(plan: ValidationPlan) -> list[CaseSpec]:
    cases = []
    for height in plan.heights:
        for codec in plan.codecs:
            for family in plan.families:
                cases.append(
                    CaseSpec(f"{family}__clean__h{height}__{codec}", "synthetic", family, height=height, codec=codec)
                )
            for failure in plan.failures:
                family = FAILURE_FAMILY[failure]
                for level in plan.levels:
                    severity = SEVERITIES[failure][LEVELS.index(level)]
                    cid = f"{family}__{failure}-{level}__h{height}__{codec}"
                    cases.append(CaseSpec(cid, "synthetic", family, failure, level, severity, height, codec))
    return cases


_CLIP_SUFFIXES = (".mp4", ".avi", ".mov", ".webm", ".gif")


def real_clips(data: Path) -> list[Path]:
    """Every clip under ``data``: video files and folders that hold only image frames (at least two),
    in sorted order. Folders that mix frames with other files (still image pairs with their ground
    truth) are not clips."""
    clips = [p for p in data.rglob("*") if p.is_file() and p.suffix.lower() in _CLIP_SUFFIXES]
    for folder in [data, *(p for p in data.rglob("*") if p.is_dir())]:
        files = [p for p in folder.iterdir() if p.is_file()]
        if len(files) >= 2 and all(p.suffix.lower() in (".png", ".jpg", ".jpeg") for p in files):
            clips.append(folder)
    return sorted(clips)


def _real_cases(data: Path, annotations: dict[str, Annotation]) -> list[CaseSpec]:
    cases = []
    for clip in real_clips(data):
        rel = clip.relative_to(data).as_posix()
        cid = "real__" + rel.replace("/", "__")
        cases.append(CaseSpec(cid, "real", source=str(clip), annotation=annotations.get(rel)))
    return cases


def plan_cases(plan: ValidationPlan, annotations: dict[str, Annotation] | None = None) -> list[CaseSpec]:
    """The cases of ``plan``: the synthetic grid, then the real clips of ``plan.data``."""
    cases = _synthetic_cases(plan) if plan.synthetic else []
    if plan.data is not None:
        cases += _real_cases(plan.data, annotations if annotations is not None else read_annotations())
    return cases


def _yes_no(value: str, where: str) -> bool | None:
    v = value.strip().lower()
    if v in ("", "?"):
        return None
    if v not in ("yes", "no"):
        raise ValueError(f"{where}: expected yes or no, got {value!r}")
    return v == "yes"


def read_annotations(path: str | Path = ANNOTATIONS_PATH) -> dict[str, Annotation]:
    """The annotation file (CSV; lines starting with ``#`` are its header notes), by clip path."""
    p = Path(path)
    text = "".join(line for line in p.read_text().splitlines(keepends=True) if not line.startswith("#"))
    out: dict[str, Annotation] = {}
    for i, row in enumerate(csv.DictReader(io.StringIO(text)), 2):
        where = f"{p.name} row {i} ({row.get('clip')})"
        gate = row["gate"].strip().upper() or None
        if gate not in (None, "H", "F"):
            raise ValueError(f"{where}: gate must be H, F or blank, got {row['gate']!r}")
        movers = row["movers"].strip()
        out[row["clip"].strip()] = Annotation(
            clip=row["clip"].strip(),
            regime=row["regime"].strip(),
            gate=gate,
            movers=int(movers) if movers else None,
            static_camera=_yes_no(row["static_camera"], where),
            source=row["source"].strip(),
            stable_scene=_yes_no(row["stable_scene"], where),
            category=row["category"].strip() or None,
            artifacts=row["artifacts"].strip(),
            note=row["note"].strip(),
        )
    return out
