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
from typing import Literal, Sequence

import numpy as np

from .models import inlier_stats
from .record import ClipRecord, GapSummary

__all__ = ["FitRow", "Regated", "aggregate_gaps", "regate_family", "DEFAULT_TAU_H_GRID", "DEFAULT_TAU_F_GRID", "sensitivity_scan"]

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


def regate_family(record: ClipRecord, family: Family, tau: float, *, min_inliers: int | None = None) -> Regated:
    """Re-gate one family of a record at threshold ``tau`` from its stored residuals (no
    re-fitting: the models stay those of the scoring run). A pair is valid when it was scored,
    its model exists and it keeps at least ``min_inliers`` (default: the record's) inliers."""
    if family not in ("H", "F"):
        raise ValueError(f"family must be 'H' or 'F', got {family!r}")
    cfg = record.config
    need = cfg.min_inliers if min_inliers is None else min_inliers
    res_name, px_name = ("h_res", "h_res") if family == "H" else ("f_res", "f_res_px")
    res_all, px_all = getattr(record.matches, res_name), getattr(record.matches, px_name)
    rows = []
    for p in record.pairs:
        fit = p.fit(family)
        if p.skip is not None or fit is None or fit.model is None:
            rows.append(FitRow(p.gap, p.scale, False, None, None))
            continue
        sl = record.matches.rows(p.index)
        inl, ir, ge = inlier_stats(res_all[sl], px_all[sl], tau)
        valid = int(np.count_nonzero(inl)) >= need
        rows.append(FitRow(p.gap, p.scale, valid, ir if valid else None, ge if valid else None))
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
