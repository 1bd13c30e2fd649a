"""From the stages' results to a :class:`~geocon_core.record.ClipRecord`: the background
(both families, the verdict, the gate and its timeline), the pairs with their per-match arrays,
then the objects, the masked share and the category."""

from __future__ import annotations

import platform
from dataclasses import fields, replace
from pathlib import Path
from typing import Any, Sequence

import cv2
import numpy as np

from .._version import __version__
from ..config import ScoreConfig, config_hash
from ..geometry import FAMILIES, ModelFit, PairFits
from ..masks import MaskSource
from ..media import ClipInfo
from ..pose import PoseEstimate
from ..record import (
    BackgroundSummary,
    CellArrays,
    ClipRecord,
    FamilySummary,
    FitSummary,
    GateRecord,
    GateWindow,
    MatchArrays,
    ObjectEntry,
    PairRecord,
    ShotRecord,
)
from .category import categorize_record
from .rigidity import MASK_JUMP, ObjectPairScore, object_summaries
from .verdict import (
    ClipVerdict,
    Thresholds,
    combine_shots,
    deciding_shot,
    family_verdict,
    gate_decision,
    gate_shot,
    summarize_family,
    window_t_inf,
)

__all__ = ["software_versions", "fit_summary", "assemble_record", "add_objects", "object_entries"]


def software_versions() -> dict[str, str]:
    """The versions of GeoCon, Python and the libraries that change scores, as a record carries them."""
    versions = {
        "geocon": __version__,
        "python": platform.python_version(),
        "numpy": np.__version__,
        "opencv": cv2.__version__,
    }
    return versions


def fit_summary(fit: ModelFit) -> FitSummary:
    """The record's summary of ``fit``: its fields of the same name, the model as nested lists."""
    model = None if fit.model is None else [[float(v) for v in row] for row in fit.model]
    return FitSummary(**{f.name: getattr(fit, f.name) for f in fields(FitSummary) if f.name != "model"}, model=model)


def _gate_record(
    cfg: ScoreConfig, v: ClipVerdict, backend: str, pose: PoseEstimate, windows, timeline_poses, n: int
) -> GateRecord:
    def label(est: PoseEstimate) -> str | None:
        if not est.pose_present:
            return None
        return gate_decision(est.t_inf, pose_present=True, tau_t=cfg.tau_t, low=cfg.tau_t_low, high=cfg.tau_t_high)[0]

    timeline = [
        GateWindow(start=s, end=e, t_inf=est.t_inf, label=label(est), pose_present=est.pose_present)
        for (s, e), est in timeline_poses
    ]
    if (0, n - 1) in windows:
        timeline.append(GateWindow(0, n - 1, pose.t_inf, v.label if pose.pose_present else None, pose.pose_present))
    return GateRecord(
        label=v.label,
        binary_label=v.binary_label,
        model=v.model,
        t_inf=pose.t_inf,
        pose_present=pose.pose_present,
        margin=v.margin,
        backend=backend,
        thresholds={"tau_t": cfg.tau_t, "low": cfg.tau_t_low, "high": cfg.tau_t_high},
        pose=pose,
        timeline=tuple(timeline),
    )


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


def _pair_record(i: int, r: PairFits) -> tuple[PairRecord, dict[str, np.ndarray]]:
    """A scored pair's record entry and its per-match arrays (zeros where a family has no fit)."""
    m = len(r.x1)
    arrays = {"x1": r.x1, "x2": r.x2}
    for name, spec in FAMILIES.items():
        fit = r.fit(name)
        arrays[spec.inliers] = np.zeros(m, bool) if fit is None else fit.inliers
        arrays[spec.residual_px] = np.zeros(m, np.float32) if fit is None else fit.residuals_px
        arrays[spec.residual] = np.zeros(m, np.float32) if fit is None else fit.residuals  # H: the same column
        ind = None if fit is None else fit.independent
        arrays[spec.independent] = np.zeros(m, bool) if ind is None else ind
    h, f = r.fit("H"), r.fit("F")
    pair = PairRecord(
        index=i,
        t0=r.t0,
        t1=r.t1,
        gap=r.gap,
        scale=r.scale,
        n_matches=m,
        skip=r.skip,
        h=None if h is None else fit_summary(h),
        f=None if f is None else fit_summary(f),
        n_gross=r.n_gross,
    )
    return pair, arrays


