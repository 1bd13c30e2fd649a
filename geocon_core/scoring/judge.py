"""The clip's background verdict, decided once from the stages' finished results, before the
record is assembled (:mod:`.assemble`): both families over the pair fits and the gate
(:func:`judge_background`; each shot on its own when the clip has cuts), then the multi-view
check, whose drifting layer fails a background that its pair fits pass (:func:`judge_drift`).
The rules themselves live in :mod:`.verdict`."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Sequence

from ..config import ScoreConfig
from ..geometry import FAMILIES, PairFits
from ..pose import PoseEstimate
from ..reconstruction import MultiViewResult
from ..record import BackgroundSummary, FamilySummary, ShotRecord
from .verdict import (
    ClipVerdict,
    Thresholds,
    combine_shots,
    deciding_shot,
    family_verdict,
    gate_shot,
    summarize_family,
    window_t_inf,
)

__all__ = ["BackgroundJudgement", "INVALID_TEXT", "coverage_note", "judge_background", "judge_drift"]


@dataclass(frozen=True)
class BackgroundJudgement:
    """The background's verdict over the pair fits: ``verdict`` (the gate and the report rule,
    what the gate record shows), ``families`` (both families' summaries of the span that decides),
    ``background`` (the record's summary, with the multi-view check's drift once
    :func:`judge_drift` has read it), ``shots`` (each shot's record, with cuts), ``pose`` (the
    first-last pose of the span that decides: the clip's, or its deciding shot's) and
    ``gate_pose`` (the one the gate shows: the clip's, or its gate shot's)."""

    verdict: ClipVerdict
    families: dict[str, FamilySummary]
    background: BackgroundSummary
    shots: tuple[ShotRecord, ...]
    pose: PoseEstimate
    gate_pose: PoseEstimate

    def spans(self, num_frames: int) -> list[tuple[int, int, str]]:
        """(start, end, model) of each span the multi-view check reconstructs: every shot under
        its own model, or the whole clip under the background's."""
        return [(s.start, s.end, s.model) for s in self.shots] or [(0, num_frames - 1, self.background.model)]


INVALID_TEXT = {
    "independent_motion": "more than half of the background matches move on their own (movers the masks did not "
    "cover whole, or a dynamic background)",
    "too_few_inliers": "too few matches fit the background model",
    "too_few_matches": "too few matches (little texture, a fast camera or a dynamic background)",
    "model_failed": "no background model could be fitted",
}
"""Why pairs could not be judged, in words, by reason code (the codes of ``invalid_reasons``)."""


def coverage_note(summary: FamilySummary, min_coverage: float) -> str | None:
    """Why a family's background cannot be judged, or which gaps the coverage rule left out of
    its headline (None when every gap was judged); the commonest reason a pair was invalid is
    named in words."""
    reasons = {k: v for k, v in summary.invalid_reasons.items() if k in INVALID_TEXT}
    why = f"; most invalid pairs: {INVALID_TEXT[max(reasons, key=lambda k: reasons[k])]}" if reasons else ""
    if summary.valid_pairs == 0:
        return f"no valid pair: the background could not be judged{why}"
    out = [g for g in summary.per_gap if not g.judged and g.judgeable_pairs]  # a gap longer than the clip: no pair
    if not out:
        return None
    parts = ", ".join(f"gap {g.gap}: {g.valid_pairs} of {g.judgeable_pairs}" for g in out)
    head = "the background could not be judged" if summary.ir is None else "left out of the headline"
    return f"too few valid pair-scales ({parts}; the coverage rule needs {min_coverage:.0%}{why}): {head}"


def _background(
    cfg: ScoreConfig, v: ClipVerdict, fam: dict[str, FamilySummary], pose: PoseEstimate, t_window: float | None = None
) -> BackgroundSummary:
    if fam[v.model].ir is None:
        note = coverage_note(fam[v.model], cfg.min_coverage) or "the background could not be judged"
    elif v.untrusted:
        note = (
            f"the background could not be judged: {fam[v.model].independent_share:.0%} of its matches (median over "
            f"the pairs) move on their own (movers the masks did not cover whole), and the {v.model} fit failed "
            f"(IR {v.ir:.3f}, GE {v.ge:.2f} px) where they leak; a failure there says nothing about the scene"
        )
    elif not pose.pose_present:
        note = f"no pose ({pose.reason}): gated F by the fail->F policy"
    elif v.label == "U":
        why = (
            f" (t_inf {pose.t_inf:.4f}, but a gate window reads {t_window:.4f} > {cfg.tau_t_window:g})"
            if pose.t_inf is not None and pose.t_inf <= cfg.tau_t_low and t_window is not None
            else ""
        )
        irs = ", ".join(f"IR {k} " + ("-" if fam[k].ir is None else f"{fam[k].ir:.3f}") for k in ("H", "F"))
        note = f"gray zone{why}: both families fitted, kept {v.model} ({irs})"
    else:
        note = f"t_inf {pose.t_inf:.4f} -> {v.label}" + (f" ({pose.note})" if pose.note else "")
    chosen = fam[v.model]
    other = next(f for name, f in fam.items() if name != v.model)
    return BackgroundSummary(
        model=v.model,
        ir=chosen.ir,
        ge=chosen.ge,
        valid_pairs=chosen.valid_pairs,
        total_pairs=chosen.total_pairs,
        consistent=v.consistent,
        tau_f_px=fam["F"].per_scale[list(cfg.scales).index(max(cfg.scales))].tau_f_px,
        chosen=chosen,
        other=other,
        choice_note=note,
    )


def _judge_span(
    cfg: ScoreConfig,
    thresholds: Thresholds,
    scored: list[PairFits],
    pose: PoseEstimate,
    timeline_poses: Sequence[tuple[tuple[int, int], PoseEstimate]],
    span: tuple[int, int],
) -> tuple[dict[str, FamilySummary], ClipVerdict, float | None]:
    """Both families over ``scored`` (the pairs of frames ``span``) and their verdict under the
    gate of ``pose`` and of the gate windows inside ``span``; the largest window too."""
    fam = {name: summarize_family(name, scored, cfg) for name in FAMILIES}
    rows = [(s, e, est.t_inf, est.pose_present) for (s, e), est in timeline_poses]
    t_window = window_t_inf(rows, span)
    verdict = family_verdict(
        fam["H"],
        fam["F"],
        t_inf=pose.t_inf,
        pose_present=pose.pose_present,
        thresholds=thresholds,
        tau_t=cfg.tau_t,
        t_window=t_window,
    )
    return fam, verdict, t_window


def _judge_shots(
    cfg: ScoreConfig,
    thresholds: Thresholds,
    shot_poses: Sequence[tuple[tuple[int, int], PoseEstimate]],
    scored: list[PairFits],
    timeline_poses: Sequence[tuple[tuple[int, int], PoseEstimate]] = (),
) -> tuple[ClipVerdict, dict[str, FamilySummary], PoseEstimate, tuple[ShotRecord, ...]]:
    """Each shot judged on its own pairs with its own gate (and the gate windows inside it); the
    combined verdict, the families and pose of the shot that decides, and the shots' records."""
    verdicts, families, records = [], [], []
    for (start, end), est in shot_poses:
        mine = [r for r in scored if start <= r.t0 and r.t1 <= end]
        fam, v, t_window = _judge_span(cfg, thresholds, mine, est, timeline_poses, (start, end))
        note = (
            "a single frame: nothing to judge" if end == start else _background(cfg, v, fam, est, t_window).choice_note
        )
        verdicts.append(v)
        families.append(fam)
        records.append(
            ShotRecord(
                start=start,
                end=end,
                label=v.label if est.pose_present else None,
                t_inf=est.t_inf,
                pose_present=est.pose_present,
                pose_method=est.method if est.pose_present else None,
                model=v.model,
                ir=v.ir,
                ge=v.ge,
                consistent=v.consistent,
                note=note,
            )
        )
    gate = gate_shot([w for w, _ in shot_poses])
    decides = deciding_shot(verdicts)
    return combine_shots(verdicts, gate), families[decides], shot_poses[decides][1], tuple(records)


def _shots_note(shots: tuple[ShotRecord, ...], verdict: ClipVerdict) -> str:
    """The background's note for a clip with cuts: which shot decided, and how each one fared."""
    judged = [s for s in shots if s.consistent is not None]
    if not judged:
        return f"none of the {len(shots)} shots could be judged (cuts split the clip)"
    decides = next(s for s in shots if s.consistent == verdict.consistent and s.ir == verdict.ir and s.ge == verdict.ge)
    state = {True: "consistent", False: "inconsistent"}[bool(verdict.consistent)]
    return (
        f"{len(shots)} shots judged on their own ({len(judged)} judged); shot {decides.start}-{decides.end} "
        f"decides: {state} ({decides.note})"
    )


def judge_background(
    cfg: ScoreConfig,
    num_frames: int,
    pose: PoseEstimate,
    timeline_poses: Sequence[tuple[tuple[int, int], PoseEstimate]],
    scored: list[PairFits],
    shot_poses: Sequence[tuple[tuple[int, int], PoseEstimate]] = (),
) -> BackgroundJudgement:
    """Both families over ``scored`` (sorted by gap, frame, scale) and their verdict under the gate
    of ``pose`` and of the gate windows (``timeline_poses``). A clip with hard cuts gives
    ``shot_poses``, the pose of each shot's first and last frame: each shot is then judged on its
    own (its gate, its pairs), the clip's gate is that of its first shot of two frames or more and
    its background that of the shot that decides
    (:func:`~geocon_core.scoring.verdict.combine_shots`)."""
    thresholds = Thresholds.of(cfg)
    if len(shot_poses) > 1:
        verdict, fam, pose, shots = _judge_shots(cfg, thresholds, shot_poses, scored, timeline_poses)
        background = replace(_background(cfg, verdict, fam, pose), choice_note=_shots_note(shots, verdict))
        gate_pose = shot_poses[gate_shot([w for w, _ in shot_poses])][1]
        return BackgroundJudgement(verdict, fam, background, shots, pose, gate_pose)
    fam, verdict, t_window = _judge_span(cfg, thresholds, scored, pose, timeline_poses, (0, num_frames - 1))
    return BackgroundJudgement(verdict, fam, _background(cfg, verdict, fam, pose, t_window), (), pose, pose)


def judge_drift(judgement: BackgroundJudgement, result: MultiViewResult | None) -> BackgroundJudgement:
    """The judgement once the multi-view check has read the clip: a drifting layer fails a
    background that its pair fits do not already fail, and the background's note says so."""
    bg = judgement.background
    if result is None or not result.flagged or bg.consistent is False:
        return judgement
    note = f"{bg.choice_note}; the multi-view check: {result.layers[0].describe()}".lstrip("; ")
    return replace(judgement, background=replace(bg, consistent=False, choice_note=note))
