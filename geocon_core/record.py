"""The audit record of one clip (SPEC section 7): frozen dataclasses, written as

- ``record.json``: everything but the per-match arrays, human-readable and byte-stable;
- ``matches.npz``: per-match coordinates, residuals and inlier masks of every scored pair and
  scale for both families (enough to re-gate at other thresholds without re-running), the
  per-cell AdaDFRC vectors and the first/last point cloud,
  concatenated with offsets, written with fixed zip timestamps so that the same scores give
  the same bytes.

Both read back exactly (:func:`read_record`). The viewers read these records and never
recompute scores.
"""

from __future__ import annotations

import io
import json
import zipfile
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from .config import ScoreConfig

__all__ = [
    "RECORD_FORMAT",
    "FitSummary",
    "PairRecord",
    "MatchArrays",
    "GapSummary",
    "ScaleSummary",
    "FamilySummary",
    "BackgroundSummary",
    "GateWindow",
    "GateRecord",
    "ObjectEntry",
    "ObjectScaleSummary",
    "ObjectSummary",
    "CellArrays",
    "Category",
    "PointCloud",
    "ClipRecord",
    "write_record",
    "read_record",
]

RECORD_FORMAT = "geocon-record/1"
Family = Literal["H", "F"]


@dataclass(frozen=True)
class FitSummary:
    """One family's fit on one pair at one scale. ``model`` is ``H_2from1`` or ``F_21`` (3x3 as
    nested lists, pixels of the scale); ``ge`` and ``tau_px`` in pixels of the scale."""

    valid: bool
    reason: str | None
    ir: float | None
    ge: float | None
    n_inliers: int
    tau: float
    tau_px: float | None
    model: list[list[float]] | None


@dataclass(frozen=True)
class PairRecord:
    """Frames (t0, t1) at one scale. ``skip`` names why the pair was not scored (then ``h`` and
    ``f`` are None). ``index`` addresses the pair's rows in :class:`MatchArrays`."""

    index: int
    t0: int
    t1: int
    gap: int
    scale: float
    n_matches: int
    skip: str | None
    h: FitSummary | None
    f: FitSummary | None

    def fit(self, family: Family) -> FitSummary | None:
        return self.h if family == "H" else self.f


@dataclass(frozen=True, eq=False)
class MatchArrays:
    """Per-match arrays of all pairs, concatenated; rows of pair i are
    ``offsets[i]:offsets[i+1]`` (P+1 offsets, int64).

    x1, x2: (M, 2) float32 pixels of the pair's scale.
    h_res: (M,) float32 symmetric transfer error (px).
    f_res: (M,) float32 Sampson distance in Hartley-normalised units.
    f_res_px: (M,) float32 Sampson distance of the denormalised F (px).
    h_inl, f_inl: (M,) bool inlier masks at the recorded thresholds.
    """

    offsets: np.ndarray
    x1: np.ndarray
    x2: np.ndarray
    h_res: np.ndarray
    f_res: np.ndarray
    f_res_px: np.ndarray
    h_inl: np.ndarray
    f_inl: np.ndarray

    NAMES = ("offsets", "x1", "x2", "h_res", "f_res", "f_res_px", "h_inl", "f_inl")

    def __post_init__(self) -> None:
        m = int(self.offsets[-1]) if len(self.offsets) else 0
        shapes = {
            "x1": (m, 2),
            "x2": (m, 2),
            "h_res": (m,),
            "f_res": (m,),
            "f_res_px": (m,),
            "h_inl": (m,),
            "f_inl": (m,),
        }
        for name, shape in shapes.items():
            if getattr(self, name).shape != shape:
                raise ValueError(f"MatchArrays.{name} must have shape {shape}, got {getattr(self, name).shape}")

    @property
    def num_pairs(self) -> int:
        return len(self.offsets) - 1

    def rows(self, index: int) -> slice:
        return slice(int(self.offsets[index]), int(self.offsets[index + 1]))

    def pair(self, index: int) -> dict[str, np.ndarray]:
        """All arrays of one pair (views)."""
        sl = self.rows(index)
        return {name: getattr(self, name)[sl] for name in self.NAMES[1:]}

    @classmethod
    def concatenate(cls, per_pair: list[dict[str, np.ndarray]]) -> "MatchArrays":
        counts = [len(p["x1"]) for p in per_pair]
        offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        cat = {}
        for name, dtype, shape in (
            ("x1", np.float32, (0, 2)),
            ("x2", np.float32, (0, 2)),
            ("h_res", np.float32, (0,)),
            ("f_res", np.float32, (0,)),
            ("f_res_px", np.float32, (0,)),
            ("h_inl", bool, (0,)),
            ("f_inl", bool, (0,)),
        ):
            parts = [np.asarray(p[name], dtype) for p in per_pair]
            cat[name] = np.concatenate(parts) if parts else np.zeros(shape, dtype)
        return cls(offsets=offsets, **cat)


