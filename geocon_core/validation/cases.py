"""The cases of a validation run: synthetic scenes on a grid of heights, codecs and injected
failures, and the real clips of a data folder with a person's annotation of each.

A case names what to score and what is expected of it; :mod:`.prepare` makes its clip and
:mod:`.runner` scores it. With ``planted``, every annotated real-camera clip also gets failures
planted into it (:mod:`geocon_core.plant`) at each kind and severity, and one clean re-encode
made the same way (:func:`planted_cases`).
"""

from __future__ import annotations

import csv
import functools
import hashlib
import io
from dataclasses import dataclass
from pathlib import Path
from typing import Literal, Sequence

__all__ = [
    "ANNOTATIONS_PATH",
    "CODECS",
    "CaseSpec",
    "Annotation",
    "is_geometric",
    "CLEAN_FAMILIES",
    "FAILURE_FAMILY",
    "HEIGHTS",
    "LEVELS",
    "QUICK",
    "SEVERITIES",
    "ValidationPlan",
    "plan_cases",
    "planted_cases",
    "PLANT_LEVELS",
    "PLANT_KINDS",
    "missing_clips",
    "wrong_clips",
    "split_of",
    "ROOTS",
    "SPLITS",
    "SPLIT_SEED",
    "GEOMETRIC_ARTIFACTS",
    "OTHER_ARTIFACTS",
    "read_annotations",
    "real_clips",
    "width_for",
    "source_sha256",
]

CodecName = Literal["png", "crf18", "crf28"]
CaseKind = Literal["synthetic", "real", "planted"]

HEIGHTS: tuple[int, ...] = (256, 384, 512, 720, 1080)
"""Synthetic frame heights, px; widths are 16:9 (:func:`width_for`)."""
CODECS: tuple[str, ...] = ("png", "crf18", "crf28")
"""How synthetic frames are stored: lossless PNG frames, H.264 at CRF 18 and at CRF 28."""
CODEC_CRF: dict[str, int] = {"crf18": 18, "crf28": 28}
CLEAN_FAMILIES: tuple[str, ...] = ("C1", "C2", "C3", "C4", "C5", "C6")
LEVELS: tuple[str, ...] = ("low", "middle", "high")
"""The severity levels of a failure case (values per failure in :data:`SEVERITIES`)."""
PLANT_KINDS: tuple[str, ...] = ("morph", "redraw", "breathing", "slide")
"""The kinds of ``--planted`` cases: every kind of :data:`geocon_core.plant.PLANT_KINDS` (a test
keeps the two equal; listed here so planning a run imports no planting code)."""
PLANT_LEVELS: tuple[str, ...] = ("low", "middle", "high")
"""The severities of ``--planted`` cases (:data:`geocon_core.plant.LEVELS`)."""
SEVERITIES: dict[str, tuple[float, float, float]] = {
    "breathing": (1.0, 2.0, 4.0),
    "slide": (4.0, 8.0, 16.0),
    "slide_along": (4.0, 8.0, 16.0),
    "slide_across": (4.0, 8.0, 16.0),
    "elastic": (2.0, 4.0, 8.0),
}
"""Severity per failure at the low, middle and high level, in the failure's unit (source px: peak
breathing displacement, slide drift at the last frame, peak elastic displacement). The same source
pixels at every height: a generator's defect of a few pixels does not grow with the frame, and
the issue's targets are stated in source pixels."""
FAILURE_FAMILY: dict[str, tuple[str, ...]] = {
    "breathing": ("C2",),
    "slide": ("C3",),
    "slide_along": ("C2", "C3"),
    "slide_across": ("C2", "C3"),
    "elastic": ("C4",),
}
"""The scene families each failure is injected into (elastic needs moving objects; a layer
slides along and across its travel under a rotating (C2) and a translating (C3) camera)."""
ANNOTATIONS_PATH = Path(__file__).resolve().parent / "annotations.csv"
"""The annotation file kept in the project (one row per real clip, made by looking at frames). It
ships inside the package, so an installed wheel validates with it too; ``assets/validation/annotations.csv``
in a checkout is a link to it."""


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


MAX_HEIGHT = 4608
"""The tallest synthetic height: a 16:9 frame 8192 px wide (8K), as large as ``geocon synth`` renders."""


