"""The validation table: one row per measure, computed from :class:`~.results.CaseResult` rows.

======================  =================================================================
row                     what it counts
======================  =================================================================
gate accuracy           gate label == expected label, over cases whose expected label is
                        H or F (synthetic: the clip's truth; real: the annotation; the gray
                        zone is left out)
false flags             share not called consistent: clean synthetic clips, and real-camera
                        clips (annotated ``source = real``)
detection               per failure and severity: background inconsistent, or (elastic)
                        the highest object AdaDFRC >= :data:`OBJECT_RATIO` x that of the clean
                        clip of the same scene, height and codec
clean IR 256 vs 1080    per scene family: the largest |IR(256) - IR(1080)| over codecs
object count            tracks <= 1.5 x movers + 1 (synthetic: truth objects; real: annotated
                        movers); the detail gives the mean |tracks - movers|
object identity         synthetic clips with movers: one track covers >= 80% of the visible
                        frames of every true mover (checked against the true masks)
no phantom objects      still scenes seen by a moving camera (synthetic C3/C5, annotated real
                        walk-throughs) get no object
category C4             a still camera with movers is categorised C4
category accuracy       record category == expected family (synthetic clean; real where
                        annotated)
pose coverage           share of clips whose gate had a pose (generated clips annotated as a
                        stable scene; clean synthetic clips)
======================  =================================================================

Where a target is met at every height matters (detection, false flags), the detail column
breaks the row down by height.

Every share carries its 95% Wilson interval and every AUC a 95% interval from a seeded,
stratified bootstrap over clips (:mod:`geocon_core.intervals`); a comparison with the peer is
paired: the difference on the same clips, with the interval of the difference over the same
resamples, and the detail says whether that interval includes 0.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Callable, Iterable
from dataclasses import dataclass, replace

import numpy as np

from ..intervals import (
    Interval,
    bootstrap_aucs,
    mann_whitney_auc,
    paired_rate_difference,
    percentile_interval,
    wilson_interval,
)
from .cases import FAILURE_FAMILY, LEVELS, SEVERITIES
from .results import CaseResult

__all__ = [
    "auc",
    "AUC_SETS",
    "MetricRow",
    "OBJECT_RATIO",
    "IR_TOLERANCE",
    "TRACK_COVERAGE",
    "MIN_COMPARE",
    "compute_metrics",
    "detected",
    "share_text",
    "auc_text",
    "difference_text",
]

OBJECT_RATIO = 5.0
"""An injected object failure is detected when the object's AdaDFRC is at least this many times
the clean clip's (the issue's criterion)."""
IR_TOLERANCE = 0.02
"""Clean IR at 256 px must lie within this of the IR at 1080 px (share, 0..1)."""


@dataclass(frozen=True)
class MetricRow:
    """One row of the table: ``value`` is a share (0..1) or, for the IR rows, an IR difference;
    ``hits`` of ``n`` cases; ``target`` in words; ``ok`` whether it is met (None: no target or
    no case); ``detail`` a breakdown."""

    metric: str
    subset: str
    value: float | None
    hits: int
    n: int
    target: str
    ok: bool | None
    detail: str = ""
    interval: Interval | None = None
    """The 95% interval of ``value``: Wilson for a share, the bootstrap over clips for an AUC;
    None for an IR difference or a median share, and without a value."""
    peer: Interval | None = None
    """The peer's value on the same clips, with its interval (AUC and matched flag-rate rows)."""
    difference: Interval | None = None
    """GeoCon's value minus the peer's on the same clips, with its paired bootstrap interval."""
    second_peer: Interval | None = None
    """The second peer's (Epipolar-DPO's) AUC on the same clips, with its interval (AUC rows)."""
    second_difference: Interval | None = None
    """GeoCon's AUC minus the second peer's, paired as :attr:`difference` is."""


def share_text(hits: int, n: int) -> str:
    """A share as the report prints it: ``86% [72%, 94%] (24/28)``, with its Wilson interval."""
    if not n:
        return "-"
    w = wilson_interval(hits, n)
    return f"{100 * w.estimate:.0f}% [{100 * w.low:.0f}%, {100 * w.high:.0f}%] ({hits}/{n})"