def assemble_record(
    clip: str,
    info: ClipInfo,
    cfg: ScoreConfig,
    K: np.ndarray,
    backend: str,
    pose: PoseEstimate,
    timeline_poses: list[tuple[tuple[int, int], PoseEstimate]],
    windows: list[tuple[int, int]],
    scored: list[PairFits],
    shot_poses: Sequence[tuple[tuple[int, int], PoseEstimate]] = (),
) -> ClipRecord:
    """The record of a clip's background: both families summarised over ``scored`` (sorted by
    gap, frame, scale), the verdict (:func:`~geocon_core.scoring.verdict.family_verdict`), the gate with
    its timeline (``timeline_poses`` of the ``windows``; the whole-clip window uses ``pose``), the
    pairs and their per-match arrays, and the warnings; no objects or category yet.

    A clip with hard cuts gives ``shot_poses``, the pose of each shot's first and last frame: each
    shot is then judged on its own (its gate, its pairs), the clip's gate is that of its first
    shot of two frames or more and its background that of the shot that decides
    (:func:`~geocon_core.scoring.verdict.combine_shots`); the shots are in :attr:`ClipRecord.shots`."""
    thresholds = Thresholds.of(cfg)
    shots: tuple[ShotRecord, ...] = ()
    if len(shot_poses) > 1:
        verdict, fam, pose, shots = _judge_shots(cfg, thresholds, shot_poses, scored, timeline_poses)
        background = replace(_background(cfg, verdict, fam, pose), choice_note=_shots_note(shots, verdict))
    else:
        fam, verdict, t_window = _judge_span(cfg, thresholds, scored, pose, timeline_poses, (0, info.num_frames - 1))
        background = _background(cfg, verdict, fam, pose, t_window)
    warnings: list[str] = list(info.warnings)  # frames lost to a damaged file, from the reader
    if not pose.pose_present:
        warnings.append(f"the first-last pose could not be recovered ({pose.reason}); the clip is gated F")
    elif pose.method == "chain":
        warnings.append(f"the gate's pose is a chain of short hops: {pose.note}")
    coverage = coverage_note(fam[verdict.model], cfg.min_coverage)
    if coverage:
        warnings.append(coverage)
    moving = fam[verdict.model].independent_share
    if moving >= 0.01:
        warnings.append(
            f"independent motion: {moving:.0%} of the background matches (median over the scored pairs) move on their "
            "own, away from the background around them (movers the masks did not cover whole), and are left out of IR"
        )
    if info.duplicates:
        warnings.append(f"{len(info.duplicates)} duplicated frame(s): pairs across them are not scored")
    if info.fades:
        warnings.append(
            f"{len(info.fades)} cross-fade(s) over frames {', '.join(f'{s}-{e}' for s, e in info.fades)}: the frames "
            "between each fade's ends blend two shots, and no pair among them is scored"
        )
    if info.cuts:
        warnings.append(
            f"{len(info.cuts)} hard cut(s) at frame(s) {list(info.cuts)}: pairs across them are not scored, and "
            f"each of the {len(info.shots)} shots is judged on its own"
        )
    pairs, arrays = zip(*(_pair_record(i, r) for i, r in enumerate(scored)), strict=True) if scored else ((), ())
    gate_pose = shot_poses[gate_shot([w for w, _ in shot_poses])][1] if shots else pose
    return ClipRecord(
        clip=clip,
        video=info,
        config=cfg,
        config_hash=config_hash(cfg),
        versions=software_versions(),
        gate=_gate_record(cfg, verdict, backend, gate_pose, windows, timeline_poses, info.num_frames),
        background=background,
        shots=shots,
        pairs=tuple(pairs),
        matches=MatchArrays.concatenate(list(arrays)),
        intrinsics=[[float(v) for v in row] for row in K],
        category=None,
        warnings=tuple(warnings),
    )


