"""Clip aggregation of pair scores, and re-gating stored residuals at other thresholds.

The scorer and every re-gating path (threshold-score sensitivity scans, the viewers' live
thresholds) share :func:`aggregate_gaps`, and re-gating uses the same float32 residuals and the
same inlier rule as the fit (:func:`geocon_core.models.inlier_stats`), so at the recorded
thresholds :func:`regate_family` reproduces the record's IR and GE exactly.

>>> from geocon_core.record import read_record
>>> rec = read_record("geocon-out/clip")                       # doctest: +SKIP
>>> regate_family(rec, "H", 3.0).ir                           # doctest: +SKIP
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal, Sequence

import numpy as np

from .config import ScoreConfig
from .gate import gate_decision
from .models import inlier_stats
from .record import ClipRecord, GapSummary, MatchArrays, PairRecord

__all__ = [
    "FitRow", "Regated", "aggregate_gaps", "regate_family", "regate_pairs", "pair_inliers", "DEFAULT_TAU_H_GRID", "DEFAULT_TAU_F_GRID", "sensitivity_scan",
    "Thresholds", "ClipVerdict", "Residuals", "ResidualArrays", "choose_model", "report_verdict", "report_margin", "clip_verdict",
    "load_residuals", "regate_clip",
]

Family = Literal["H", "F"]

DEFAULT_TAU_H_GRID = (0.5, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0)
"""Symmetric transfer error thresholds (px) of the default sensitivity scan."""
DEFAULT_TAU_F_GRID = (0.025, 0.05, 0.075, 0.1, 0.15, 0.2, 0.3)
"""Normalised Sampson thresholds of the default sensitivity scan."""


@dataclass(frozen=True)
class FitRow:
    """One family's score on one (pair, scale): ``valid`` pairs carry IR and GE (px)."""

    gap: int
    scale: float
    valid: bool
    ir: float | None
    ge: float | None


def _median(values: list[float]) -> float | None:
    return float(np.median(values)) if values else None


def aggregate_gaps(
    rows: Sequence[FitRow], *, gaps: Sequence[int], scales: Sequence[float], aggregation: str
) -> tuple[tuple[GapSummary, ...], float | None, float | None]:
    """Per-gap summaries and the clip's headline IR and GE (see ``ScoreConfig.aggregation``).

    ``median`` (the paper): per gap, the median IR and GE over its valid (pair, scale) rows;
    ``worst``: per gap and scale the median over pairs, and the gap takes its lowest IR and
    highest GE. The headline is the lowest per-gap IR and the highest per-gap GE."""
    per_gap = []
    for gap in gaps:
        mine = [r for r in rows if r.gap == gap]
        valid = [r for r in mine if r.valid]
        if aggregation == "median":
            ir, ge = _median([r.ir for r in valid]), _median([r.ge for r in valid])
        elif aggregation == "worst":
            cells = [[r for r in valid if r.scale == s] for s in scales]
            irs = [m for m in (_median([r.ir for r in c]) for c in cells) if m is not None]
            ges = [m for m in (_median([r.ge for r in c]) for c in cells) if m is not None]
            ir, ge = (min(irs) if irs else None), (max(ges) if ges else None)
        else:
            raise ValueError(f"aggregation must be 'median' or 'worst', got {aggregation!r}")
        per_gap.append(GapSummary(gap=gap, ir=ir, ge=ge, valid_pairs=len(valid), total_pairs=len(mine)))
    irs = [g.ir for g in per_gap if g.ir is not None]
    ges = [g.ge for g in per_gap if g.ge is not None]
    return tuple(per_gap), (min(irs) if irs else None), (max(ges) if ges else None)


@dataclass(frozen=True)
class Regated:
    """A family's clip score at threshold ``tau`` (H: px; F: normalised Sampson units)."""

    family: Family
    tau: float
    ir: float | None
    ge: float | None
    valid_pairs: int
    per_gap: tuple[GapSummary, ...]


def regate_pairs(record: "ClipRecord | Residuals", family: Family, tau: float, *, min_inliers: int | None = None) -> list[tuple[PairRecord, FitRow]]:
    """Every pair of a record with its IR and GE re-gated at ``tau`` (the rows behind
    :func:`regate_family`). A pair is valid when it was scored, its model exists and it keeps at
    least ``min_inliers`` (default: the record's) inliers."""
    if family not in ("H", "F"):
        raise ValueError(f"family must be 'H' or 'F', got {family!r}")
    need = record.config.min_inliers if min_inliers is None else min_inliers
    res_name, px_name = ("h_res", "h_res") if family == "H" else ("f_res", "f_res_px")
    res_all, px_all = getattr(record.matches, res_name), getattr(record.matches, px_name)
    rows = []
    for p in record.pairs:
        fit = p.fit(family)
        if p.skip is not None or fit is None or fit.model is None:
            rows.append((p, FitRow(p.gap, p.scale, False, None, None)))
            continue
        sl = record.matches.rows(p.index)
        inl, ir, ge = inlier_stats(res_all[sl], px_all[sl], tau)
        valid = int(np.count_nonzero(inl)) >= need
        rows.append((p, FitRow(p.gap, p.scale, valid, ir if valid else None, ge if valid else None)))
    return rows


