"""The record, assembled last from finished parts: the pairs with their per-match arrays
(:func:`pair_tables`), the objects (:func:`object_parts`), then :func:`assemble_record`, which
puts them beside the background's judgement (:mod:`.judge`), the gate and its timeline, the
multi-view check, the readings and the clouds, and reads the category off the finished record."""

from __future__ import annotations

import platform
from dataclasses import dataclass, fields, replace
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
from ..reconstruction import MultiViewResult, WindowCloud
from ..record import (
    CellArrays,
    ClipRecord,
    FitSummary,
    GateRecord,
    GateWindow,
    MatchArrays,
    ObjectEntry,
    ObjectSummary,
    PairRecord,
    PointCloud,
    PointMaps,
)
from ..regions import RegionsPart
from ..signals import ClipReadings
from .category import categorize_record
from .judge import BackgroundJudgement, coverage_note
from .rigidity import MASK_JUMP, ObjectPairScore, object_summaries
from .verdict import ClipVerdict, gate_decision

__all__ = [
    "ObjectParts",
    "assemble_record",
    "fit_summary",
    "object_entries",
    "object_parts",
    "pair_tables",
    "software_versions",
]


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


def pair_tables(scored: Sequence[PairFits]) -> tuple[tuple[PairRecord, ...], MatchArrays]:
    """The record's pairs (``scored`` sorted by gap, frame, scale, indexed in that order) and their
    per-match arrays, concatenated."""
    pairs, arrays = zip(*(_pair_record(i, r) for i, r in enumerate(scored)), strict=True) if scored else ((), ())
    return tuple(pairs), MatchArrays.concatenate(list(arrays))


def _background_warnings(info: ClipInfo, cfg: ScoreConfig, judgement: BackgroundJudgement) -> list[str]:
    """What the record warns of about its background: frames lost to a damaged file (from the
    reader), a missing or chained pose, the coverage rule, independent motion, duplicated frames,
    fades and cuts."""
    pose, fam, verdict = judgement.pose, judgement.families, judgement.verdict
    warnings: list[str] = list(info.warnings)
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
    return warnings


@dataclass(frozen=True)
class ObjectParts:
    """What a record keeps of the moving objects: ``entries`` (AdaDFRC per object, frame pair and
    scale) with their ``cells``, the per-object ``summaries``, the mask source's name
    (``masks_source``), the masked and dynamic shares per frame and the ``warnings`` they raise."""

    entries: tuple[ObjectEntry, ...] = ()
    cells: CellArrays | None = None
    summaries: tuple[ObjectSummary, ...] = ()
    masks_source: str = "none"
    masked_share: tuple[float, ...] = ()
    dynamic_share: tuple[float, ...] = ()
    warnings: tuple[str, ...] = ()


def assemble_record(
    clip: str,
    info: ClipInfo,
    cfg: ScoreConfig,
    K: np.ndarray,
    backend: str,
    judgement: BackgroundJudgement,
    timeline_poses: list[tuple[tuple[int, int], PoseEstimate]],
    windows: list[tuple[int, int]],
    tables: tuple[tuple[PairRecord, ...], MatchArrays],
    objects: ObjectParts,
    *,
    notes: Sequence[str] = (),
    multiview: MultiViewResult | None = None,
    readings: ClipReadings | None = None,
    regions: RegionsPart | None = None,
    dense: tuple[WindowCloud, ...] = (),
    cloud: PointCloud | None = None,
    pointmaps: PointMaps | None = None,
) -> ClipRecord:
    """The record of a clip, made once from finished parts: the background's ``judgement``
    (:mod:`.judge`, the multi-view check's drift included), the gate with its timeline
    (``timeline_poses`` of the ``windows``; the whole-clip window uses the judgement's gate pose),
    the pairs and their per-match arrays (``tables``, :func:`pair_tables`), the ``objects``
    (:func:`object_parts`), the multi-view check's ``multiview``, the ``readings`` and the clouds;
    its warnings are the background's, then ``notes`` (the scorer's), then the objects'. The
    category (:func:`~geocon_core.scoring.category.categorize_record`) is read off the finished
    record last."""
    pairs, matches = tables
    record = ClipRecord(
        clip=clip,
        video=info,
        config=cfg,
        config_hash=config_hash(cfg),
        versions=software_versions(),
        gate=_gate_record(
            cfg, judgement.verdict, backend, judgement.gate_pose, windows, timeline_poses, info.num_frames
        ),
        background=judgement.background,
        shots=judgement.shots,
        pairs=pairs,
        matches=matches,
        intrinsics=[[float(v) for v in row] for row in K],
        category=None,
        warnings=(*_background_warnings(info, cfg, judgement), *notes, *objects.warnings),
        masks_source=objects.masks_source,
        masked_share=objects.masked_share,
        dynamic_share=objects.dynamic_share,
        objects=objects.summaries,
        object_entries=objects.entries,
        cells=objects.cells,
        cloud=cloud,
        pointmaps=pointmaps,
        dense=dense,
        multiview=multiview,
        readings=readings,
        regions=regions,
    )
    return replace(record, category=categorize_record(record, [o.frames for o in objects.summaries]))


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


def object_parts(
    cfg: ScoreConfig,
    scores: list[ObjectPairScore],
    *,
    scales: Sequence[float],
    masked_share: np.ndarray,
    object_share: dict[int, dict[int, float]],
    mask_source: MaskSource | None,
    masks_path: str | Path | None,
) -> ObjectParts:
    """The objects' part of a record: entries (``scores`` sorted by object, frame, scale), per-object
    summaries (:func:`~geocon_core.scoring.rigidity.object_summaries`), the masked share per frame,
    the dynamic share, and the warnings of the mask source and of the objects."""
    entries, cells = object_entries(scores)
    min_pairs = cfg.min_object_pairs
    summaries = object_summaries(
        entries, scales, object_share, min_pairs=min_pairs, jump_window=cfg.mask_jump_window, max_jump=cfg.max_mask_jump
    )
    warnings = list(mask_source.warnings) if mask_source is not None else []
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
    return ObjectParts(
        entries=tuple(entries),
        cells=CellArrays.concatenate(cells),
        summaries=tuple(summaries),
        masks_source=source,
        masked_share=tuple(float(v) for v in masked_share),
        dynamic_share=dynamic,
        warnings=tuple(warnings),
    )