def object_entries(scores: Sequence[ObjectPairScore]) -> tuple[list[ObjectEntry], list[dict[str, Any] | None]]:
    """The record's object entries (indexed in order) and each entry's cell arrays (None when the
    pair has none)."""
    entries: list[ObjectEntry] = []
    cells: list[dict[str, Any] | None] = []
    for sc in scores:
        i, res = len(entries), sc.result
        if res is None:
            entries.append(ObjectEntry(i, sc.object_id, sc.t0, sc.t1, sc.scale, False, sc.skip, None, None, 0, None))
            cells.append(None)
            continue
        affine = None if res.affine is None else [[float(v) for v in row] for row in res.affine]
        entries.append(
            ObjectEntry(
                i, sc.object_id, sc.t0, sc.t1, sc.scale, res.valid, res.reason, res.d_t, res.w2, res.n_pixels, affine
            )
        )
        c = res.cells
        cells.append(
            None
            if c is None
            else {
                "cells": c.cells,
                "positions": c.positions,
                "observed": c.observed,
                "predicted": c.predicted,
                "weights": c.weights,
            }
        )
    return entries, cells


DYNAMIC_NOTE_SHARE = 0.05
"""A dynamic background covering at least this median share of the frame is named in the warnings."""


def _dynamic_share(mask_source: MaskSource | None, n: int) -> tuple[float, ...]:
    """Per frame, the share of the frame the motion segmentation found moving incoherently
    outside the objects (``MotionSegmenter.dynamic``); empty for a source that does not measure it."""
    dynamic = getattr(mask_source, "dynamic", None)
    if not dynamic:
        return ()
    return tuple(float(dynamic.get(t, 0.0)) for t in range(n))


def add_objects(
    record: ClipRecord,
    scores: list[ObjectPairScore],
    *,
    scales: Sequence[float],
    masked_share: np.ndarray,
    object_share: dict[int, dict[int, float]],
    mask_source: MaskSource | None,
    masks_path: str | Path | None,
) -> ClipRecord:
    """Add object entries (``scores`` sorted by object, frame, scale), per-object summaries
    (:func:`~geocon_core.scoring.rigidity.object_summaries`), the masked share per frame, the mask
    source's warnings and the category (:func:`~geocon_core.scoring.category.categorize_record`)."""
    entries, cells = object_entries(scores)
    cfg = record.config
    min_pairs = cfg.min_object_pairs
    summaries = object_summaries(
        entries, scales, object_share, min_pairs=min_pairs, jump_window=cfg.mask_jump_window, max_jump=cfg.max_mask_jump
    )
    warnings = list(record.warnings) + (list(mask_source.warnings) if mask_source is not None else [])
    s_max = max(scales)
    jumped = {
        o.object_id: p.skipped[MASK_JUMP]
        for o in summaries
        for p in o.per_scale
        if p.scale == s_max and MASK_JUMP in p.skipped
    }
    if jumped:
        listed = ", ".join(f"{oid} ({n})" for oid, n in list(jumped.items())[:12])
        warnings.append(
            f"{sum(jumped.values())} object pair(s) left out of AdaDFRC because the mask's area jumped by more than "
            f"{cfg.max_mask_jump:.0%} against its neighbouring frames (a segmentation glitch): object (pairs) {listed}"
        )
    dynamic = _dynamic_share(mask_source, len(masked_share))
    if dynamic and float(np.median(dynamic)) >= DYNAMIC_NOTE_SHARE:
        warnings.append(
            f"a dynamic background (water, fire, smoke, foliage in wind) moves on its own in about "
            f"{float(np.median(dynamic)):.0%} of the frame (median over frames): its texture re-forms from frame to "
            "frame and obeys no camera"
        )
    thin = [o.object_id for o in summaries if o.adadfrc is None]
    if thin:
        ids = ", ".join(map(str, thin[:12])) + (" ..." if len(thin) > 12 else "")
        warnings.append(f"{len(thin)} object(s) with fewer than {min_pairs} valid pairs are listed, not scored: {ids}")
    source = (
        "none" if mask_source is None else (f"external:{masks_path}" if masks_path is not None else mask_source.name)
    )
    return replace(
        record,
        masks_source=source,
        masked_share=tuple(float(v) for v in masked_share),
        dynamic_share=dynamic,
        objects=tuple(summaries),
        object_entries=tuple(entries),
        cells=CellArrays.concatenate(cells),
        warnings=tuple(warnings),
        category=categorize_record(record, [o.frames for o in summaries]),
    )
