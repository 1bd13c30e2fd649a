"""Re-gating stored residuals at other thresholds, without re-fitting.

Re-gating uses the same float32 residuals and the same inlier rule as the fit
(:func:`geocon_core.geometry.models.inlier_stats`) and the same aggregation and verdict rules as the
scorer (:mod:`geocon_core.scoring.verdict`), so at the recorded thresholds :func:`regate_family`
reproduces the record's IR and GE and :func:`regate_clip` the record's verdict exactly.

>>> from geocon_core.record import read_record
>>> rec = read_record("geocon-out/clip")                       # doctest: +SKIP
>>> regate_family(rec, "H", 3.0).ir                           # doctest: +SKIP
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property
from pathlib import Path
from typing import Any, Iterable, Sequence

import numpy as np

from ..config import ScoreConfig
from ..geometry import FAMILIES, family_spec, inlier_mask, segment_inlier_stats, segment_order
from ..reconstruction import DriftLayer
from ..record import (
    DRIFT_MARGIN,
    ClipRecord,
    GapSummary,
    GateWindow,
    MatchArrays,
    PairRecord,
    pairs_from_json,
    read_matches,
    read_record_json,
)
from .verdict import (
    ClipVerdict,
    Family,
    FitRow,
    Thresholds,
    aggregate_gap_arrays,
    combine_shots,
    family_verdict,
    gate_shot,
    window_t_inf,
)

__all__ = [
    "with_drift",
    "Regated",
    "regate_family",
    "regate_pairs",
    "pair_inliers",
    "timeline_rows",
    "sensitivity_scan",
    "Residuals",
    "ResidualArrays",
    "ShotGate",
    "load_residuals",
    "regate_clip",
]


@dataclass(frozen=True)
class Regated:
    """A family's clip score at threshold ``tau`` (H: px; F: normalised Sampson units)."""

    family: Family
    tau: float
    ir: float | None
    ge: float | None
    valid_pairs: int
    per_gap: tuple[GapSummary, ...]
    independent_share: float = 0.0
    """As :attr:`~geocon_core.record.FamilySummary.independent_share` (the stored flags: it does
    not depend on ``tau``)."""


@dataclass(frozen=True, eq=False)
class PairTable:
    """A record's pairs as arrays, per family: where the family can be re-gated at all (pair
    scored, model fitted) and each pair's matches sorted by residual."""

    gap: np.ndarray
    scale: np.ndarray
    index: np.ndarray
    judgeable: np.ndarray
    t0: np.ndarray
    t1: np.ndarray
    usable: dict[str, np.ndarray]
    order: dict[str, np.ndarray]

    @classmethod
    def of(cls, pairs: Sequence[PairRecord], matches: "ResidualArrays | MatchArrays") -> "PairTable":
        usable = {}
        for fam, spec in FAMILIES.items():
            fits = [p.fit(spec.name) for p in pairs]
            usable[fam] = np.array(
                [p.skip is None and f is not None and f.model is not None for p, f in zip(pairs, fits, strict=True)],
                dtype=bool,
            )
        return cls(
            gap=np.array([p.gap for p in pairs], dtype=np.int64),
            scale=np.array([p.scale for p in pairs], dtype=np.float64),
            index=np.array([p.index for p in pairs], dtype=np.int64),
            judgeable=np.array([p.skip is None for p in pairs], dtype=bool),
            t0=np.array([p.t0 for p in pairs], dtype=np.int64),
            t1=np.array([p.t1 for p in pairs], dtype=np.int64),
            usable=usable,
            order={
                name: segment_order(getattr(matches, spec.residual_px), matches.offsets)
                for name, spec in FAMILIES.items()
            },
        )


def _pair_table(record: "ClipRecord | Residuals") -> PairTable:
    if isinstance(record, Residuals):
        return record.table
    return PairTable.of(record.pairs, record.matches)