def width_for(height: int) -> int:
    """The even 16:9 width for ``height`` (px)."""
    return int(round(height * 16 / 9 / 2)) * 2


ROOTS: tuple[str, ...] = ("data", "real2", "footage")
"""Where an annotated clip lies: ``data`` (``--data``, the shared test footage), ``real2`` (the
shared folder of further real-camera clips beside it) or ``footage`` (the footage cache that
:mod:`geocon_core.validation.footage` fills from the repositories the annotation names)."""

SPLIT_SEED = "geocon-validation-split/2026-11-26"
"""Seed of the tune/check split (:func:`split_of`). Fixed once: changing it re-deals every clip."""

SPLITS: tuple[str, ...] = ("tune", "check")

GEOMETRIC_ARTIFACTS: tuple[str, ...] = ("melting", "stretching", "morphing", "sliding", "breathing", "warping")
"""Artifact kinds that break the scene's geometry (an object or the background changes shape)."""
OTHER_ARTIFACTS: tuple[str, ...] = ("blur", "watermark", "text", "flicker")
"""Artifact kinds a geometric check is not meant to see."""


def is_geometric(artifact_kinds: Sequence[str]) -> bool:
    """Whether any of ``artifact_kinds`` is geometric (:data:`GEOMETRIC_ARTIFACTS`)."""
    return any(k in GEOMETRIC_ARTIFACTS for k in artifact_kinds)


def split_of(key: str) -> str:
    """``tune`` or ``check``: the half a clip belongs to, from a seeded hash of its key
    (``root:clip``). Rules and thresholds are chosen on the tune half only; the check half is
    looked at once per change."""
    digest = hashlib.sha256(f"{SPLIT_SEED}:{key}".encode()).digest()
    return SPLITS[digest[0] & 1]


@dataclass(frozen=True)
class Annotation:
    """A person's expectations for one clip, made by looking at its frames (see the header of the
    annotation file), with where it came from.

    ``cuts``: 0-based first frames of new shots over the whole clip; ``fades`` those of them that
    are fades. ``dynamic``: non-rigid background a person sees (``water 40%``; empty: none).
    ``artifact_kinds``: the kinds of visible generation artifacts (:data:`GEOMETRIC_ARTIFACTS`,
    :data:`OTHER_ARTIFACTS`; empty: none seen). ``exclude``: why the clip is left out of the
    measures (empty: it counts)."""

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
    root: str = "data"
    camera: str = ""
    mover_size: str = ""
    cuts: tuple[int, ...] = ()
    fades: tuple[int, ...] = ()
    dynamic: str = ""
    artifact_kinds: tuple[str, ...] = ()
    artifact_frames: str = ""
    generator: str = ""
    pose_file: str = ""
    pose_path: str = ""
    repo: str = ""
    commit: str = ""
    path: str = ""
    licence: str = ""
    sha256: str = ""
    exclude: str = ""

    @property
    def key(self) -> str:
        """``root:clip``, unique over the annotation file."""
        return f"{self.root}:{self.clip}"

    @property
    def split(self) -> str:
        """The half this clip belongs to (:func:`split_of`)."""
        return split_of(self.key)

    @property
    def geometric_artifact(self) -> bool:
        """A visible artifact of a geometric kind (an object or the background changes shape)."""
        return is_geometric(self.artifact_kinds)

    @property
    def visible_artifact(self) -> bool:
        """Any visible generation artifact (geometric or not)."""
        return bool(self.artifact_kinds) or bool(self.artifacts)


