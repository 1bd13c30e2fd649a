"""Every rule of the clip verdict (SPEC sections 1 and 4), each stated once.

- the translation gate: :func:`hysteresis_gate` (H / U / F), :func:`binary_gate`, their
  :func:`gate_margin`, and :func:`gate_decision` with the fail->F policy for a clip without pose;
- the clip aggregation of pair scores over gaps and scales: :func:`aggregate_gaps` (and
  :func:`summarize_family`, a family's whole :class:`~geocon_core.record.FamilySummary`);
- the model choice (:func:`choose_model`: the gate's label, IR in the gray zone, F without pose);
- the report gate (:func:`report_verdict`) and its headroom (:func:`report_margin`);
- the whole verdict under some :class:`Thresholds` (:func:`family_verdict`; :func:`clip_verdict`
  from plain values), which the scorer and every re-gating path (:mod:`geocon_core.scoring.regate`, the
  results index, the viewers) compose alike;
- which clips deserve an audit (:func:`is_flagged`), for the benchmark, the triage list, the
  report and the audit app.

Default thresholds are those of :class:`~geocon_core.config.ScoreConfig`.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Iterable, Literal, NamedTuple, Protocol, Sequence

import numpy as np

from ..config import ScoreConfig
from ..geometry import PairFits, family_spec
from ..record import Family, FamilySummary, GapSummary, ScaleSummary, report_margin

__all__ = [
    "GateLabel",
    "Family",
    "binary_gate",
    "hysteresis_gate",
    "gate_margin",
    "gate_decision",
    "window_t_inf",
    "FitRow",
    "aggregate_gaps",
    "aggregate_gap_arrays",
    "summarize_family",
    "Thresholds",
    "choose_model",
    "report_verdict",
    "report_margin",
    "ClipVerdict",
    "FamilyScores",
    "Scores",
    "family_verdict",
    "clip_verdict",
    "gate_shot",
    "deciding_shot",
    "combine_shots",
    "flag_reasons",
    "is_flagged",
]

GateLabel = Literal["H", "F", "U"]
"""The translation gate's label: H, F, or U (undecided inside the hysteresis band)."""

_DEFAULTS = ScoreConfig()


# --- the translation gate ----------------------------------------------------------------------


def binary_gate(t_inf: float, tau_t: float | None = None) -> GateLabel:
    """``"F"`` if ``t_inf > tau_t`` else ``"H"`` (default ``ScoreConfig.tau_t``)."""
    tau = _DEFAULTS.tau_t if tau_t is None else tau_t
    return "F" if t_inf > tau else "H"


def hysteresis_gate(t_inf: float, low: float | None = None, high: float | None = None) -> GateLabel:
    """``"H"`` if ``t_inf <= low``, ``"F"`` if ``t_inf >= high``, else ``"U"`` (gray zone); defaults
    ``ScoreConfig.tau_t_low`` / ``tau_t_high``."""
    low = _DEFAULTS.tau_t_low if low is None else low
    high = _DEFAULTS.tau_t_high if high is None else high
    if not low <= high:
        raise ValueError(f"hysteresis thresholds must satisfy low <= high, got {low} > {high}")
    if t_inf <= low:
        return "H"
    if t_inf >= high:
        return "F"
    return "U"


def gate_margin(label: GateLabel, t_inf: float, low: float | None = None, high: float | None = None) -> float:
    """Distance of ``t_inf`` from the threshold its label depends on: ``low - t_inf`` for H,
    ``t_inf - high`` for F; for U, minus the distance to the nearer threshold (negative inside
    the gray zone)."""
    low = _DEFAULTS.tau_t_low if low is None else low
    high = _DEFAULTS.tau_t_high if high is None else high
    if label == "H":
        return low - t_inf
    if label == "F":
        return t_inf - high
    return -min(t_inf - low, high - t_inf)