def auc_text(iv: Interval) -> str:
    """An AUC with its interval: ``0.53 [0.35, 0.71]``."""
    return f"{iv.estimate:.2f} [{iv.low:.2f}, {iv.high:.2f}]"


def _signed(v: float, points: bool) -> str:
    """``v`` with its sign (percentage points when ``points``); a value that rounds to zero but is
    not zero gets one more digit, so the bound of an interval that excludes 0 never reads 0."""
    scaled, digits = (100 * v, 0) if points else (v, 2)
    while scaled != 0.0 and round(scaled, digits) == 0.0 and digits < 6:
        digits += 1
    return f"{round(scaled, digits) + 0.0:+.{digits}f}"


MIN_COMPARE = 5
"""A difference with the peer is judged only with at least this many clips on each side (the
positives and the negatives of an AUC; the clips of a rate): resamples of fewer clips vary too
little for their interval to be trusted."""


def difference_text(diff: Interval, *, points: bool, more: str, few: str | None = None, peer: str = "peer") -> str:
    """GeoCon minus the peer in words: ``GeoCon - peer +0.04 [-0.12, +0.19]: the interval
    includes 0, so the two cannot be told apart on these clips``; ``points`` prints a difference
    of shares in percentage points; ``more`` says what a positive difference means ("separates
    these clips better", "flags more of these clips"); ``few`` (the clips, in words) when there are
    fewer than :data:`MIN_COMPARE` on a side, and then no side is called better; ``peer`` names
    the peer."""
    unit = " points" if points else ""
    head = (
        f"GeoCon - {peer} {_signed(diff.estimate, points)}{unit} "
        f"[{_signed(diff.low, points)}, {_signed(diff.high, points)}]"
    )
    if few is not None:
        return f"{head}: too few clips ({few}) to tell the two apart"
    if diff.low <= 0.0 <= diff.high:
        return f"{head}: the interval includes 0, so the two cannot be told apart on these clips"
    who = "GeoCon" if diff.low > 0.0 else f"the {peer}" if peer == "peer" else peer
    return f"{head}: the interval excludes 0, {who} {more}"


def _share(
    metric: str,
    subset: str,
    rows: list[CaseResult],
    hit: Callable[[CaseResult], bool],
    target: str,
    ok: Callable[[float], bool] | None,
    by_height: bool = False,
) -> MetricRow:
    hits = sum(1 for r in rows if hit(r))
    value = hits / len(rows) if rows else None
    detail = _by_height(rows, hit) if by_height else ""
    ok_ = None if value is None or ok is None else ok(value)
    return MetricRow(metric, subset, value, hits, len(rows), target, ok_, detail, _wilson(hits, len(rows)))


def _wilson(hits: int, n: int) -> Interval | None:
    return wilson_interval(hits, n) if n else None


def _by_height(rows: list[CaseResult], hit: Callable[[CaseResult], bool]) -> str:
    groups: dict[int, list[CaseResult]] = defaultdict(list)
    for r in rows:
        if r.height is not None:
            groups[r.height].append(r)
    return "  ".join(f"{h}: {sum(1 for r in g if hit(r))}/{len(g)}" for h, g in sorted(groups.items()))


def detected(row: CaseResult, clean: CaseResult | None) -> bool:
    """A planted failure is detected: the background is inconsistent, or for an object failure the
    highest object AdaDFRC is at least :data:`OBJECT_RATIO` times the clean twin's."""
    if row.verdict == "inconsistent":
        return True
    if row.failure != "elastic" or row.max_adadfrc is None or clean is None or clean.verdict == "failed":
        return False
    if clean.max_adadfrc is None:
        return False
    return row.max_adadfrc >= OBJECT_RATIO * clean.max_adadfrc


def _twins(rows: Iterable[CaseResult]) -> dict[tuple, CaseResult]:
    return {(r.family, r.height, r.codec): r for r in rows if r.clean}