@dataclass(frozen=True)
class CaseSpec:
    """One case. Synthetic: ``family``, ``failure`` / ``level`` / ``severity`` (None when clean),
    ``height`` (px) and ``codec``. Real: ``source`` is the clip's path and ``annotation`` what a
    person expects (None when the clip is not annotated). Planted: ``source`` and ``annotation``
    are the real clip's, ``failure`` the planted kind, ``level`` its severity and ``severity`` its
    amplitude (:func:`geocon_core.plant.amplitude_of`); all three None for the clean re-encode."""

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
    real2: Path | None = None
    """The shared folder of further real-camera clips (annotated rows of root ``real2``)."""
    footage: Path | None = None
    """The footage cache (annotated rows of root ``footage``); clips missing from it are listed,
    not scored (:func:`missing_clips`)."""
    split: str = "all"
    """``all``, ``tune`` or ``check``: the clips of ``real2`` and ``footage`` in that half only
    (:func:`split_of`); synthetic cases and the clips of ``data`` are not split."""
    real: bool = True
    """Score the clips of the roots themselves; without it the roots only give the sources of the
    planted cases."""
    planted: bool = False
    """Plant failures into every annotated real-camera clip of the roots (:func:`planted_cases`)."""
    plant_kinds: tuple[str, ...] = PLANT_KINDS
    """The planted kinds (:data:`PLANT_KINDS`)."""
    plant_levels: tuple[str, ...] = PLANT_LEVELS
    """The planted severities (:data:`PLANT_LEVELS`)."""

    def __post_init__(self) -> None:
        for name, values, valid in (
            ("codec", self.codecs, CODECS),
            ("family", self.families, CLEAN_FAMILIES),
            ("failure", self.failures, tuple(SEVERITIES)),
            ("level", self.levels, LEVELS),
            ("planted kind", self.plant_kinds, PLANT_KINDS),
            ("severity", self.plant_levels, PLANT_LEVELS),
        ):
            bad = [v for v in values if v not in valid]
            if bad:
                raise ValueError(f"unknown {name} {bad[0]!r}; valid: {', '.join(valid)}")
        if any(h < 16 or h > MAX_HEIGHT or h % 2 for h in self.heights):
            raise ValueError(
                f"--heights must be even, at least 16 px and at most {MAX_HEIGHT} px (16:9 frames "
                f"{width_for(MAX_HEIGHT)} px wide, 8K), got {','.join(map(str, self.heights))}"
            )
        lists: tuple[tuple[str, tuple[object, ...], str], ...] = (
            ("--heights", self.heights, "at least one height"),
            ("--codecs", self.codecs, f"at least one of {', '.join(CODECS)}"),
        )
        for option, listed, some in lists:
            if self.synthetic and not listed:
                raise ValueError(f"{option} lists none, so no synthetic clip is made; give {some} (or --no-synthetic)")
        planted_lists = (
            ("--plant-kinds", self.plant_kinds, PLANT_KINDS),
            ("--severity", self.plant_levels, PLANT_LEVELS),
        )
        for option, listed, valid in planted_lists:
            if self.planted and not listed:
                raise ValueError(
                    f"{option} lists none, so no planted clip is made; give at least one of {', '.join(valid)} "
                    "(or leave out --planted)"
                )
        if self.frames < 2 or self.max_frames < 2:
            raise ValueError("a clip needs at least 2 frames")
        if self.split not in ("all", *SPLITS):
            raise ValueError(f"unknown split {self.split!r}; valid: all, {', '.join(SPLITS)}")


def _synthetic_cases(plan: ValidationPlan) -> list[CaseSpec]:
    cases = []
    for height in plan.heights:
        for codec in plan.codecs:
            for family in plan.families:
                cases.append(
                    CaseSpec(f"{family}__clean__h{height}__{codec}", "synthetic", family, height=height, codec=codec)
                )
            for failure in plan.failures:
                for family in FAILURE_FAMILY[failure]:
                    for level in plan.levels:
                        severity = SEVERITIES[failure][LEVELS.index(level)]
                        cid = f"{family}__{failure}-{level}__h{height}__{codec}"
                        cases.append(CaseSpec(cid, "synthetic", family, failure, level, severity, height, codec))
    return cases


_CLIP_SUFFIXES = (".mp4", ".avi", ".mov", ".webm", ".gif", ".mkv", ".m4v")