def pair_inliers(record: "ClipRecord | Residuals", index: int, family: Family, tau: float) -> np.ndarray:
    """The inlier mask of pair ``index``'s matches under ``family`` at threshold ``tau`` (the rule
    of every re-gating: stored residual <= tau)."""
    if family not in ("H", "F"):
        raise ValueError(f"family must be 'H' or 'F', got {family!r}")
    res = record.matches.h_res if family == "H" else record.matches.f_res
    return res[record.matches.rows(index)] <= np.float32(tau)


def regate_family(record: "ClipRecord | Residuals", family: Family, tau: float, *, min_inliers: int | None = None) -> Regated:
    """Re-gate one family of a record at threshold ``tau`` from its stored residuals (no
    re-fitting: the models stay those of the scoring run); pairs as in :func:`regate_pairs`."""
    rows = [row for _, row in regate_pairs(record, family, tau, min_inliers=min_inliers)]
    cfg = record.config
    per_gap, ir, ge = aggregate_gaps(rows, gaps=cfg.gaps, scales=cfg.scales, aggregation=cfg.aggregation)
    return Regated(family=family, tau=float(tau), ir=ir, ge=ge, valid_pairs=sum(g.valid_pairs for g in per_gap), per_gap=per_gap)


def sensitivity_scan(
    record: ClipRecord,
    *,
    tau_h: Sequence[float] = DEFAULT_TAU_H_GRID,
    tau_f: Sequence[float] = DEFAULT_TAU_F_GRID,
) -> list[Regated]:
    """The threshold-score scan of one clip: every tau of both grids, plus the recorded
    thresholds when the grids lack them (so the scan always contains the record's values)."""
    cfg = record.config
    out = []
    for family, grid, recorded in (("H", tau_h, cfg.tau_h), ("F", tau_f, cfg.tau_f)):
        taus = sorted(set(float(t) for t in grid) | {float(recorded)})
        out.extend(regate_family(record, family, t) for t in taus)  # type: ignore[arg-type]
    return out


# --- live re-gating of whole clips (the viewers' threshold controls) ---------------------------

@dataclass(frozen=True)
class Thresholds:
    """Every threshold an inspector may move without re-scoring: the residual thresholds
    (``tau_h`` px, ``tau_f`` normalised Sampson), the report gates and the hysteresis gate."""

    tau_h: float
    tau_f: float
    ir_gate: float
    ge_gate: float
    tau_t_low: float
    tau_t_high: float

    NAMES = ("tau_h", "tau_f", "ir_gate", "ge_gate", "tau_t_low", "tau_t_high")

    @classmethod
    def of(cls, config: ScoreConfig) -> "Thresholds":
        """The thresholds a record was scored with."""
        return cls(**{name: float(getattr(config, name)) for name in cls.NAMES})

    def __post_init__(self) -> None:
        if self.tau_h <= 0 or self.tau_f <= 0:
            raise ValueError(f"tau_h and tau_f must be positive, got {self.tau_h} and {self.tau_f}")
        if not self.tau_t_low <= self.tau_t_high:
            raise ValueError(f"the gate's low threshold {self.tau_t_low} exceeds its high threshold {self.tau_t_high}")

    def changed(self, recorded: "Thresholds") -> dict[str, tuple[float, float]]:
        """``name -> (recorded, now)`` for every threshold that differs from ``recorded``."""
        return {n: (getattr(recorded, n), getattr(self, n)) for n in self.NAMES if getattr(self, n) != getattr(recorded, n)}


def choose_model(label: str, pose_present: bool, ir_h: float | None, ir_f: float | None) -> Family:
    """The family that scores the background: the gate's label, the one with the higher IR in the
    gray zone (an unjudged family counts as IR -1, ties go to H), F when there is no pose."""
    if not pose_present:
        return "F"
    if label == "U":
        return "H" if (-1.0 if ir_h is None else ir_h) >= (-1.0 if ir_f is None else ir_f) else "F"
    return label  # type: ignore[return-value]


def report_verdict(ir: float | None, ge: float | None, ir_gate: float, ge_gate: float) -> bool | None:
    """The report gate: consistent when ``ir >= ir_gate`` and ``ge <= ge_gate``; None when the
    background could not be judged (no valid pair)."""
    if ir is None or ge is None:
        return None
    return bool(ir >= ir_gate and ge <= ge_gate)


def report_margin(ir: float | None, ge: float | None, ir_gate: float, ge_gate: float) -> float | None:
    """Headroom to the report gate as a fraction of each gate's range, the smaller of
    ``(ir - ir_gate) / (1 - ir_gate)`` and ``(ge_gate - ge) / ge_gate``: negative exactly when the
    clip fails the report gate, None when it cannot be judged."""
    if ir is None or ge is None:
        return None
    ir_room = (ir - ir_gate) / (1.0 - ir_gate) if ir_gate < 1.0 else ir - ir_gate
    return float(min(ir_room, (ge_gate - ge) / ge_gate if ge_gate > 0 else ge_gate - ge))