def _gate_rows(rows: list[CaseResult]) -> list[MetricRow]:
    out = []
    for subset, pick in (
        ("synthetic", lambda r: r.kind == "synthetic"),
        ("real clips, annotated", lambda r: r.kind == "real"),
    ):
        judged = [r for r in rows if pick(r) and r.truth_gate is not None and r.verdict != "failed"]
        out.append(
            _share("gate accuracy", subset, judged, lambda r: r.gate == r.truth_gate, ">= 90%", lambda v: v >= 0.9)
        )
    posed = [r for r in rows if r.kind == "real" and r.posed and r.truth_gate is not None and r.verdict != "failed"]
    row = _share(
        "gate accuracy", "posed walk-throughs", posed, lambda r: r.gate == r.truth_gate, "all", lambda v: v == 1.0
    )
    wrong = [
        f"{r.case_id.split('__', 1)[-1]} ({r.gate}, t_inf {'-' if r.t_inf is None else f'{r.t_inf:.3f}'})"
        for r in posed
        if r.gate != r.truth_gate
    ]
    out.append(replace(row, detail=", ".join(wrong)))
    return out


REAL_GROUPS: tuple[tuple[str, str], ...] = (
    ("data", "../shared/data (rules chosen on it earlier)"),
    ("tune", "tune half"),
    ("check", "check half"),
)
"""The sets annotated clips are reported in, with their names in the table."""


def _false_flag_rows(rows: list[CaseResult]) -> list[MetricRow]:
    clean = [r for r in rows if r.clean]
    out = [_share("false flags", "clean synthetic", clean, lambda r: r.flagged, "0", lambda v: v == 0.0, True)]
    codecs: dict[str, list[CaseResult]] = defaultdict(list)
    for r in clean:
        codecs[str(r.codec)].append(r)
    if len(codecs) > 1:
        by_codec = "  ".join(f"{c}: {sum(r.flagged for r in g)}/{len(g)}" for c, g in codecs.items())
        out[0] = replace(out[0], detail=f"{out[0].detail};  {by_codec}")
    for group, name in REAL_GROUPS:
        real = [r for r in rows if r.kind == "real" and r.source == "real" and r.group == group]
        out.append(
            _share(
                "false flags", f"real-camera clips, {name}", real, lambda r: r.false_flag, "<= 5%", lambda v: v <= 0.05
            )
        )
        if real:
            named = [r.case_id.split("__", 1)[-1] for r in real if r.false_flag]
            out[-1] = replace(out[-1], detail=", ".join(named))
        out.append(
            _share(
                "cannot judge",
                f"real-camera clips, {name}",
                real,
                lambda r: r.verdict == "not judged",
                "<= 15%",
                lambda v: v <= 0.15,
            )
        )
    return out


def _generated_rows(rows: list[CaseResult]) -> list[MetricRow]:
    """Flag rates of generated clips with a visible artifact against clean-looking ones, per set:
    how well the verdict follows what people see."""
    out = []
    for group, name in REAL_GROUPS:
        gen = [r for r in rows if r.kind == "real" and r.source == "generated" and r.group == group]
        for subset, pick in (
            ("visible artifact", lambda r: r.artifact),
            ("geometric artifact", lambda r: r.geometric_artifact),
            ("clean-looking", lambda r: not r.artifact),
        ):
            group_rows = [r for r in gen if pick(r)]
            row = _share(
                "flagged inconsistent",
                f"generated, {subset}, {name}",
                group_rows,
                lambda r: r.verdict == "inconsistent",
                "reported",
                None,
            )
            judged = sum(r.verdict == "not judged" for r in group_rows)
            out.append(replace(row, detail=f"{judged} not judged" if group_rows else ""))
    return out


def _scores(values: Iterable[float | None]) -> np.ndarray:
    """Scores for an AUC: a missing score (a clip that cannot be judged) counts as 0.5, no
    evidence either way."""
    return np.array([0.5 if v is None else v for v in values], float)


def _field_scores(pos: list[CaseResult], neg: list[CaseResult], name: str) -> tuple[np.ndarray, np.ndarray]:
    """The scores of field ``name`` for an AUC: a missing one counts as 0.5 (:func:`_scores`), or,
    for the second peer, whose distances have no fixed range, as the median of the others."""
    if name != "epipolar_score":
        return _scores(getattr(r, name) for r in pos), _scores(getattr(r, name) for r in neg)
    present = [r.epipolar_score for r in pos + neg if r.epipolar_score is not None]
    fill = float(np.median(present)) if present else 0.0
    return tuple(  # type: ignore[return-value]
        np.array([fill if r.epipolar_score is None else r.epipolar_score for r in side], float) for side in (pos, neg)
    )