@dataclass(frozen=True, eq=False)
class CellArrays:
    """Per-cell AdaDFRC vectors of all object entries, concatenated; rows of entry i are
    ``offsets[i]:offsets[i+1]``.

    cells: (C, 2) int16 grid indices (row, col); positions: (C, 2) float32 pixel where the
    cell's flow was observed (pixels of the entry's scale); observed, predicted: (C, 2) float32
    median and affine-predicted flow (px); weights: (C,) float32 reliable pixel counts.
    """

    offsets: np.ndarray
    cells: np.ndarray
    positions: np.ndarray
    observed: np.ndarray
    predicted: np.ndarray
    weights: np.ndarray

    NAMES = ("offsets", "cells", "positions", "observed", "predicted", "weights")

    def entry(self, index: int) -> dict[str, np.ndarray]:
        sl = slice(int(self.offsets[index]), int(self.offsets[index + 1]))
        return {name: getattr(self, name)[sl] for name in self.NAMES[1:]}

    @classmethod
    def concatenate(cls, per_entry: list[dict[str, np.ndarray] | None]) -> "CellArrays":
        counts = [0 if e is None else len(e["weights"]) for e in per_entry]
        offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        out = {}
        for name, dtype, shape in (
            ("cells", np.int16, (0, 2)),
            ("positions", np.float32, (0, 2)),
            ("observed", np.float32, (0, 2)),
            ("predicted", np.float32, (0, 2)),
            ("weights", np.float32, (0,)),
        ):
            parts = [np.asarray(e[name], dtype).reshape((-1,) + shape[1:]) for e in per_entry if e is not None]
            out[name] = np.concatenate(parts) if parts else np.zeros(shape, dtype)
        return cls(offsets=offsets, **out)


@dataclass(frozen=True)
class ObjectEntry:
    """AdaDFRC of one object on frames (t0, t1) at one scale. ``d_t`` (the paper's score) and
    ``w2`` in px^2 of the scale; ``affine`` is [M | b] (2x3) with v_pred(p) = M p + b; ``index``
    addresses the entry's cells in :class:`CellArrays`. ``reason`` says why an entry is skipped."""

    index: int
    object_id: int
    t0: int
    t1: int
    scale: float
    valid: bool
    reason: str | None
    d_t: float | None
    w2: float | None
    n_pixels: int
    affine: list[list[float]] | None


@dataclass(frozen=True)
class ObjectScaleSummary:
    scale: float
    adadfrc: float | None
    adadfrc_w2: float | None
    adap90: float | None
    valid_frames: int
    skipped: dict[str, int]


@dataclass(frozen=True)
class ObjectSummary:
    """One tracked object: frames where it is visible, its mean masked share of the content,
    and per scale the mean ``D_t`` (``adadfrc`` = S), mean W2 and AdaP90; the headline values are
    those of the largest scale."""

    object_id: int
    frames: int
    first_frame: int
    last_frame: int
    masked_share: float
    adadfrc: float | None
    adadfrc_w2: float | None
    adap90: float | None
    per_scale: tuple[ObjectScaleSummary, ...]


