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

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal, Sequence

import numpy as np

from .config import ScoreConfig
from .gate import gate_decision
from .models import inlier_mask, segment_inlier_stats, segment_order
from .record import ClipRecord, GapSummary, MatchArrays, PairRecord, pairs_from_json, read_record_json

__all__ = [
    "FitRow",
    "Regated",
    "aggregate_gaps",
    "regate_family",
    "regate_pairs",
    "pair_inliers",
    "sensitivity_scan",
    "Thresholds",
    "ClipVerdict",
    "Residuals",
    "ResidualArrays",
    "choose_model",
    "report_verdict",
    "report_margin",
    "clip_verdict",
    "load_residuals",
    "regate_clip",
]

Family = Literal["H", "F"]


@dataclass(frozen=True)
class FitRow:
    """One family's score on one (pair, scale): ``valid`` pairs carry IR and GE (px)."""

    gap: int
    scale: float
    valid: bool
    ir: float | None
    ge: float | None


def _median(values: np.ndarray) -> float | None:
    return float(np.median(values)) if len(values) else None


def _aggregate(
    gap: np.ndarray,
    scale: np.ndarray,
    valid: np.ndarray,
    ir: np.ndarray,
    ge: np.ndarray,
    *,
    gaps: Sequence[int],
    scales: Sequence[float],
    aggregation: str,
) -> tuple[tuple[GapSummary, ...], float | None, float | None]:
    """:func:`aggregate_gaps` on per-row arrays (float64 IR/GE, NaN where not valid)."""
    per_gap = []
    for g in gaps:
        mine = gap == g
        ok = mine & valid
        if aggregation == "median":
            ir_g, ge_g = _median(ir[ok]), _median(ge[ok])
        elif aggregation == "worst":
            cells = [ok & (scale == s) for s in scales]
            irs = [m for m in (_median(ir[c]) for c in cells) if m is not None]
            ges = [m for m in (_median(ge[c]) for c in cells) if m is not None]
            ir_g, ge_g = (min(irs) if irs else None), (max(ges) if ges else None)
        else:
            raise ValueError(f"aggregation must be 'median' or 'worst', got {aggregation!r}")
        per_gap.append(GapSummary(gap=g, ir=ir_g, ge=ge_g, valid_pairs=int(ok.sum()), total_pairs=int(mine.sum())))
    irs = [x.ir for x in per_gap if x.ir is not None]
    ges = [x.ge for x in per_gap if x.ge is not None]
    return tuple(per_gap), (min(irs) if irs else None), (max(ges) if ges else None)


def aggregate_gaps(
    rows: Sequence[FitRow], *, gaps: Sequence[int], scales: Sequence[float], aggregation: str
) -> tuple[tuple[GapSummary, ...], float | None, float | None]:
    """Per-gap summaries and the clip's headline IR and GE (see ``ScoreConfig.aggregation``).

    ``median`` (the paper): per gap, the median IR and GE over its valid (pair, scale) rows;
    ``worst``: per gap and scale the median over pairs, and the gap takes its lowest IR and
    highest GE. The headline is the lowest per-gap IR and the highest per-gap GE."""

    def column(name: str) -> np.ndarray:
        return np.array([np.nan if getattr(r, name) is None else getattr(r, name) for r in rows], dtype=np.float64)

    gap = np.array([r.gap for r in rows], dtype=np.int64)
    scale = np.array([r.scale for r in rows], dtype=np.float64)
    valid = np.array([r.valid for r in rows], dtype=bool)
    return _aggregate(gap, scale, valid, column("ir"), column("ge"), gaps=gaps, scales=scales, aggregation=aggregation)


@dataclass(frozen=True)
class Regated:
    """A family's clip score at threshold ``tau`` (H: px; F: normalised Sampson units)."""

    family: Family
    tau: float
    ir: float | None
    ge: float | None
    valid_pairs: int
    per_gap: tuple[GapSummary, ...]


@dataclass(frozen=True, eq=False)
class _PairTable:
    """A record's pairs as arrays, per family: where the family can be re-gated at all (pair
    scored, model fitted) and each pair's matches sorted by residual."""

    gap: np.ndarray
    scale: np.ndarray
    index: np.ndarray
    usable: dict[str, np.ndarray]
    order: dict[str, np.ndarray]