def auc(pos: Iterable[float | None], neg: Iterable[float | None]) -> float | None:
    """Area under the ROC curve of a score (higher = more broken) separating ``pos`` from ``neg``:
    the chance that a random positive scores above a random negative, ties counting half
    (:func:`~geocon_core.intervals.mann_whitney_auc`). A missing score counts as 0.5. None when
    either side is empty."""
    p, n = _scores(pos), _scores(neg)
    if not len(p) or not len(n):
        return None
    return mann_whitney_auc(p, n)


AUC_SETS: tuple[tuple[str, Callable[[CaseResult], bool], Callable[[CaseResult], bool]], ...] = (
    ("visible artifact vs clean-looking generated", lambda r: r.artifact, lambda r: r.generated and not r.artifact),
    (
        "geometric artifact vs clean-looking generated",
        lambda r: r.geometric_artifact,
        lambda r: r.generated and not r.artifact,
    ),
    ("visible artifact vs real cameras", lambda r: r.artifact, lambda r: r.source == "real"),
    ("generated vs real cameras", lambda r: r.generated, lambda r: r.source == "real"),
)
"""The separations the AUC rows report: (name, positives, negatives), over annotated clips."""

AUC_MARGIN = 0.10
"""On the check half, the clip score must beat the peer's AUC (visible artifact vs clean) by this."""
AUC_GEOMETRIC = 0.80
"""On the check half, the clip score's AUC for geometric artifacts against clean-looking clips."""


def _auc_row(label: str, group: str, name: str, pos: list[CaseResult], neg: list[CaseResult]) -> MetricRow:
    """One AUC row: the clip score's AUC with its bootstrap interval, the peer's on the same
    clips and the paired difference, all from the same resamples of the clips."""
    n = len(pos) + len(neg)
    metric = f"AUC, clip score ({label})"
    if not pos or not neg:
        return MetricRow(metric, name, None, len(pos), n, "reported", None)
    with_peer = any(r.peer_score is not None for r in pos + neg)
    with_second = any(r.epipolar_score is not None for r in pos + neg)
    fields = ("clip_score", *(("peer_score",) if with_peer else ()), *(("epipolar_score",) if with_second else ()))
    sample, boot = bootstrap_aucs(
        np.column_stack([_field_scores(pos, neg, f)[0] for f in fields]),
        np.column_stack([_field_scores(pos, neg, f)[1] for f in fields]),
    )
    ours = percentile_interval(sample[0], boot[:, 0], n)
    peer = percentile_interval(sample[1], boot[:, 1], n) if with_peer else None
    diff = percentile_interval(sample[0] - sample[1], boot[:, 0] - boot[:, 1], n) if with_peer else None
    second = second_diff = None
    if with_second:
        k = fields.index("epipolar_score")
        second = percentile_interval(sample[k], boot[:, k], n)
        second_diff = percentile_interval(sample[0] - sample[k], boot[:, 0] - boot[:, k], n)
    target, ok = "reported", None
    if group == "check" and peer is not None and label.startswith("visible artifact vs c"):
        target, ok = f">= peer + {AUC_MARGIN:.2f}", ours.estimate >= peer.estimate + AUC_MARGIN
    elif group == "check" and label.startswith("geometric"):
        target, ok = f">= {AUC_GEOMETRIC:.2f}", ours.estimate >= AUC_GEOMETRIC
    notes = []
    if peer is not None and diff is not None:
        notes.append(f"peer {auc_text(peer)}")
        few = f"{len(pos)} vs {len(neg)}" if min(len(pos), len(neg)) < MIN_COMPARE else None
        notes.append(difference_text(diff, points=False, more="separates these clips better", few=few))
        missing = sum(r.peer_score is None for r in pos + neg)
        notes += [f"{missing} clips without a peer score counted at 0.5"] if missing else []
    else:
        notes.append("no peer score")
    if second is not None and second_diff is not None:
        notes.append(f"Epipolar-DPO {auc_text(second)}")
        notes.append(
            difference_text(second_diff, points=False, more="separates these clips better", peer="Epipolar-DPO")
        )
    judged = sum(r.clip_score is None for r in pos + neg)
    notes += [f"{judged} not judged counted at 0.5"] if judged else []
    return MetricRow(
        metric, name, ours.estimate, len(pos), n, target, ok, "; ".join(notes), ours, peer, diff, second, second_diff
    )