def gate_decision(
    t_inf: float | None,
    *,
    pose_present: bool,
    tau_t: float | None = None,
    low: float | None = None,
    high: float | None = None,
    t_window: float | None = None,
    window: float = 0.0,
) -> tuple[GateLabel, GateLabel, float | None]:
    """(hysteresis label, binary label, margin). Without a pose the clip is gated F with no
    margin (the fail->F policy). With ``window`` > 0 (``ScoreConfig.tau_t_window``), a clip the
    first-last ``t_inf`` gates H whose largest gate-window statistic ``t_window`` exceeds
    ``window`` is in the gray zone instead, its margin ``window - t_window`` (negative)."""
    if not pose_present or t_inf is None:
        return "F", "F", None
    label = hysteresis_gate(t_inf, low, high)
    if label == "H" and window > 0 and t_window is not None and t_window > window:
        return "U", binary_gate(t_inf, tau_t), window - t_window
    return label, binary_gate(t_inf, tau_t), gate_margin(label, t_inf, low, high)


def window_t_inf(windows: Iterable[tuple[int, int, float | None, bool]], span: tuple[int, int]) -> float | None:
    """The largest gate statistic of the gate windows ``(start, end, t_inf, pose_present)`` that
    lie inside ``span`` (inclusive) other than the span itself; None when none has a pose. The
    background is judged on pairs a few frames apart: a camera that translates inside the clip
    and comes back near its start reads a small first-last ``t_inf`` while its windows do not."""
    values = [
        float(t)
        for start, end, t, present in windows
        if present and t is not None and span[0] <= start and end <= span[1] and (start, end) != tuple(span)
    ]
    return max(values) if values else None


# --- aggregation over gaps and scales ----------------------------------------------------------


@dataclass(frozen=True)
class FitRow:
    """One family's score on one (pair, scale): ``valid`` pairs carry IR and GE (px)."""

    gap: int
    scale: float
    valid: bool
    ir: float | None
    ge: float | None
    judgeable: bool = True
    """False for rows skipped by design (duplicate frame, hard cut): they do not count against
    the coverage rule."""


def _median(values: np.ndarray) -> float | None:
    return float(np.median(values)) if len(values) else None


def aggregate_gap_arrays(
    gap: np.ndarray,
    scale: np.ndarray,
    valid: np.ndarray,
    ir: np.ndarray,
    ge: np.ndarray,
    *,
    gaps: Sequence[int],
    scales: Sequence[float],
    aggregation: str,
    judgeable: np.ndarray | None = None,
    min_coverage: float = 0.0,
) -> tuple[tuple[GapSummary, ...], float | None, float | None]:
    """:func:`aggregate_gaps` on per-row arrays (float64 IR/GE, NaN where not valid; ``judgeable``
    False where a row was skipped by design, default all True)."""
    judgeable = np.ones(len(valid), dtype=bool) if judgeable is None else judgeable
    per_gap = []
    for g in gaps:
        mine = gap == g
        ok = mine & valid
        n_judgeable = int((mine & judgeable).sum())
        if aggregation == "median":
            ir_g, ge_g = _median(ir[ok]), _median(ge[ok])
        elif aggregation == "worst":
            cells = [ok & (scale == s) for s in scales]
            irs = [m for m in (_median(ir[c]) for c in cells) if m is not None]
            ges = [m for m in (_median(ge[c]) for c in cells) if m is not None]
            ir_g, ge_g = (min(irs) if irs else None), (max(ges) if ges else None)
        else:
            raise ValueError(f"aggregation must be 'median' or 'worst', got {aggregation!r}")
        judged = ir_g is not None and int(ok.sum()) >= min_coverage * n_judgeable
        per_gap.append(
            GapSummary(
                gap=g,
                ir=ir_g,
                ge=ge_g,
                valid_pairs=int(ok.sum()),
                total_pairs=int(mine.sum()),
                judgeable_pairs=n_judgeable,
                judged=judged,
            )
        )
    irs = [x.ir for x in per_gap if x.ir is not None and x.judged]
    ges = [x.ge for x in per_gap if x.ge is not None and x.judged]
    return tuple(per_gap), (min(irs) if irs else None), (max(ges) if ges else None)