def _pair_table(record: "ClipRecord | Residuals") -> _PairTable:
    cached = record.cache.get("pairs") if isinstance(record, Residuals) else None
    if cached is not None:
        return cached
    pairs = record.pairs
    usable = {}
    for fam in ("H", "F"):
        fits = [p.fit(fam) for p in pairs]
        usable[fam] = np.array(
            [p.skip is None and f is not None and f.model is not None for p, f in zip(pairs, fits)], dtype=bool
        )
    m = record.matches
    table = _PairTable(
        gap=np.array([p.gap for p in pairs], dtype=np.int64),
        scale=np.array([p.scale for p in pairs], dtype=np.float64),
        index=np.array([p.index for p in pairs], dtype=np.int64),
        usable=usable,
        order={"H": segment_order(m.h_res, m.offsets), "F": segment_order(m.f_res_px, m.offsets)},
    )
    if isinstance(record, Residuals):  # kept: a viewer re-gates the same clip many times
        record.cache["pairs"] = table
    return table


def _regate_arrays(
    record: "ClipRecord | Residuals", family: Family, tau: float, min_inliers: int | None
) -> tuple[_PairTable, np.ndarray, np.ndarray, np.ndarray]:
    """(pair table, valid, IR, GE) per pair of ``record.pairs`` at ``tau``; IR and GE are NaN
    where not valid."""
    if family not in ("H", "F"):
        raise ValueError(f"family must be 'H' or 'F', got {family!r}")
    need = record.config.min_inliers if min_inliers is None else min_inliers
    m = record.matches
    res, px = (m.h_res, m.h_res) if family == "H" else (m.f_res, m.f_res_px)
    table = _pair_table(record)
    k, n, ge = segment_inlier_stats(res, px, m.offsets, tau, order=table.order[family])
    k, n, ge = k[table.index], n[table.index], ge[table.index]
    valid = table.usable[family] & (n > 0) & (k >= need) & (k > 0)
    ir = np.where(valid, k / np.maximum(n, 1), np.nan)
    return table, valid, ir, np.where(valid, ge, np.nan)


def regate_pairs(
    record: "ClipRecord | Residuals", family: Family, tau: float, *, min_inliers: int | None = None
) -> list[tuple[PairRecord, FitRow]]:
    """Every pair of a record with its IR and GE re-gated at ``tau`` (the rows behind
    :func:`regate_family`). A pair is valid when it was scored, its model exists and it keeps at
    least ``min_inliers`` (default: the record's) inliers."""
    _, valid, ir, ge = _regate_arrays(record, family, tau, min_inliers)
    return [
        (p, FitRow(p.gap, p.scale, bool(v), float(i) if v else None, float(g) if v else None))
        for p, v, i, g in zip(record.pairs, valid, ir, ge)
    ]


def pair_inliers(record: "ClipRecord | Residuals", index: int, family: Family, tau: float) -> np.ndarray:
    """The inlier mask of pair ``index``'s matches under ``family`` at threshold ``tau``
    (:func:`~geocon_core.models.inlier_mask`)."""
    if family not in ("H", "F"):
        raise ValueError(f"family must be 'H' or 'F', got {family!r}")
    res = record.matches.h_res if family == "H" else record.matches.f_res
    return inlier_mask(res[record.matches.rows(index)], tau)


def regate_family(
    record: "ClipRecord | Residuals", family: Family, tau: float, *, min_inliers: int | None = None
) -> Regated:
    """Re-gate one family of a record at threshold ``tau`` from its stored residuals (no
    re-fitting: the models stay those of the scoring run); pairs as in :func:`regate_pairs`."""
    table, valid, ir, ge = _regate_arrays(record, family, tau, min_inliers)
    cfg = record.config
    per_gap, ir_c, ge_c = _aggregate(
        table.gap, table.scale, valid, ir, ge, gaps=cfg.gaps, scales=cfg.scales, aggregation=cfg.aggregation
    )
    return Regated(
        family=family,
        tau=float(tau),
        ir=ir_c,
        ge=ge_c,
        valid_pairs=sum(g.valid_pairs for g in per_gap),
        per_gap=per_gap,
    )