def _auc_rows(rows: list[CaseResult]) -> list[MetricRow]:
    """GeoCon's clip score against the peer (1 - GVGC keep rate) on the same annotated clips, per
    set: AUC of each separation in :data:`AUC_SETS`, and the flag rates when the peer's threshold
    flags as many clean-looking generated clips as GeoCon's verdict does."""
    out = []
    for group, name in REAL_GROUPS:
        annotated = [r for r in rows if r.kind == "real" and r.group == group and r.verdict != "failed"]
        if not any(r.generated for r in annotated):
            continue
        for label, is_pos, is_neg in AUC_SETS:
            pos = [r for r in annotated if r.generated and is_pos(r)]
            neg = [r for r in annotated if is_neg(r)]
            out.append(_auc_row(label, group, name, pos, neg))
        out += _matched_flag_rows(annotated, name)
    return out + _f_test_rows(rows)


def _f_test_rows(rows: list[CaseResult]) -> list[MetricRow]:
    """How loose the F test is: per set, the median over clips of the share of background matches
    within each :data:`~.results.F_PX_STEPS` source px of their pair's F, beside the source-pixel
    equivalent of tau_F. Value: the share at 1 px."""
    from .results import F_PX_STEPS

    out = []
    one = F_PX_STEPS.index(1.0)
    for group, name in REAL_GROUPS:
        annotated = [r for r in rows if r.kind == "real" and r.group == group and r.f_within is not None]
        for subset, pick in (
            ("real cameras", lambda r: r.source == "real"),
            ("clean-looking generated", lambda r: r.generated and not r.artifact),
            ("geometric artifact", lambda r: r.geometric_artifact),
        ):
            chosen = [r for r in annotated if pick(r)]
            if not chosen:
                continue
            shares = np.median(np.array([r.f_within for r in chosen]), axis=0)
            taus = [r.tau_f_px for r in chosen if r.tau_f_px is not None]
            detail = " · ".join(f"{t:g} px {v:.2f}" for t, v in zip(F_PX_STEPS, shares, strict=True))
            detail += f"; tau_F ~ {np.median(taus):.1f} px (median)" if taus else ""
            out.append(
                MetricRow("F keeps within 1 px (median share)", f"{subset}, {name}", float(shares[one]), len(chosen),
                          len(chosen), "reported", None, detail)
            )  # fmt: skip
    return out


def _matched_flag_rows(annotated: list[CaseResult], name: str) -> list[MetricRow]:
    """Flag rates of GeoCon's verdict and of the peer at the threshold that flags the same share of
    clean-looking generated clips (the peer's own threshold is not published)."""
    clean = [r for r in annotated if r.generated and not r.artifact]
    scored = sorted((r.peer_score for r in clean if r.peer_score is not None), reverse=True)
    if not clean or not scored:
        return []
    flagged = sum(r.verdict == "inconsistent" for r in clean)
    k = round(flagged / len(clean) * len(scored))
    cut = scored[k - 1] if k > 0 else float("inf")
    out = []
    for subset, pick in (
        ("clean-looking generated", lambda r: r.generated and not r.artifact),
        ("visible artifact", lambda r: r.artifact),
        ("real cameras", lambda r: r.source == "real"),
    ):
        group_rows = [r for r in annotated if pick(r)]
        if not group_rows:
            continue
        ours = [r.verdict == "inconsistent" for r in group_rows]
        theirs = [r.peer_score is not None and r.peer_score >= cut for r in group_rows]
        flags = "flagged inconsistent, GeoCon"
        row = _share(flags, f"{subset}, {name}", group_rows, lambda r: r.verdict == "inconsistent", "reported", None)
        diff = paired_rate_difference(ours, theirs)
        few = str(len(ours)) if len(ours) < MIN_COMPARE else None
        detail = f"peer at the same clean-looking rate: {share_text(sum(theirs), len(theirs))}; " + difference_text(
            diff, points=True, more="flags more of these clips", few=few
        )
        out.append(replace(row, detail=detail, peer=wilson_interval(sum(theirs), len(theirs)), difference=diff))
    return out


