"""The audit record of one clip (SPEC section 7): frozen dataclasses, written as

- ``record.json``: everything but the per-match arrays, human-readable and byte-stable;
- ``matches.npz``: per-match coordinates, residuals and inlier masks of every scored pair and
  scale for both families (enough to re-gate at other thresholds without re-running),
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
        shapes = {"x1": (m, 2), "x2": (m, 2), "h_res": (m,), "f_res": (m,), "f_res_px": (m,), "h_inl": (m,), "f_inl": (m,)}
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
        for name, dtype, shape in (("x1", np.float32, (0, 2)), ("x2", np.float32, (0, 2)), ("h_res", np.float32, (0,)),
                                   ("f_res", np.float32, (0,)), ("f_res_px", np.float32, (0,)), ("h_inl", bool, (0,)), ("f_inl", bool, (0,))):
            parts = [np.asarray(p[name], dtype) for p in per_pair]
            cat[name] = np.concatenate(parts) if parts else np.zeros(shape, dtype)
        return cls(offsets=offsets, **cat)


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
    category: str | None = None
    warnings: tuple[str, ...] = field(default_factory=tuple)

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
            "per_gap": {str(g.gap): {"ir": g.ir, "ge": g.ge, "valid_pairs": g.valid_pairs, "total_pairs": g.total_pairs} for g in bg.chosen.per_gap},
            "coverage": {
                "frames": self.video.get("num_frames"),
                "duplicates": len(self.video.get("duplicates", [])),
                "cuts": len(self.video.get("cuts", [])),
                "invalid_reasons": bg.chosen.invalid_reasons,
            },
            "category": self.category,
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
            "category": self.category,
            "warnings": list(self.warnings),
        }


def _fit_from(d: dict | None) -> FitSummary | None:
    return None if d is None else FitSummary(**d)


def _family_from(d: dict) -> FamilySummary:
    return FamilySummary(
        family=d["family"], ir=d["ir"], ge=d["ge"], valid_pairs=d["valid_pairs"], total_pairs=d["total_pairs"],
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
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for name in MatchArrays.NAMES:
            info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            arr = io.BytesIO()
            np.lib.format.write_array(arr, np.ascontiguousarray(getattr(record.matches, name)), allow_pickle=False)
            zf.writestr(info, arr.getvalue())
    for name, data in (("matches.npz", buf.getvalue()), ("record.json", _dumps(record.to_json_dict()).encode())):
        tmp = out / f".{name}.part"
        tmp.write_bytes(data)
        tmp.replace(out / name)
    return out / "record.json"


def read_record(path: str | Path) -> ClipRecord:
    """Read a record from its folder or its ``record.json``."""
    p = Path(path)
    folder = p if p.is_dir() else p.parent
    d = json.loads((folder / "record.json").read_text())
    if d.get("format") != RECORD_FORMAT:
        raise ValueError(f"{folder / 'record.json'}: not a GeoCon record (format {d.get('format')!r}, expected {RECORD_FORMAT!r})")
    with np.load(folder / "matches.npz", allow_pickle=False) as z:
        matches = MatchArrays(**{name: z[name] for name in MatchArrays.NAMES})
    g = d["gate"]
    gate = GateRecord(**{**g, "timeline": tuple(GateWindow(**w) for w in g["timeline"])})
    b = d["background"]
    background = BackgroundSummary(**{**b, "chosen": _family_from(b["chosen"]), "other": _family_from(b["other"])})
    pairs = tuple(PairRecord(**{**p, "h": _fit_from(p["h"]), "f": _fit_from(p["f"])}) for p in d["pairs"])
    return ClipRecord(
        clip=d["clip"], video=d["video"], config=ScoreConfig.from_dict(d["config"]), config_hash=d["config_hash"],
        versions=d["versions"], gate=gate, background=background, pairs=pairs, matches=matches,
        intrinsics=d["intrinsics"], category=d["category"], warnings=tuple(d["warnings"]),
    )