@dataclass(frozen=True)
class ClipVerdict:
    """A clip's gate and background verdict under some :class:`Thresholds`: the hysteresis
    ``label`` and ``margin`` (None without a pose), the family used and its IR/GE, both families'
    values, the report gate verdict and its :func:`report_margin`."""

    label: str
    model: Family
    margin: float | None
    ir: float | None
    ge: float | None
    consistent: bool | None
    report_margin: float | None
    ir_h: float | None
    ge_h: float | None
    ir_f: float | None
    ge_f: float | None


def clip_verdict(
    *, t_inf: float | None, pose_present: bool, ir_h: float | None, ge_h: float | None, ir_f: float | None, ge_f: float | None,
    thresholds: Thresholds,
) -> ClipVerdict:
    """The verdict from a clip's gate statistic and both families' scores (the scorer's rule)."""
    label, _, margin = gate_decision(t_inf, pose_present=pose_present, low=thresholds.tau_t_low, high=thresholds.tau_t_high)
    model = choose_model(label, pose_present and t_inf is not None, ir_h, ir_f)
    ir, ge = (ir_h, ge_h) if model == "H" else (ir_f, ge_f)
    return ClipVerdict(
        label=label, model=model, margin=margin, ir=ir, ge=ge,
        consistent=report_verdict(ir, ge, thresholds.ir_gate, thresholds.ge_gate),
        report_margin=report_margin(ir, ge, thresholds.ir_gate, thresholds.ge_gate),
        ir_h=ir_h, ge_h=ge_h, ir_f=ir_f, ge_f=ge_f,
    )


@dataclass(frozen=True, eq=False)
class ResidualArrays:
    """The per-match residuals of a record, without coordinates (see :class:`MatchArrays`)."""

    offsets: np.ndarray
    h_res: np.ndarray
    f_res: np.ndarray
    f_res_px: np.ndarray

    NAMES = ("offsets", "h_res", "f_res", "f_res_px")

    def rows(self, index: int) -> slice:
        return slice(int(self.offsets[index]), int(self.offsets[index + 1]))


@dataclass(frozen=True, eq=False)
class Residuals:
    """What re-gating a clip needs from its record (a few hundred kB, where the record with match
    coordinates, object cells and point cloud can be several MB)."""

    config: ScoreConfig
    pairs: tuple[PairRecord, ...]
    matches: ResidualArrays | MatchArrays
    t_inf: float | None
    pose_present: bool

    @classmethod
    def of(cls, record: ClipRecord) -> "Residuals":
        return cls(record.config, record.pairs, record.matches, record.gate.t_inf, record.gate.pose_present)

    @classmethod
    def load(cls, folder: str | Path) -> "Residuals":
        """Read only the residuals of the record in ``folder`` (``record.json`` + ``matches.npz``)."""
        return load_residuals(folder)


def load_residuals(folder: str | Path) -> Residuals:
    """:class:`Residuals` of the record in ``folder``, reading no coordinates, cells or cloud."""
    import json

    from .record import RECORD_FORMAT, _fit_from

    path = Path(folder)
    path = path if path.is_dir() else path.parent
    d = json.loads((path / "record.json").read_text())
    if d.get("format") != RECORD_FORMAT:
        raise ValueError(f"{path / 'record.json'}: not a GeoCon record (format {d.get('format')!r})")
    with np.load(path / "matches.npz", allow_pickle=False) as z:
        arrays = ResidualArrays(**{name: z[name] for name in ResidualArrays.NAMES})
    pairs = tuple(PairRecord(**{**p, "h": _fit_from(p["h"]), "f": _fit_from(p["f"])}) for p in d["pairs"])
    gate = d["gate"]
    return Residuals(ScoreConfig.from_dict(d["config"]), pairs, arrays, gate["t_inf"], bool(gate["pose_present"]))


def regate_clip(source: ClipRecord | Residuals, thresholds: Thresholds) -> ClipVerdict:
    """The whole clip re-gated at ``thresholds`` from its stored residuals: both families at
    ``tau_h`` / ``tau_f``, then the gate and report rules (:func:`clip_verdict`). At the recorded
    thresholds this is the record's verdict exactly."""
    res = source if isinstance(source, Residuals) else Residuals.of(source)
    h = regate_family(res, "H", thresholds.tau_h)  # type: ignore[arg-type]
    f = regate_family(res, "F", thresholds.tau_f)  # type: ignore[arg-type]
    return clip_verdict(t_inf=res.t_inf, pose_present=res.pose_present, ir_h=h.ir, ge_h=h.ge, ir_f=f.ir, ge_f=f.ge, thresholds=thresholds)