@dataclass(frozen=True, eq=False)
class PointCloud:
    """Two-view point cloud of the first/last pair: background matches triangulated with the
    gate's pose (in front of both cameras, reprojection <= 2 px).

    xyz: (N, 3) float32 in first-camera coordinates, on the pose's translation scale (unit mean
    scene distance); rgb: (N, 3) uint8 colours sampled from the first frame; note: how it was
    made, or why it is empty (no pose, rotation only: no parallax to triangulate).
    """

    xyz: np.ndarray
    rgb: np.ndarray
    note: str

    def __post_init__(self) -> None:
        n = self.xyz.shape[0]
        if self.xyz.shape != (n, 3) or self.rgb.shape != (n, 3):
            raise ValueError(f"PointCloud needs xyz (N, 3) and rgb (N, 3), got {self.xyz.shape} and {self.rgb.shape}")


@dataclass(frozen=True)
class Category:
    """Post-hoc scene family (SPEC section 5) with the inputs of the decision and the rule that
    fired."""

    label: str
    rule: str
    inputs: dict[str, Any]


@dataclass(frozen=True)
class GapSummary:
    gap: int
    ir: float | None
    ge: float | None
    valid_pairs: int
    total_pairs: int


@dataclass(frozen=True)
class ScaleSummary:
    scale: float
    ir: float | None
    ge: float | None
    valid_pairs: int
    tau_f_px: float | None


@dataclass(frozen=True)
class FamilySummary:
    """Clip-level aggregation of one family (see ``ScoreConfig.aggregation``): per gap, the median
    IR and GE over its valid (pair, scale) entries (``median``) or the worst per-scale median
    (``worst``); headline ``ir`` is the lowest per-gap IR and ``ge`` the highest per-gap GE, which
    for the paper preset (gap 1, median) is exactly the paper's median over (t, s)."""

    family: Family
    ir: float | None
    ge: float | None
    valid_pairs: int
    total_pairs: int
    per_gap: tuple[GapSummary, ...]
    per_scale: tuple[ScaleSummary, ...]
    invalid_reasons: dict[str, int]


@dataclass(frozen=True)
class BackgroundSummary:
    """The background verdict. ``model`` is the family the gate chose (for U: the one with the
    higher IR); ``consistent`` is the report gate ``ir >= ir_gate and ge <= ge_gate`` (None when
    no pair is valid). ``tau_f_px``: pixel equivalent of tau_F (median over valid F fits at the
    largest scale). ``other`` is the other family, kept for best-of analysis."""

    model: Family
    ir: float | None
    ge: float | None
    valid_pairs: int
    total_pairs: int
    consistent: bool | None
    tau_f_px: float | None
    chosen: FamilySummary
    other: FamilySummary
    choice_note: str


@dataclass(frozen=True)
class GateWindow:
    """The gate statistic on frames (start, end)."""

    start: int
    end: int
    t_inf: float | None
    label: str | None
    pose_present: bool


@dataclass(frozen=True)
class GateRecord:
    """The translation gate: ``label`` H / F / U under the hysteresis rule, ``binary_label`` under
    the single threshold, ``model`` the family used (U -> decided by IR, fail -> F), ``margin``
    (``0.03 - t_inf`` for H, ``t_inf - 0.05`` for F, minus the distance to the nearer threshold for U,
    None without a pose), and the pose estimate it came from."""

    label: str
    binary_label: str
    model: Family
    t_inf: float | None
    pose_present: bool
    margin: float | None
    backend: str
    thresholds: dict[str, float]
    pose: dict[str, Any]
    timeline: tuple[GateWindow, ...] = ()