def real_clips(data: Path) -> list[Path]:
    """Every clip under ``data``: video files and folders that hold only image frames (at least two),
    in sorted order. Folders that mix frames with other files (still image pairs with their ground
    truth) are not clips. A FIFO, a device or a socket named as a clip raises ``ValueError`` naming it
    (read, it would block or never end; left out, its clip would be missing without a word)."""
    named = [p for p in data.rglob("*") if p.suffix.lower() in _CLIP_SUFFIXES and not p.is_dir()]
    odd = next((p for p in named if not p.is_file()), None)
    if odd is not None:
        from ..files import special_file

        kind = special_file(odd) or ("a link to nothing" if odd.is_symlink() else "not a regular file")
        raise ValueError(f"{odd} is {kind}, not a clip file, among the real clips of {data}; move it out")
    clips = [p for p in named if p.is_file()]
    for folder in [data, *(p for p in data.rglob("*") if p.is_dir())]:
        files = [p for p in folder.iterdir() if p.is_file()]
        if len(files) >= 2 and all(p.suffix.lower() in (".png", ".jpg", ".jpeg") for p in files):
            clips.append(folder)
    return sorted(clips)


def _case_id(root: str, rel: str) -> str:
    prefix = "real" if root == "data" else root
    return f"{prefix}__" + rel.replace("/", "__")


def _roots(plan: ValidationPlan) -> dict[str, Path]:
    roots = {"data": plan.data, "real2": plan.real2, "footage": plan.footage}
    return {name: path for name, path in roots.items() if path is not None}


def _in_split(plan: ValidationPlan, key: str) -> bool:
    """Whether the clip ``key`` is in the plan's half. The clips of ``data`` are not split: the
    earlier validation chose its rules on them, so they are reported as a set of their own."""
    return plan.split == "all" or key.startswith("data:") or split_of(key) == plan.split


def _planted_sources(plan: ValidationPlan, annotations: dict[str, Annotation]) -> list[tuple[Annotation, Path]]:
    """The annotated real-camera clips (``source = real``, not excluded) of the plan's roots that
    are present and in the plan's half, with their paths, in key order."""
    roots = _roots(plan)
    return [
        (note, roots[note.root] / note.clip)
        for note in sorted(annotations.values(), key=lambda a: a.key)
        if note.source == "real"
        and note.root in roots
        and not note.exclude
        and _in_split(plan, note.key)
        and (roots[note.root] / note.clip).exists()
    ]


def planted_cases(plan: ValidationPlan, annotations: dict[str, Annotation]) -> list[CaseSpec]:
    """The planted family: for every annotated real-camera clip of the plan's roots that is present
    and in the plan's half, one clean re-encode (the original's counterpart, encoded as the planted
    clips are, so only the planted damage differs) and one case per kind of ``plan.plant_kinds``
    and severity of ``plan.plant_levels``, planted from ``plan.seed`` into the clip's first
    ``plan.max_frames`` frames. Each carries its source clip's annotation: its scene
    (:attr:`Annotation.key`) and its half are the source's."""
    from ..plant import amplitude_of

    cases = []
    for note, clip in _planted_sources(plan, annotations):
        base = "planted__" + _case_id(note.root, note.clip)
        cases.append(CaseSpec(f"{base}__clean", "planted", source=str(clip), annotation=note))
        for kind in plan.plant_kinds:
            for level in plan.plant_levels:
                amplitude = amplitude_of(kind, level)
                cid = f"{base}__{kind}-{level}-s{plan.seed}"
                cases.append(CaseSpec(cid, "planted", None, kind, level, amplitude, source=str(clip), annotation=note))
    return cases


def _real_cases(plan: ValidationPlan, annotations: dict[str, Annotation]) -> list[CaseSpec]:
    """Every clip of ``plan.data`` (annotated or not), then the annotated clips of the other roots
    that are present; excluded rows and clips of the other half are left out."""
    cases = []
    roots = _roots(plan)
    if plan.data is not None:
        for clip in real_clips(plan.data):
            rel = clip.relative_to(plan.data).as_posix()
            note = annotations.get(f"data:{rel}")
            if (note is None or not note.exclude) and _in_split(plan, f"data:{rel}"):
                cases.append(CaseSpec(_case_id("data", rel), "real", source=str(clip), annotation=note))
    for note in sorted(annotations.values(), key=lambda a: a.key):
        if note.root == "data" or note.root not in roots or note.exclude or not _in_split(plan, note.key):
            continue
        clip = roots[note.root] / note.clip
        if clip.exists():
            cases.append(CaseSpec(_case_id(note.root, note.clip), "real", source=str(clip), annotation=note))
    return cases