def aggregate_gaps(
    rows: Sequence[FitRow],
    *,
    gaps: Sequence[int],
    scales: Sequence[float],
    aggregation: str,
    min_coverage: float = 0.0,
) -> tuple[tuple[GapSummary, ...], float | None, float | None]:
    """Per-gap summaries and the clip's headline IR and GE (see ``ScoreConfig.aggregation``).

    ``median`` (the paper): per gap, the median IR and GE over its valid (pair, scale) rows;
    ``worst``: per gap and scale the median over pairs, and the gap takes its lowest IR and
    highest GE. A gap is judged when its valid rows are at least ``min_coverage`` of its
    judgeable rows (the coverage rule, ``ScoreConfig.min_coverage``). The headline is the lowest
    judged per-gap IR and the highest judged per-gap GE; None when no gap is judged."""

    def column(name: str) -> np.ndarray:
        return np.array([np.nan if getattr(r, name) is None else getattr(r, name) for r in rows], dtype=np.float64)

    gap = np.array([r.gap for r in rows], dtype=np.int64)
    scale = np.array([r.scale for r in rows], dtype=np.float64)
    valid = np.array([r.valid for r in rows], dtype=bool)
    judgeable = np.array([r.judgeable for r in rows], dtype=bool)
    return aggregate_gap_arrays(
        gap,
        scale,
        valid,
        column("ir"),
        column("ge"),
        gaps=gaps,
        scales=scales,
        aggregation=aggregation,
        judgeable=judgeable,
        min_coverage=min_coverage,
    )


def summarize_family(family: str, scored: Sequence[PairFits], cfg: ScoreConfig) -> FamilySummary:
    """One family's clip summary from every scored (pair, scale): :func:`aggregate_gaps` over the
    fits, per-scale medians, and the count of each reason a pair could not be judged."""
    spec = family_spec(family)
    rows = []
    for r in scored:
        fit = None if r.skip else r.fit(family)
        rows.append(
            FitRow(r.gap, r.scale, False, None, None, judgeable=r.skip is None)
            if fit is None
            else FitRow(r.gap, r.scale, fit.valid, fit.ir, fit.ge)
        )
    per_gap, ir, ge = aggregate_gaps(
        rows, gaps=cfg.gaps, scales=cfg.scales, aggregation=cfg.aggregation, min_coverage=cfg.min_coverage
    )
    reasons: dict[str, int] = {}
    moved = []
    for r in scored:
        fit = r.fit(family)
        if fit is not None and fit.model is not None and len(r.x1):
            moved.append(fit.n_independent / len(r.x1))
        reason = r.skip or (fit.reason if fit is not None else None)
        if reason:
            reasons[reason] = reasons.get(reason, 0) + 1
    per_scale = []
    for s in cfg.scales:
        mine = [r for r in scored if r.scale == s and r.skip is None]
        valid = [f for f in (r.fit(family) for r in mine) if f is not None and f.valid]
        f_valid = [r.f for r in mine if r.f is not None and r.f.valid]
        per_scale.append(
            ScaleSummary(
                scale=s,
                ir=float(np.median([f.ir for f in valid])) if valid else None,
                ge=float(np.median([f.ge for f in valid])) if valid else None,
                valid_pairs=len(valid),
                tau_f_px=float(np.median([f.tau_px for f in f_valid])) if f_valid else None,
            )
        )
    return FamilySummary(
        family=spec.name,
        ir=ir,
        ge=ge,
        valid_pairs=sum(g.valid_pairs for g in per_gap),
        total_pairs=len(scored),
        per_gap=tuple(per_gap),
        per_scale=tuple(per_scale),
        invalid_reasons=dict(sorted(reasons.items())),
        independent_share=float(np.median(moved)) if moved else 0.0,
    )