def _cut_rows(rows: list[CaseResult]) -> list[MetricRow]:
    """Annotated cuts within the scored frames that the reader found (a cut is judged per shot,
    never as a geometry failure), and clips with a cut that were flagged inconsistent."""
    annotated = [r for r in rows if r.kind == "real" and r.truth_cuts is not None and r.cuts is not None]
    with_cut = [r for r in annotated if r.truth_cuts]
    found = sum(len(set(r.truth_cuts or ()) & set(r.cuts or ())) for r in with_cut)
    total = sum(len(r.truth_cuts or ()) for r in with_cut)
    spurious = sum(len(set(r.cuts or ()) - set(r.truth_cuts or ())) for r in annotated)
    out = []
    if total:
        out.append(
            MetricRow(
                "cuts found",
                "annotated clips",
                found / total,
                found,
                total,
                "all",
                found == total,
                f"{spurious} cuts found where none is annotated (over {len(annotated)} clips)",
                _wilson(found, total),
            )
        )
    real_cut = [r for r in with_cut if r.source == "real"]
    out.append(
        _share(
            "flagged for a cut",
            "real-camera clips with a cut",
            real_cut,
            lambda r: r.false_flag,
            "0",
            lambda v: v == 0.0,
        )
    )
    return out


def _detection_rows(rows: list[CaseResult]) -> list[MetricRow]:
    twins = _twins(rows)
    out = []
    for failure in SEVERITIES:
        families = FAILURE_FAMILY.get(failure, ())
        for family in families:
            for level in LEVELS:
                group = [
                    r
                    for r in rows
                    if r.kind == "synthetic"
                    and r.failure == failure
                    and r.level == level
                    and (len(families) == 1 or r.family == family)
                ]
                if not group:
                    continue
                sev = SEVERITIES[failure][LEVELS.index(level)]
                target, ok = ("reported", None) if level == "low" else (">= 90% at every height", None)
                where = f" on {family}" if len(families) > 1 else ""
                row = _share(
                    "detection",
                    f"{failure} {level} ({sev:g} px){where}",
                    group,
                    lambda r: detected(r, twins.get((r.family, r.height, r.codec))),
                    target,
                    ok,
                    True,
                )
                if level != "low":
                    per_height = defaultdict(list)
                    for r in group:
                        per_height[r.height].append(detected(r, twins.get((r.family, r.height, r.codec))))
                    row = replace(row, ok=all(sum(v) / len(v) >= 0.9 for v in per_height.values()))
                out.append(row)
    return out


def _ir_rows(rows: list[CaseResult]) -> list[MetricRow]:
    twins = _twins(rows)
    out = []
    for family in sorted({r.family for r in rows if r.clean and r.family}):
        diffs = []
        for codec in sorted({str(r.codec) for r in rows if r.clean}):
            lo, hi = twins.get((family, 256, codec)), twins.get((family, 1080, codec))
            if lo is not None and hi is not None and lo.ir is not None and hi.ir is not None:
                diffs.append((codec, abs(lo.ir - hi.ir)))
        if not diffs:
            continue
        worst = max(d for _, d in diffs)
        out.append(
            MetricRow(
                "clean IR 256 vs 1080",
                family,
                worst,
                sum(d <= IR_TOLERANCE for _, d in diffs),
                len(diffs),
                f"<= {IR_TOLERANCE:g}",
                worst <= IR_TOLERANCE,
                "  ".join(f"{c}: {d:.3f}" for c, d in diffs),
            )
        )
    return out


def _count_ok(r: CaseResult) -> bool:
    assert r.objects is not None and r.truth_movers is not None
    return r.objects <= 1.5 * r.truth_movers + 1


def _object_rows(rows: list[CaseResult]) -> list[MetricRow]:
    out = []
    for subset, pick in (("clean synthetic", lambda r: r.clean), ("real clips, annotated", lambda r: r.kind == "real")):
        group = [r for r in rows if pick(r) and r.truth_movers is not None and r.objects is not None]
        row = _share("object count", subset, group, _count_ok, "tracks <= 1.5 x movers + 1", lambda v: v == 1.0)
        if group:
            mean_err = sum(abs(int(r.objects or 0) - int(r.truth_movers or 0)) for r in group) / len(group)
            row = replace(row, detail=f"mean abs(tracks - movers) {mean_err:.1f}")
        out.append(row)
    return out