def missing_clips(plan: ValidationPlan, annotations: dict[str, Annotation]) -> list[Annotation]:
    """Annotated clips of the plan's roots that are not where they should be (in the plan's half):
    a footage cache not filled yet, a shared folder or a ``--data`` folder that lacks them."""
    roots = _roots(plan)
    return [
        a
        for a in sorted(annotations.values(), key=lambda a: a.key)
        if a.root in roots and not a.exclude and _in_split(plan, a.key) and not (roots[a.root] / a.clip).exists()
    ]


def source_sha256(path: str | Path) -> str:
    """The SHA-256 (hex) of a source clip's bytes; for a folder of frames, of its image files'
    names and bytes in sorted order. Remembered per process by path, size and modification time."""
    p = Path(path).resolve()
    if p.is_dir():
        files = sorted(f for f in p.iterdir() if f.is_file() and f.suffix.lower() in (".png", ".jpg", ".jpeg"))
        stamp = tuple((f.name, f.stat().st_size, f.stat().st_mtime_ns) for f in files)
    else:
        from ..files import CLIP, regular_file

        stat = regular_file(p, CLIP, str(path))  # a FIFO or a device would block or never end
        files, stamp = [p], ((p.name, stat.st_size, stat.st_mtime_ns),)
    return _sha256_of(str(p), stamp, tuple(str(f) for f in files), p.is_dir())