# --- model choice and the report gate ----------------------------------------------------------


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
    tau_t_window: float = 0.0
    """Gate windows (``ScoreConfig.tau_t_window``; 0: off)."""
    untrusted_share: float = 0.0
    """A failing background with this share of matches moving on their own cannot be judged
    (``ScoreConfig.untrusted_share``; 0: off)."""

    NAMES = ("tau_h", "tau_f", "ir_gate", "ge_gate", "tau_t_low", "tau_t_high", "tau_t_window", "untrusted_share")

    @classmethod
    def of(cls, config: ScoreConfig) -> "Thresholds":
        """The thresholds a record was scored with."""
        return cls(**{name: float(getattr(config, name)) for name in cls.NAMES})

    def __post_init__(self) -> None:
        if self.tau_h <= 0 or self.tau_f <= 0:
            raise ValueError(f"tau_h and tau_f must be positive, got {self.tau_h} and {self.tau_f}")
        if not self.tau_t_low <= self.tau_t_high:
            raise ValueError(f"the gate's low threshold {self.tau_t_low} exceeds its high threshold {self.tau_t_high}")
        if self.tau_t_window < 0:
            raise ValueError(f"the gate window threshold must be >= 0 (0: off), got {self.tau_t_window}")
        if not 0.0 <= self.untrusted_share <= 1.0:
            raise ValueError(f"the untrusted share must be in [0, 1] (0: off), got {self.untrusted_share}")

    def tau(self, family: str) -> float:
        """The residual threshold of ``family``."""
        tau: float = getattr(self, family_spec(family).threshold)
        return tau

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
    return family_spec(label).name


def report_verdict(ir: float | None, ge: float | None, ir_gate: float, ge_gate: float) -> bool | None:
    """The report gate: consistent when ``ir >= ir_gate`` and ``ge <= ge_gate``; None when the
    background could not be judged (no valid pair)."""
    if ir is None or ge is None:
        return None
    return bool(ir >= ir_gate and ge <= ge_gate)


@dataclass(frozen=True)
class ClipVerdict:
    """A clip's gate and background verdict under some :class:`Thresholds`: the hysteresis
    ``label`` and ``margin`` (None without a pose), the family used and its IR/GE, both families'
    values, the report gate verdict and its :func:`report_margin`, and the binary gate's label."""

    label: GateLabel
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
    binary_label: GateLabel = "F"
    untrusted: bool = False
    """The chosen family failed the report gate on a background whose matches moved on their own
    at ``Thresholds.untrusted_share`` or more: not judged (``consistent`` None)."""


class FamilyScores(Protocol):
    """A family's clip IR and GE (None when it could not be judged) and the share of its matches
    that moved on their own: a :class:`~geocon_core.record.FamilySummary`, a re-gated family, or
    :class:`Scores`."""

    @property
    def ir(self) -> float | None: ...

    @property
    def ge(self) -> float | None: ...

    @property
    def independent_share(self) -> float: ...


class Scores(NamedTuple):
    """A family's clip IR and GE as plain values (see :class:`FamilyScores`)."""

    ir: float | None
    ge: float | None
    independent_share: float = 0.0


def family_verdict(
    h: FamilyScores,
    f: FamilyScores,
    *,
    t_inf: float | None,
    pose_present: bool,
    thresholds: Thresholds,
    tau_t: float | None = None,
    t_window: float | None = None,
) -> ClipVerdict:
    """The verdict from a clip's gate statistic (and its largest gate window, ``t_window``) and
    both families' scores ``h`` and ``f``: the gate (:func:`gate_decision`; ``tau_t`` is the binary
    gate's threshold, default the config's), the model (:func:`choose_model`) and the report gate
    on that model's IR and GE."""
    label, binary, margin = gate_decision(
        t_inf,
        pose_present=pose_present,
        tau_t=tau_t,
        low=thresholds.tau_t_low,
        high=thresholds.tau_t_high,
        t_window=t_window,
        window=thresholds.tau_t_window,
    )
    model = choose_model(label, pose_present and t_inf is not None, h.ir, f.ir)
    chosen = h if model == "H" else f
    ir, ge = chosen.ir, chosen.ge
    consistent = report_verdict(ir, ge, thresholds.ir_gate, thresholds.ge_gate)
    untrusted = (
        consistent is False
        and thresholds.untrusted_share > 0
        and chosen.independent_share >= thresholds.untrusted_share
    )
    return ClipVerdict(
        label=label,
        model=model,
        margin=margin,
        ir=ir,
        ge=ge,
        consistent=None if untrusted else consistent,
        report_margin=None if untrusted else report_margin(ir, ge, thresholds.ir_gate, thresholds.ge_gate),
        untrusted=untrusted,
        ir_h=h.ir,
        ge_h=h.ge,
        ir_f=f.ir,
        ge_f=f.ge,
        binary_label=binary,
    )