@dataclass(frozen=True, eq=False)
class ClipRecord:
    clip: str
    video: dict[str, Any]
    config: ScoreConfig
    config_hash: str
    versions: dict[str, str]
    gate: GateRecord
    background: BackgroundSummary
    pairs: tuple[PairRecord, ...]
    matches: MatchArrays
    intrinsics: list[list[float]]
    category: Category | None = None
    warnings: tuple[str, ...] = field(default_factory=tuple)
    masks_source: str = "none"
    masked_share: tuple[float, ...] = ()
    objects: tuple[ObjectSummary, ...] = ()
    object_entries: tuple[ObjectEntry, ...] = ()
    cells: CellArrays | None = None
    cloud: PointCloud | None = None

    def summary(self) -> dict[str, Any]:
        """The clip summary printed by ``geocon score --json``."""
        bg, gate = self.background, self.gate
        return {
            "clip": self.clip,
            "gate": {
                "label": gate.label,
                "model": gate.model,
                "t_inf": gate.t_inf,
                "pose_present": gate.pose_present,
                "margin": gate.margin,
                "binary_label": gate.binary_label,
                "backend": gate.backend,
            },
            "background": {
                "model": bg.model,
                "ir": bg.ir,
                "ge": bg.ge,
                "valid_pairs": bg.valid_pairs,
                "total_pairs": bg.total_pairs,
                "consistent": bg.consistent,
                "tau_f_px": bg.tau_f_px,
                "other_family": {"model": bg.other.family, "ir": bg.other.ir, "ge": bg.other.ge},
            },
            "per_gap": {
                str(g.gap): {"ir": g.ir, "ge": g.ge, "valid_pairs": g.valid_pairs, "total_pairs": g.total_pairs}
                for g in bg.chosen.per_gap
            },
            "coverage": {
                "frames": self.video.get("num_frames"),
                "duplicates": len(self.video.get("duplicates", [])),
                "cuts": len(self.video.get("cuts", [])),
                "invalid_reasons": bg.chosen.invalid_reasons,
            },
            "objects": [
                {
                    "id": o.object_id,
                    "frames": o.frames,
                    "adadfrc": o.adadfrc,
                    "adadfrc_w2": o.adadfrc_w2,
                    "adap90": o.adap90,
                    "masked_share": o.masked_share,
                }
                for o in self.objects
            ],
            "masks": self.masks_source,
            "category": None if self.category is None else self.category.label,
            "preset": self.config.preset,
            "config_hash": self.config_hash,
            "versions": self.versions,
            "warnings": list(self.warnings),
        }

    def to_json_dict(self) -> dict[str, Any]:
        return {
            "format": RECORD_FORMAT,
            "clip": self.clip,
            "summary": self.summary(),
            "video": self.video,
            "config": self.config.to_dict(),
            "config_hash": self.config_hash,
            "versions": self.versions,
            "intrinsics": self.intrinsics,
            "gate": asdict(self.gate),
            "background": asdict(self.background),
            "pairs": [asdict(p) for p in self.pairs],
            "category": None if self.category is None else asdict(self.category),
            "warnings": list(self.warnings),
            "masks_source": self.masks_source,
            "masked_share": list(self.masked_share),
            "objects": [asdict(o) for o in self.objects],
            "object_entries": [asdict(e) for e in self.object_entries],
            "cloud": None if self.cloud is None else {"points": int(self.cloud.xyz.shape[0]), "note": self.cloud.note},
        }


def _fit_from(d: dict | None) -> FitSummary | None:
    return None if d is None else FitSummary(**d)


def _family_from(d: dict) -> FamilySummary:
    return FamilySummary(
        family=d["family"],
        ir=d["ir"],
        ge=d["ge"],
        valid_pairs=d["valid_pairs"],
        total_pairs=d["total_pairs"],
        per_gap=tuple(GapSummary(**g) for g in d["per_gap"]),
        per_scale=tuple(ScaleSummary(**s) for s in d["per_scale"]),
        invalid_reasons=dict(d["invalid_reasons"]),
    )