@functools.lru_cache(maxsize=1024)
def _sha256_of(path: str, stamp: tuple[tuple[str, int, int], ...], files: tuple[str, ...], folder: bool) -> str:
    h = hashlib.sha256()
    for name in files:
        if folder:
            h.update(Path(name).name.encode() + b"\0")
        with open(name, "rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                h.update(block)
    return h.hexdigest()


def wrong_clips(plan: ValidationPlan, annotations: dict[str, Annotation]) -> list[Annotation]:
    """Annotated clip files of the plan's roots (in the plan's half) whose bytes do not hash to
    their annotated ``sha256``: another clip under the annotated name, which the annotation does not
    describe. They are left out of the cases (:func:`plan_cases`), and the run names them."""
    roots = _roots(plan)
    return [
        a
        for a in sorted(annotations.values(), key=lambda a: a.key)
        if a.sha256
        and a.root in roots
        and not a.exclude
        and _in_split(plan, a.key)
        and (roots[a.root] / a.clip).is_file()
        and source_sha256(roots[a.root] / a.clip) != a.sha256.lower()
    ]


def plan_cases(plan: ValidationPlan, annotations: dict[str, Annotation] | None = None) -> list[CaseSpec]:
    """The cases of ``plan``: the synthetic grid, then the clips of ``plan.data`` and the annotated
    clips of ``plan.real2`` and ``plan.footage`` (with ``plan.real``), then the planted family
    (with ``plan.planted``, :func:`planted_cases`). Annotated clips whose bytes are not the
    annotated ones (:func:`wrong_clips`) are left out of both."""
    cases = _synthetic_cases(plan) if plan.synthetic else []
    if _roots(plan) and (plan.real or plan.planted):
        notes = annotations if annotations is not None else read_annotations()
        wrong = {a.key for a in wrong_clips(plan, notes)}
        kept = {k: a for k, a in notes.items() if k not in wrong}  # the annotations that describe their clips
        real = [c for c in _real_cases(plan, kept) if c.annotation is not None or _key_of(plan, c) not in wrong]
        cases += real if plan.real else []
        cases += planted_cases(plan, kept) if plan.planted else []
    return cases


def _key_of(plan: ValidationPlan, case: CaseSpec) -> str | None:
    """The annotation key (``data:REL``) a case of a clip in ``plan.data`` would have."""
    if plan.data is None or case.source is None:
        return None
    return f"data:{Path(case.source).relative_to(plan.data).as_posix()}"


def _yes_no(value: str, where: str) -> bool | None:
    v = value.strip().lower()
    if v in ("", "?"):
        return None
    if v not in ("yes", "no"):
        raise ValueError(f"{where}: expected yes or no, got {value!r}")
    return v == "yes"


def _frames_list(value: str, where: str) -> tuple[tuple[int, ...], tuple[int, ...]]:
    """``no`` / blank, or ``12;30;88fade``: (first frames of new shots, those that are fades)."""
    v = value.strip().lower()
    if v in ("", "no"):
        return (), ()
    cuts, fades = [], []
    for part in v.split(";"):
        p = part.strip()
        fade = p.endswith("fade")
        p = p.removesuffix("fade").strip()
        if not p.isdigit():
            raise ValueError(f"{where}: cut must be 'no' or frame numbers separated by ';', got {value!r}")
        cuts.append(int(p))
        if fade:
            fades.append(int(p))
    return tuple(cuts), tuple(fades)


def _artifact_kinds(value: str, where: str) -> tuple[str, ...]:
    kinds = tuple(k.strip().lower() for k in value.split(";") if k.strip() and k.strip().lower() != "none")
    valid = GEOMETRIC_ARTIFACTS + OTHER_ARTIFACTS
    bad = [k for k in kinds if k not in valid]
    if bad:
        raise ValueError(f"{where}: unknown artifact kind {bad[0]!r}; valid: none, {', '.join(valid)}")
    return kinds


_TEXT_COLUMNS = (
    "camera", "mover_size", "dynamic", "artifact_frames", "generator", "pose_file", "pose_path", "repo", "commit",
    "path", "licence", "sha256", "exclude",
)  # fmt: skip


ANNOTATION_COLUMNS = (
    "clip", "regime", "gate", "movers", "static_camera", "source", "stable_scene", "category", "artifacts", "note",
)  # fmt: skip
"""The columns every annotation file has; the others (``root``, ``cut``, ...) take defaults."""


def _annotation_text(p: Path) -> str:
    """The text of the annotation file ``p``; ``ValueError`` with one sentence naming it when it is
    missing, a folder, a FIFO or a device, past the bound of
    :data:`~geocon_core.files.bounded.ANNOTATIONS`, unreadable or not UTF-8."""
    from ..files import ANNOTATIONS, ReadRefused, read_text

    try:
        return read_text(p, ANNOTATIONS, f"annotation file {p}")  # a regular file within its bound
    except ReadRefused as exc:
        if exc.reason == "folder":
            raise ValueError(f"annotation file {p} is a folder; give the annotation CSV") from None
        raise


def read_annotations(path: str | Path = ANNOTATIONS_PATH) -> dict[str, Annotation]:
    """The annotation file (CSV; lines starting with ``#`` are its header notes), by
    :attr:`Annotation.key` (``root:clip``). Columns the file lacks take their defaults (an older
    file: every clip in ``data``)."""
    p = Path(path)
    text = "".join(line for line in _annotation_text(p).splitlines(keepends=True) if not line.startswith("#"))
    reader = csv.DictReader(io.StringIO(text))
    missing = [c for c in ANNOTATION_COLUMNS if c not in (reader.fieldnames or ())]
    if missing:
        raise ValueError(
            f"annotation file {p} has no column{'s' if len(missing) > 1 else ''} {', '.join(missing)}: it is not an "
            "annotation CSV"
        )
    out: dict[str, Annotation] = {}
    for i, cells in enumerate(reader, 2):
        row = {k: v or "" for k, v in cells.items() if k is not None}  # a short row's missing cells are blank
        where = f"{p.name} row {i} ({row.get('clip')})"
        if row["movers"].strip() and not row["movers"].strip().isdigit():
            raise ValueError(f"{where}: movers must be a whole number or blank, got {row['movers']!r}")
        gate = row["gate"].strip().upper() or None
        if gate not in (None, "H", "F"):
            raise ValueError(f"{where}: gate must be H, F or blank, got {row['gate']!r}")
        root = (row.get("root") or "data").strip()
        if root not in ROOTS:
            raise ValueError(f"{where}: root must be one of {', '.join(ROOTS)}, got {root!r}")
        movers = row["movers"].strip()
        cuts, fades = _frames_list(row.get("cut") or "", where)
        note = Annotation(
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
            root=root,
            cuts=cuts,
            fades=fades,
            artifact_kinds=_artifact_kinds(row.get("artifact_kind") or "", where),
            **{c: (row.get(c) or "").strip() for c in _TEXT_COLUMNS},
        )
        if note.key in out:
            raise ValueError(f"{where}: {note.key} is annotated twice")
        out[note.key] = note
    return out