def clip_verdict(
    *,
    t_inf: float | None,
    pose_present: bool,
    ir_h: float | None,
    ge_h: float | None,
    ir_f: float | None,
    ge_f: float | None,
    thresholds: Thresholds,
    tau_t: float | None = None,
    t_window: float | None = None,
) -> ClipVerdict:
    """:func:`family_verdict` from both families' IR and GE given as values."""
    h, f = Scores(ir_h, ge_h), Scores(ir_f, ge_f)
    return family_verdict(
        h, f, t_inf=t_inf, pose_present=pose_present, thresholds=thresholds, tau_t=tau_t, t_window=t_window
    )


# --- clips with cuts: each shot judged on its own -------------------------------------------------


def gate_shot(shots: Sequence[tuple[int, int]]) -> int:
    """The shot whose gate is the clip's: the first with at least two frames (a cut is no camera
    motion, so the gate must see the parallax of a shot, never across a cut); 0 when none has."""
    return next((i for i, (start, end) in enumerate(shots) if end > start), 0)


def deciding_shot(verdicts: Sequence[ClipVerdict]) -> int:
    """The shot that decides a clip with cuts: of the shots that fail the report gate, the one
    with the least headroom; else, of the judged shots, the one with the least headroom (the clip
    is consistent when every judged shot is); else the first shot (nothing could be judged)."""
    judged = [(v.report_margin if v.report_margin is not None else 0.0, i) for i, v in enumerate(verdicts)]
    failing = [m for m in judged if verdicts[m[1]].consistent is False]
    passing = [m for m in judged if verdicts[m[1]].consistent is True]
    if failing:
        return min(failing)[1]
    if passing:
        return min(passing)[1]
    return 0


def combine_shots(verdicts: Sequence[ClipVerdict], gate: int) -> ClipVerdict:
    """A clip's verdict from its shots' verdicts (:func:`deciding_shot` gives the background:
    family, IR, GE and report gate) with the gate label and margin of shot ``gate``
    (:func:`gate_shot`). A cut is never a geometry failure: no pair across it is scored."""
    d, g = verdicts[deciding_shot(verdicts)], verdicts[gate]
    return replace(d, label=g.label, margin=g.margin, binary_label=g.binary_label)


# --- clips worth an audit ----------------------------------------------------------------------

FLAG_REASONS = ("model", "fails", "not_judged", "no_pose", "gate_mismatch")
"""Reason codes of :func:`flag_reasons`, in the order they are reported."""


def flag_reasons(
    *,
    consistent: bool | None,
    pose_present: bool,
    gate_model: str | None,
    expected_model: str | None,
    finding: str | None = None,
) -> tuple[str, ...]:
    """Why a clip deserves an audit (codes of :data:`FLAG_REASONS`, empty when it does not): the
    clip model calls it inconsistent (``model``; ``finding`` is the model's verdict where it decides
    the clip, :meth:`~geocon_core.record.ClipRecord.model_verdict`, and then stands in for the report
    gate), it fails the report gate (``fails``) or cannot be judged (``not_judged``: no valid pair,
    or the clip failed to score), it has no first-last pose (``no_pose``), or, with a pose, its gate
    chose another model than the expected one of its category (``gate_mismatch``; a clip without a
    known category has no expected model)."""
    why = []
    if finding is not None:
        if finding != "consistent":
            why.append("model" if finding == "inconsistent" else "not_judged")
    elif consistent is not True:
        why.append("fails" if consistent is False else "not_judged")
    if not pose_present:
        why.append("no_pose")
    elif expected_model is not None and gate_model != expected_model:
        why.append("gate_mismatch")
    return tuple(why)


def is_flagged(
    *,
    consistent: bool | None,
    pose_present: bool,
    gate_model: str | None,
    expected_model: str | None,
    finding: str | None = None,
) -> bool:
    """A clip worth auditing (see :func:`flag_reasons`): not consistent, or no pose, or a gate that
    disagrees with the expected model of the clip's category. The one definition used by
    ``geocon bench`` (which clips get a recording), the triage list's flagged filter, the report's
    flagged section and the audit app."""
    return bool(
        flag_reasons(
            consistent=consistent,
            pose_present=pose_present,
            gate_model=gate_model,
            expected_model=expected_model,
            finding=finding,
        )
    )