def sensitivity_scan(
    record: ClipRecord,
    *,
    tau_h: Sequence[float] | None = None,
    tau_f: Sequence[float] | None = None,
) -> list[Regated]:
    """The threshold-score scan of one clip: every tau of both grids (default: the record's
    ``config.scans``), plus the recorded thresholds when the grids lack them (so the scan always
    contains the record's values)."""
    cfg = record.config
    tau_h = cfg.scans.tau_h_grid if tau_h is None else tau_h
    tau_f = cfg.scans.tau_f_grid if tau_f is None else tau_f
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
        return {
            n: (getattr(recorded, n), getattr(self, n)) for n in self.NAMES if getattr(self, n) != getattr(recorded, n)
        }


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
    *,
    t_inf: float | None,
    pose_present: bool,
    ir_h: float | None,
    ge_h: float | None,
    ir_f: float | None,
    ge_f: float | None,
    thresholds: Thresholds,
) -> ClipVerdict:
    """The verdict from a clip's gate statistic and both families' scores (the scorer's rule)."""
    label, _, margin = gate_decision(
        t_inf, pose_present=pose_present, low=thresholds.tau_t_low, high=thresholds.tau_t_high
    )
    model = choose_model(label, pose_present and t_inf is not None, ir_h, ir_f)
    ir, ge = (ir_h, ge_h) if model == "H" else (ir_f, ge_f)
    return ClipVerdict(
        label=label,
        model=model,
        margin=margin,
        ir=ir,
        ge=ge,
        consistent=report_verdict(ir, ge, thresholds.ir_gate, thresholds.ge_gate),
        report_margin=report_margin(ir, ge, thresholds.ir_gate, thresholds.ge_gate),
        ir_h=ir_h,
        ge_h=ge_h,
        ir_f=ir_f,
        ge_f=ge_f,
    )


@dataclass(frozen=True, eq=False)
class ResidualArrays:
    """The per-match residuals of a record, without coordinates (see :class:`MatchArrays`)."""

    offsets: np.ndarray
    h_res: np.ndarray
    f_res: np.ndarray
    f_res_px: np.ndarray

    NAMES = ("offsets", "h_res", "f_res", "f_res_px")

    rows = MatchArrays.rows


@dataclass(frozen=True, eq=False)
class Residuals:
    """What re-gating a clip needs from its record (a few hundred kB, where the record with match
    coordinates, object cells and point cloud can be several MB)."""

    config: ScoreConfig
    pairs: tuple[PairRecord, ...]
    matches: ResidualArrays | MatchArrays
    t_inf: float | None
    pose_present: bool
    cache: dict[str, object] = field(default_factory=dict, repr=False)
    """Arrays derived on the first re-gate and kept for the next ones."""

    @classmethod
    def of(cls, record: ClipRecord) -> "Residuals":
        return cls(record.config, record.pairs, record.matches, record.gate.t_inf, record.gate.pose_present)

    def prepare(self) -> "Residuals":
        """Derive now what the first re-gate would (pair arrays, residual orders); returns self."""
        _pair_table(self)
        return self


def load_residuals(folder: str | Path) -> Residuals:
    """:class:`Residuals` of the record in ``folder``, reading no coordinates, cells or cloud."""
    path, d = read_record_json(folder)
    with np.load(path / "matches.npz", allow_pickle=False) as z:
        arrays = ResidualArrays(**{name: z[name] for name in ResidualArrays.NAMES})
    pairs = pairs_from_json(d)
    gate = d["gate"]
    return Residuals(ScoreConfig.from_dict(d["config"]), pairs, arrays, gate["t_inf"], bool(gate["pose_present"]))


def regate_clip(source: ClipRecord | Residuals, thresholds: Thresholds) -> ClipVerdict:
    """The whole clip re-gated at ``thresholds`` from its stored residuals: both families at
    ``tau_h`` / ``tau_f``, then the gate and report rules (:func:`clip_verdict`). At the recorded
    thresholds this is the record's verdict exactly."""
    res = source if isinstance(source, Residuals) else Residuals.of(source)
    h = regate_family(res, "H", thresholds.tau_h)  # type: ignore[arg-type]
    f = regate_family(res, "F", thresholds.tau_f)  # type: ignore[arg-type]
    return clip_verdict(
        t_inf=res.t_inf,
        pose_present=res.pose_present,
        ir_h=h.ir,
        ge_h=h.ge,
        ir_f=f.ir,
        ge_f=f.ge,
        thresholds=thresholds,
    )