TRACK_COVERAGE = 0.8
"""A mover is followed when one track covers at least this share of its visible frames."""


def _identity_rows(rows: list[CaseResult]) -> list[MetricRow]:
    """One id per mover (synthetic truth masks), no objects on still scenes seen by a moving
    camera, and C4 for a still camera with movers."""
    out = []
    followed = [r for r in rows if r.clean and r.track_coverage is not None]
    row = _share(
        "object identity",
        "clean synthetic with movers",
        followed,
        lambda r: (r.track_coverage or 0.0) >= TRACK_COVERAGE,
        f"one track >= {TRACK_COVERAGE:.0%} of each mover's frames",
        lambda v: v == 1.0,
    )
    if followed:
        fams: dict[str, list[CaseResult]] = defaultdict(list)
        for r in followed:
            fams[r.family or "?"].append(r)
        per = "  ".join(
            f"{f}: {sum((r.track_coverage or 0.0) >= TRACK_COVERAGE for r in g)}/{len(g)}"
            for f, g in sorted(fams.items())
        )
        row = replace(row, detail=f"{per};  least coverage {min(r.track_coverage or 0.0 for r in followed):.2f}")
    out.append(row)
    for subset, pick in (
        ("clean synthetic, moving camera", lambda r: r.clean and r.static_camera is False),
        ("real camera, annotated", lambda r: r.kind == "real" and r.source == "real" and r.static_camera is False),
    ):
        group = [r for r in rows if pick(r) and r.truth_movers == 0 and r.objects is not None]
        out.append(_share("no phantom objects", subset, group, lambda r: r.objects == 0, "all", lambda v: v == 1.0))
    for subset, pick in (("clean synthetic", lambda r: r.clean), ("real clips, annotated", lambda r: r.kind == "real")):
        group = [r for r in rows if pick(r) and r.static_camera and (r.truth_movers or 0) > 0 and r.verdict != "failed"]
        subset = f"still camera with movers, {subset}"
        out.append(_share("category C4", subset, group, lambda r: r.category == "C4", "all", lambda v: v == 1.0))
    return out


def _category_rows(rows: list[CaseResult]) -> list[MetricRow]:
    out = []
    for subset, pick in (("clean synthetic", lambda r: r.clean), ("real clips, annotated", lambda r: r.kind == "real")):
        group = [r for r in rows if pick(r) and r.truth_category is not None and r.verdict != "failed"]
        out.append(
            _share("category accuracy", subset, group, lambda r: r.category == r.truth_category, "reported", None)
        )
    return out


def _pose_rows(rows: list[CaseResult]) -> list[MetricRow]:
    generated = [r for r in rows if r.source == "generated" and r.stable_scene and r.verdict != "failed"]
    clean = [r for r in rows if r.clean and r.verdict != "failed"]
    return [
        _share(
            "pose coverage",
            "generated, stable scene",
            generated,
            lambda r: bool(r.pose_present),
            ">= 80%",
            lambda v: v >= 0.8,
        ),
        _share("pose coverage", "clean synthetic", clean, lambda r: bool(r.pose_present), "reported", None),
    ]


def compute_metrics(rows: list[CaseResult]) -> list[MetricRow]:
    """Every row of the validation table, in the order it is printed; rows whose cases were not
    run are left out, except the scoring-failure row which is always first."""
    failed = [r for r in rows if r.verdict == "failed"]
    table = [
        MetricRow(
            "cases scored",
            "all",
            (len(rows) - len(failed)) / len(rows) if rows else None,
            len(rows) - len(failed),
            len(rows),
            "all",
            not failed if rows else None,  # no case scored: nothing met
            ", ".join(r.case_id for r in failed[:5]) + (" ..." if len(failed) > 5 else ""),
            _wilson(len(rows) - len(failed), len(rows)),
        )
    ]
    for part in (
        _gate_rows,
        _false_flag_rows,
        _detection_rows,
        _ir_rows,
        _object_rows,
        _identity_rows,
        _category_rows,
        _pose_rows,
        _generated_rows,
        _auc_rows,
        _cut_rows,
    ):
        table += [row for row in part(rows) if row.n > 0]
    return table