def _regate_arrays(
    record: "ClipRecord | Residuals", family: Family, tau: float, min_inliers: int | None
) -> tuple[PairTable, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(pair table, valid, IR, GE, moved) per pair of ``record.pairs`` at ``tau``; IR and GE are
    NaN where not valid; ``moved`` is the share of the pair's matches that move on their own
    (the stored flags, whatever ``tau``; NaN where the family has no model or the pair no match)."""
    spec = family_spec(family)
    need = record.config.min_inliers if min_inliers is None else min_inliers
    m = record.matches
    res, px = getattr(m, spec.residual), getattr(m, spec.residual_px)
    table = _pair_table(record)
    independent = getattr(m, spec.independent, None)
    k, n, ge = segment_inlier_stats(res, px, m.offsets, tau, order=table.order[family], exclude=independent)
    k, n, ge = k[table.index], n[table.index], ge[table.index]
    total = np.diff(np.asarray(m.offsets, dtype=np.int64))[table.index]
    # n counts the matches left after the independent ones; NaN where the family has no model or no match
    moved = np.where(table.usable[family] & (total > 0), (total - n) / np.maximum(total, 1), np.nan)
    valid = table.usable[family] & (n > 0) & (k >= need) & (k > 0)
    valid &= moved <= record.config.independent.max_share  # a pair whose background mostly moves on its own
    ir = np.where(valid, k / np.maximum(n, 1), np.nan)
    return table, valid, ir, np.where(valid, ge, np.nan), moved


def regate_pairs(
    record: "ClipRecord | Residuals", family: Family, tau: float, *, min_inliers: int | None = None
) -> list[tuple[PairRecord, FitRow]]:
    """Every pair of a record with its IR and GE re-gated at ``tau`` (the rows behind
    :func:`regate_family`). A pair is valid when it was scored, its model exists and it keeps at
    least ``min_inliers`` (default: the record's) inliers."""
    _, valid, ir, ge, _ = _regate_arrays(record, family, tau, min_inliers)
    return [
        (p, FitRow(p.gap, p.scale, bool(v), float(i) if v else None, float(g) if v else None, p.skip is None))
        for p, v, i, g in zip(record.pairs, valid, ir, ge, strict=True)
    ]


def pair_inliers(record: "ClipRecord | Residuals", index: int, family: Family, tau: float) -> np.ndarray:
    """The inlier mask of pair ``index``'s matches under ``family`` at threshold ``tau``
    (:func:`~geocon_core.geometry.models.inlier_mask`); matches that move on their own (the record's
    independent motion) are never inliers, as in the fit."""
    spec = family_spec(family)
    rows = record.matches.rows(index)
    inl = inlier_mask(getattr(record.matches, spec.residual)[rows], tau)
    moving = getattr(record.matches, spec.independent, None)
    return inl if moving is None else inl & ~moving[rows]


def regate_family(
    record: "ClipRecord | Residuals",
    family: Family,
    tau: float,
    *,
    min_inliers: int | None = None,
    frames: tuple[int, int] | None = None,
) -> Regated:
    """Re-gate one family of a record at threshold ``tau`` from its stored residuals (no
    re-fitting: the models stay those of the scoring run); pairs as in :func:`regate_pairs`.
    ``frames`` (first, last), inclusive, keeps only the pairs inside them (one shot of a clip
    with cuts)."""
    table, valid, ir, ge, moved = _regate_arrays(record, family, tau, min_inliers)
    cfg = record.config
    keep = slice(None) if frames is None else (table.t0 >= frames[0]) & (table.t1 <= frames[1])
    per_gap, ir_c, ge_c = aggregate_gap_arrays(
        table.gap[keep],
        table.scale[keep],
        valid[keep],
        ir[keep],
        ge[keep],
        gaps=cfg.gaps,
        scales=cfg.scales,
        aggregation=cfg.aggregation,
        judgeable=table.judgeable[keep],
        min_coverage=cfg.min_coverage,
    )
    return Regated(
        family=family,
        tau=float(tau),
        ir=ir_c,
        ge=ge_c,
        independent_share=float(np.nanmedian(moved[keep])) if np.isfinite(moved[keep]).any() else 0.0,
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
    out: list[Regated] = []
    grids: tuple[tuple[Family, Sequence[float]], ...] = (("H", tau_h), ("F", tau_f))
    for family, grid in grids:
        recorded = getattr(cfg, family_spec(family).threshold)
        taus = sorted(set(float(t) for t in grid) | {float(recorded)})
        out.extend(regate_family(record, family, t) for t in taus)
    return out


# --- live re-gating of whole clips (the viewers' threshold controls) ---------------------------


@dataclass(frozen=True)
class ShotGate:
    """What re-gating one shot of a clip with cuts needs: its frames (inclusive) and its gate."""

    start: int
    end: int
    t_inf: float | None
    pose_present: bool
    t_window: float | None = None
    """The largest gate window inside the shot (:func:`~geocon_core.scoring.verdict.window_t_inf`)."""


def timeline_rows(timeline: Iterable[GateWindow | dict[str, Any]]) -> list[tuple[int, int, float | None, bool]]:
    """A record's gate windows (its :class:`~geocon_core.record.GateWindow` objects, or their JSON
    dicts) as the ``(start, end, t_inf, pose_present)`` rows of
    :func:`~geocon_core.scoring.verdict.window_t_inf`."""
    return [
        (int(w["start"]), int(w["end"]), w["t_inf"], bool(w["pose_present"]))
        if isinstance(w, dict)
        else (w.start, w.end, w.t_inf, w.pose_present)
        for w in timeline
    ]


@dataclass(frozen=True, eq=False)
class ResidualArrays:
    """The per-match residuals of a record, without coordinates (see :class:`MatchArrays`)."""

    offsets: np.ndarray
    h_res: np.ndarray
    f_res: np.ndarray
    f_res_px: np.ndarray
    h_ind: np.ndarray | None = None
    f_ind: np.ndarray | None = None

    NAMES = ("offsets", "h_res", "f_res", "f_res_px")
    OPTIONAL = ("h_ind", "f_ind")

    def rows(self, index: int) -> slice:
        """The rows of pair ``index`` (as :meth:`MatchArrays.rows`)."""
        return slice(int(self.offsets[index]), int(self.offsets[index + 1]))


class Residuals:
    """What re-gating a clip needs from its record (a few hundred kB, where the record with match
    coordinates, object cells and point cloud can be several MB). Its fields are fixed at
    construction; :attr:`table`, the pair arrays every re-gate needs, is derived on first use and
    kept (a viewer re-gates the same clip many times)."""

    def __init__(
        self,
        config: ScoreConfig,
        pairs: tuple[PairRecord, ...],
        matches: "ResidualArrays | MatchArrays",
        t_inf: float | None,
        pose_present: bool,
        shots: tuple[ShotGate, ...] = (),
        t_window: float | None = None,
        drift: str | None = None,
    ) -> None:
        self.drift = drift
        """What the multi-view check found when it failed the background (it does not depend on
        the thresholds re-gating moves), else None."""
        self.config = config
        self.pairs = pairs
        self.matches = matches
        self.t_inf = t_inf
        self.pose_present = pose_present
        self.shots = shots
        self.t_window = t_window

    def __repr__(self) -> str:
        return f"Residuals({len(self.pairs)} pairs, t_inf={self.t_inf}, pose_present={self.pose_present})"

    @classmethod
    def of(cls, record: ClipRecord) -> "Residuals":
        rows = timeline_rows(record.gate.timeline)
        shots = tuple(
            ShotGate(s.start, s.end, s.t_inf, s.pose_present, window_t_inf(rows, (s.start, s.end)))
            for s in record.shots
        )
        t_window = window_t_inf(rows, (0, record.video.num_frames - 1))
        return cls(
            record.config,
            record.pairs,
            record.matches,
            record.gate.t_inf,
            record.gate.pose_present,
            shots,
            t_window,
            record.drift_finding(),
        )

    @cached_property
    def table(self) -> PairTable:
        """The pairs as arrays and each pair's matches sorted by residual (derived once)."""
        return PairTable.of(self.pairs, self.matches)

    def prepare(self) -> "Residuals":
        """Derive now what the first re-gate would (:attr:`table`); returns self."""
        _ = self.table
        return self


def load_residuals(folder: str | Path) -> Residuals:
    """:class:`Residuals` of the record in ``folder``, reading no coordinates, cells or cloud."""
    path, d = read_record_json(folder)
    arrays = ResidualArrays(**read_matches(path, ResidualArrays.NAMES, ResidualArrays.OPTIONAL))  # nothing unpickled
    pairs = pairs_from_json(d)
    gate = d["gate"]
    rows = timeline_rows(gate.get("timeline", []))
    shots = tuple(
        ShotGate(s["start"], s["end"], s["t_inf"], bool(s["pose_present"]), window_t_inf(rows, (s["start"], s["end"])))
        for s in d.get("shots", [])
    )
    cfg = ScoreConfig.from_dict(d["config"])
    t_window = window_t_inf(rows, (0, int(d["video"]["num_frames"]) - 1))
    mv = d.get("multiview") or {}
    layers = mv.get("layers") or []
    drift = (
        DriftLayer.from_dict(layers[0]).describe()
        if layers and cfg.multiview.enabled and not mv.get("reason")
        else None
    )
    return Residuals(cfg, pairs, arrays, gate["t_inf"], bool(gate["pose_present"]), shots, t_window, drift)


def regate_clip(source: ClipRecord | Residuals, thresholds: Thresholds) -> ClipVerdict:
    """The whole clip re-gated at ``thresholds`` from its stored residuals: both families at
    ``tau_h`` / ``tau_f``, then the gate and report rules (:func:`family_verdict`). At the recorded
    thresholds this is the record's verdict exactly."""
    res = source if isinstance(source, Residuals) else Residuals.of(source)
    if res.shots:  # a clip with cuts: each shot on its own, combined as the scorer does
        verdicts = [
            family_verdict(
                regate_family(res, "H", thresholds.tau("H"), frames=(s.start, s.end)),
                regate_family(res, "F", thresholds.tau("F"), frames=(s.start, s.end)),
                t_inf=s.t_inf,
                pose_present=s.pose_present,
                thresholds=thresholds,
                t_window=s.t_window,
            )
            for s in res.shots
        ]
        return with_drift(combine_shots(verdicts, gate_shot([(s.start, s.end) for s in res.shots])), res.drift)
    h = regate_family(res, "H", thresholds.tau("H"))
    f = regate_family(res, "F", thresholds.tau("F"))
    return with_drift(
        family_verdict(
            h, f, t_inf=res.t_inf, pose_present=res.pose_present, thresholds=thresholds, t_window=res.t_window
        ),
        res.drift,
    )


def with_drift(verdict: ClipVerdict, drift: str | None) -> ClipVerdict:
    """A verdict the multi-view check fails when it found a drifting layer (as the scorer does):
    a background that passes its pair fits becomes inconsistent, its headroom at most minus
    :data:`~geocon_core.record.finding.DRIFT_MARGIN`."""
    if drift is None or verdict.consistent is not True:
        return verdict
    margin = -DRIFT_MARGIN if verdict.report_margin is None else min(verdict.report_margin, -DRIFT_MARGIN)
    return replace(verdict, consistent=False, report_margin=margin)