def _dumps(obj: Any) -> str:
    return json.dumps(obj, indent=1, sort_keys=False, allow_nan=False) + "\n"


def write_record(record: ClipRecord, out_dir: str | Path) -> Path:
    """Write ``record.json`` and ``matches.npz`` into ``out_dir`` (created), each atomically."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    buf = io.BytesIO()
    arrays = {name: getattr(record.matches, name) for name in MatchArrays.NAMES}
    if record.cells is not None:
        arrays.update({f"cells_{name}": getattr(record.cells, name) for name in CellArrays.NAMES})
    if record.cloud is not None:
        arrays.update({"cloud_xyz": record.cloud.xyz, "cloud_rgb": record.cloud.rgb})
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for name, value in arrays.items():
            info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            arr = io.BytesIO()
            np.lib.format.write_array(arr, np.ascontiguousarray(value), allow_pickle=False)
            zf.writestr(info, arr.getvalue())
    for name, data in (("matches.npz", buf.getvalue()), ("record.json", _dumps(record.to_json_dict()).encode())):
        tmp = out / f".{name}.part"
        tmp.write_bytes(data)
        tmp.replace(out / name)
    return out / "record.json"


def read_record_json(path: str | Path) -> tuple[Path, dict[str, Any]]:
    """The folder of a record (given it or its ``record.json``) and its parsed JSON, checked to be
    a GeoCon record."""
    p = Path(path)
    folder = p if p.is_dir() else p.parent
    d = json.loads((folder / "record.json").read_text())
    if d.get("format") != RECORD_FORMAT:
        raise ValueError(
            f"{folder / 'record.json'}: not a GeoCon record (format {d.get('format')!r}, expected {RECORD_FORMAT!r})"
        )
    return folder, d


def pairs_from_json(d: dict[str, Any]) -> tuple[PairRecord, ...]:
    """The pair records of a parsed ``record.json``."""
    return tuple(PairRecord(**{**p, "h": _fit_from(p["h"]), "f": _fit_from(p["f"])}) for p in d["pairs"])


def read_record(path: str | Path) -> ClipRecord:
    """Read a record from its folder or its ``record.json``."""
    folder, d = read_record_json(path)
    with np.load(folder / "matches.npz", allow_pickle=False) as z:
        matches = MatchArrays(**{name: z[name] for name in MatchArrays.NAMES})
        cells = (
            CellArrays(**{name: z[f"cells_{name}"] for name in CellArrays.NAMES})
            if "cells_offsets" in z.files
            else None
        )
        cloud = None
        if d.get("cloud") is not None:
            cloud = PointCloud(xyz=z["cloud_xyz"], rgb=z["cloud_rgb"], note=d["cloud"]["note"])
    g = d["gate"]
    gate = GateRecord(**{**g, "timeline": tuple(GateWindow(**w) for w in g["timeline"])})
    b = d["background"]
    background = BackgroundSummary(**{**b, "chosen": _family_from(b["chosen"]), "other": _family_from(b["other"])})
    pairs = pairs_from_json(d)
    return ClipRecord(
        clip=d["clip"],
        video=d["video"],
        config=ScoreConfig.from_dict(d["config"]),
        config_hash=d["config_hash"],
        versions=d["versions"],
        gate=gate,
        background=background,
        pairs=pairs,
        matches=matches,
        intrinsics=d["intrinsics"],
        category=None if d["category"] is None else Category(**d["category"]),
        warnings=tuple(d["warnings"]),
        masks_source=d["masks_source"],
        masked_share=tuple(d["masked_share"]),
        objects=tuple(
            ObjectSummary(**{**o, "per_scale": tuple(ObjectScaleSummary(**p) for p in o["per_scale"])})
            for o in d["objects"]
        ),
        object_entries=tuple(ObjectEntry(**e) for e in d["object_entries"]),
        cells=cells,
        cloud=cloud,
    )
