"""Scoring one clip: composes reading, matching, model fitting and gating into a record.

The scorer streams frames: features of a frame are extracted once per scale and kept only
while a pair, the first-last pose or a gate window still needs them, so memory does not grow
with clip length beyond the per-match arrays of the record itself. Work runs on a small thread
pool (OpenCV releases the GIL); every random choice is seeded from the config seed and the
pair's identity, so results do not depend on scheduling.
"""

from __future__ import annotations

import os
import platform
import threading
import time
from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable

import cv2
import numpy as np

from ._version import __version__
from .category import categorize
from .config import ScoreConfig, config_hash
from .diagnostics import FrameDiagnostics, ObjectFlow
from .features import FeatureSet, Matcher, make_matcher, scaled_inputs
from .flow import FlowBackend, make_flow_backend
from .gate import gate_decision
from .geometry import scale_intrinsics, triangulate_two_view
from .masks import make_mask_source
from .models import ModelFit, fit_fundamental, fit_homography
from .pose import PoseBackend, PoseEstimate, default_intrinsics, load_pose_log, make_pose_backend
from .reader import ClipInfo, Frame, iter_frames, probe_clip
from .record import (
    BackgroundSummary,
    CellArrays,
    ClipRecord,
    FamilySummary,
    FitSummary,
    GateRecord,
    GateWindow,
    MatchArrays,
    ObjectEntry,
    ObjectScaleSummary,
    ObjectSummary,
    PairRecord,
    PointCloud,
    ScaleSummary,
)
from .regate import FitRow, aggregate_gaps, choose_model, report_verdict
from .rigidity import adadfrc_pair, object_scores

__all__ = ["score_clip", "software_versions"]


def software_versions() -> dict[str, str]:
    versions = {
        "geocon": __version__,
        "python": platform.python_version(),
        "numpy": np.__version__,
        "opencv": cv2.__version__,
    }
    return versions


def _pair_seed(seed: int, t0: int, t1: int, scale_index: int) -> int:
    return int(np.random.SeedSequence([seed, t0, t1, scale_index]).generate_state(1)[0])


@dataclass
class _Scored:
    t0: int
    t1: int
    gap: int
    scale: float
    skip: str | None
    x1: np.ndarray
    x2: np.ndarray
    h: ModelFit | None
    f: ModelFit | None


def _fit_summary(fit: ModelFit) -> FitSummary:
    model = None if fit.model is None else [[float(v) for v in row] for row in fit.model]
    return FitSummary(
        valid=fit.valid,
        reason=fit.reason,
        ir=fit.ir,
        ge=fit.ge,
        n_inliers=fit.n_inliers,
        tau=fit.tau,
        tau_px=fit.tau_px,
        model=model,
    )


class _Timer:
    """Thread-safe sums of seconds spent per stage (reported by benchmarks, never recorded)."""

    def __init__(self, sink: dict[str, float] | None) -> None:
        self.sink = sink
        self.lock = threading.Lock()

    def add(self, stage: str, start: float) -> float:
        now = time.perf_counter()
        if self.sink is not None:
            with self.lock:
                self.sink[stage] = self.sink.get(stage, 0.0) + now - start
        return now


class _Pipeline:
    def __init__(
        self, info: ClipInfo, config: ScoreConfig, matcher: Matcher, flow: FlowBackend | None, timer: _Timer
    ) -> None:
        self.info, self.config, self.matcher, self.flow, self.timer = info, config, matcher, flow, timer
        self.s_max = max(config.scales)
        self.keep_flows = False

    def extract(self, frame: Frame, background: np.ndarray | None) -> dict[float, FeatureSet]:
        """Features of frame t inside ``B_t`` = content minus object masks, at every scale."""
        start = time.perf_counter()
        mask = frame.content if background is None else frame.content & background
        out = {}
        for s in self.config.scales:
            g, m = scaled_inputs(frame.gray, mask, s)
            out[s] = self.matcher.extract(g, m, frame.index, s)
        self.timer.add("features", start)
        return out

    def score_pair(self, fa: Future, fb: Future, t0: int, t1: int, gap: int) -> list[_Scored]:
        a, b = fa.result(), fb.result()
        cfg = self.config
        results = []
        for si, s in enumerate(cfg.scales):
            start = time.perf_counter()
            x1, x2 = self.matcher.match(a[s], b[s])
            start = self.timer.add("matching", start)
            seed = _pair_seed(cfg.seed, t0, t1, si)
            kw = dict(min_inliers=cfg.min_inliers, iters=cfg.ransac_iters, confidence=cfg.ransac_confidence)
            h = fit_homography(x1, x2, tau=cfg.tau_h, seed=seed, **kw)
            f = fit_fundamental(x1, x2, tau=cfg.tau_f, **kw)
            self.timer.add("model_fitting", start)
            # kept as the record stores them (float32), so memory per match stays small
            results.append(_Scored(t0, t1, gap, s, None, x1.astype(np.float32), x2.astype(np.float32), h, f))
        return results

    def score_objects(
        self, f0: Frame, f1: Frame, labels0: np.ndarray, skip: str | None
    ) -> tuple[list[tuple], list[ObjectFlow]]:
        """AdaDFRC of every object of frame t0 on the pair (t0, t1), at every scale:
        (object_id, t0, t1, scale, RigidityResult | reason), and the flow slices at scale 1
        (kept only when diagnostics are streamed)."""
        start = time.perf_counter()
        out: list[tuple] = []
        flows: list[ObjectFlow] = []
        ids = [int(i) for i in np.unique(labels0) if i]
        for s in self.config.scales:
            if s == 1.0:
                g0, g1, lab = f0.gray, f1.gray, labels0
            else:
                h, w = f0.gray.shape
                size = (max(1, round(w * s)), max(1, round(h * s)))
                g0 = cv2.resize(f0.gray, size, interpolation=cv2.INTER_AREA)
                g1 = cv2.resize(f1.gray, size, interpolation=cv2.INTER_AREA)
                lab = cv2.resize(labels0, size, interpolation=cv2.INTER_NEAREST)
            for oid in ids:
                if skip is not None:
                    out.append((oid, f0.index, f1.index, s, skip))
                    continue
                mask = lab == oid
                ys, xs = np.nonzero(mask)
                if len(xs) == 0:
                    out.append((oid, f0.index, f1.index, s, "empty_mask"))
                    continue
                box = (int(xs.min()), int(ys.min()), int(xs.max()) + 1, int(ys.max()) + 1)
                field = self.flow.compute(g0, g1, box)
                x0, y0, x1, y1 = field.box
                res = adadfrc_pair(
                    field.flow,
                    mask[y0:y1, x0:x1],
                    field.reliable,
                    grid=self.config.grid,
                    min_cells=self.config.min_cells,
                    origin=(float(x0), float(y0)),
                )
                out.append((oid, f0.index, f1.index, s, res))
                if self.keep_flows and s == 1.0:
                    flows.append(
                        ObjectFlow(oid, f0.index, f1.index, field.box, field.flow, field.reliable, mask[y0:y1, x0:x1])
                    )
        self.timer.add("objects", start)
        return out, flows

    def pose(
        self,
        fa: Future,
        fb: Future,
        backend: PoseBackend,
        K: np.ndarray,
        t0: int,
        t1: int,
        rgb0: np.ndarray | None = None,
    ):
        """The relative pose (t0 -> t1); with ``rgb0`` (frame t0), also the two-view point cloud."""
        a, b = fa.result()[self.s_max], fb.result()[self.s_max]
        start = time.perf_counter()
        x0, x1 = self.matcher.match(a, b)
        est = backend.estimate(x0, x1, K, seed=_pair_seed(self.config.seed, t0, t1, 99))
        self.timer.add("pose", start)
        if rgb0 is None:
            return est
        return est, _two_view_cloud(est, K, x0, x1, rgb0, self.s_max)


def _two_view_cloud(
    est: PoseEstimate, K: np.ndarray, x0: np.ndarray, x1: np.ndarray, rgb0: np.ndarray, scale: float
) -> PointCloud:
    empty = PointCloud(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.uint8), "")
    if not est.pose_present:
        return replace(empty, note=f"no point cloud: no first-last pose ({est.reason})")
    T = np.asarray(est.T_cam0_camT, dtype=float)
    if not np.linalg.norm(T[:3, 3]) > 0:
        return replace(
            empty, note=f"no point cloud: {est.method} pose without translation (no parallax to triangulate)"
        )
    Ks = K.copy()
    Ks[0, 0] *= est.focal_scale
    Ks[1, 1] *= est.focal_scale
    X, ok = triangulate_two_view(Ks, T, x0, x1)
    X, px = X[ok], x0[ok]
    # colours from the first frame (pixels of the pose scale -> working pixels)
    h, w = rgb0.shape[:2]
    u = np.clip(np.round((px[:, 0] + 0.5) / scale - 0.5).astype(int), 0, w - 1)
    v = np.clip(np.round((px[:, 1] + 0.5) / scale - 0.5).astype(int), 0, h - 1)
    note = f"{len(X)} of {len(x0)} first-last matches triangulated with the {est.method} pose (front of both cameras, reprojection <= 2 px)"
    return PointCloud(X.astype(np.float32), rgb0[v, u].astype(np.uint8), note)


def _windows(n: int, window: int, stride: int) -> list[tuple[int, int]]:
    if n - 1 <= window:
        return [(0, n - 1)]
    return [(s, s + window) for s in range(0, n - 1 - window + 1, stride)]


def score_clip(
    path: str | Path,
    config: ScoreConfig | None = None,
    *,
    pose_log: str | Path | None = None,
    masks: str | Path | None = None,
    workers: int | None = None,
    progress: Callable[[int, int], None] | None = None,
    timings: dict[str, float] | None = None,
    on_frame: Callable[[FrameDiagnostics], None] | None = None,
) -> ClipRecord:
    """Score one clip. ``pose_log`` replaces the pose backend by an external pose (JSON, see
    :mod:`geocon_core.pose`); ``masks`` is a path to external object masks (see
    :mod:`geocon_core.masks`), otherwise ``config.masks`` chooses the built-in segmentation or
    none; ``progress(done, total)`` is called as frames are processed; ``timings``, if given,
    receives seconds per stage (summed over worker threads); ``on_frame``, if given, receives a
    :class:`~geocon_core.diagnostics.FrameDiagnostics` per frame, in frame order, on the calling
    thread. Raises
    :class:`~geocon_core.reader.ClipError` for unusable input."""
    cfg = config or ScoreConfig()
    if masks is not None:
        cfg = cfg.with_(masks="external")
    timer = _Timer(timings)
    start = time.perf_counter()
    info = probe_clip(path, cfg)
    start = timer.add("probe", start)
    matcher = make_matcher(cfg.matcher, max_features=cfg.max_features, ratio=cfg.ratio)
    backend: PoseBackend = load_pose_log(pose_log) if pose_log is not None else make_pose_backend(cfg.pose_backend)
    mask_source = None
    flow = make_flow_backend(cfg.flow) if cfg.masks != "none" else None  # shared: thread-safe per instance
    if cfg.masks == "external":
        if masks is None:
            raise ValueError("config.masks is 'external' but no masks path was given")
        mask_source = make_mask_source("external", info, path=masks)
    elif cfg.masks == "motion":
        mask_source = make_mask_source("motion", info, flow=flow, seed=cfg.seed)
    K = default_intrinsics(info.content_box, cfg.fov_x_deg)
    K_pose = scale_intrinsics(K, max(cfg.scales))
    n = info.num_frames
    windows = _windows(n, cfg.gate_window, cfg.gate_stride)
    window_ends: dict[int, list[tuple[int, int]]] = {}
    for w in windows:
        window_ends.setdefault(w[1], []).append(w)
    anchors = {0} | {w[0] for w in windows}
    max_gap = max(cfg.gaps)
    lookahead = 0 if mask_source is None else mask_source.lookahead
    content = info.content_mask
    content_px = max(1, int(np.count_nonzero(content)))

    workers = workers or min(2, os.cpu_count() or 1)
    feats: dict[int, Future] = {}
    inflight: deque[Future] = deque()
    pair_futures: list[Future] = []
    object_futures: list[Future] = []
    skipped: list[_Scored] = []
    window_futures: list[tuple[tuple[int, int], Future]] = []
    first_last: Future | None = None
    frames_buf: dict[int, Frame] = {}
    labels_buf: dict[int, np.ndarray] = {}
    masked_share = np.zeros(n)
    object_share: dict[int, dict[int, float]] = {}

    with ThreadPoolExecutor(max_workers=workers) as pool:
        pipe = _Pipeline(info, cfg, matcher, flow, timer)
        pipe.keep_flows = on_frame is not None
        rgb0: np.ndarray | None = None
        # frames waiting for their object flows (pair t, t+1) before they go to on_frame, in
        # order: [frame, labels, flows future or None, ready]
        pending: deque[list] = deque()

        def emit(final: bool) -> None:
            while pending and (final or pending[0][3]):
                frame, labels, fut, _ = pending[0]
                if not final and fut is not None and not fut.done() and len(pending) <= 2 * workers + 2:
                    break
                pending.popleft()
                flows = () if fut is None else tuple(fut.result()[1])
                on_frame(
                    FrameDiagnostics(frame.index, frame, info.fps, labels, float(masked_share[frame.index]), flows)
                )

        def process(t: int) -> None:
            """Everything that needs frame t and its mask; runs once labels(t) are final."""
            nonlocal first_last, rgb0
            frame = frames_buf[t]
            if t == 0:
                rgb0 = frame.rgb
            labels = None
            if mask_source is not None:
                labels = mask_source.labels(t)
                labels_buf[t] = labels
                inside = labels[content]
                masked_share[t] = np.count_nonzero(inside) / content_px
                ids, counts = np.unique(inside[inside > 0], return_counts=True)
                object_share[t] = {int(i): int(c) / content_px for i, c in zip(ids, counts)}
            # bounded read-ahead: a few frames wait for features, a few pairs for fitting
            while len(inflight) > workers:
                inflight.popleft().result()
            while sum(not f.done() for f in pair_futures[-4 * workers :]) >= 2 * workers:
                next(f for f in pair_futures if not f.done()).result()
            feats[t] = pool.submit(pipe.extract, frame, None if labels is None else labels == 0)
            inflight.append(feats[t])
            for gap in cfg.gaps:
                t0 = t - gap
                if t0 < 0:
                    continue
                reason = info.pair_skip_reason(t0, t)
                if reason is not None:
                    empty = np.zeros((0, 2))
                    skipped.extend(_Scored(t0, t, gap, s, reason, empty, empty, None, None) for s in cfg.scales)
                else:
                    pair_futures.append(pool.submit(pipe.score_pair, feats[t0], feats[t], t0, t, gap))
            if labels is not None and t >= 1 and (t - 1) in labels_buf:
                object_futures.append(
                    pool.submit(
                        pipe.score_objects, frames_buf[t - 1], frame, labels_buf[t - 1], info.pair_skip_reason(t - 1, t)
                    )
                )
                if on_frame is not None and pending and pending[-1][0].index == t - 1:
                    pending[-1][2] = object_futures[-1]  # frame t-1 is complete once its flows are
            if on_frame is not None:
                if pending:
                    pending[-1][3] = True
                pending.append([frame, labels, None, False])
                emit(final=False)
            for w in window_ends.get(t, []):
                if pose_log is None and w != (0, n - 1):
                    window_futures.append((w, pool.submit(pipe.pose, feats[w[0]], feats[t], backend, K_pose, w[0], t)))
            if t == n - 1:
                first_last = pool.submit(pipe.pose, feats[0], feats[t], backend, K_pose, 0, t, rgb0)
            for old in [k for k in feats if k < t - max_gap and k not in anchors]:
                del feats[old]
            for a in [k for k in anchors if k in feats and all(e < t for s, e in windows if s == k) and k != 0]:
                del feats[a]
            for old in [k for k in frames_buf if k < t - 1]:
                del frames_buf[old]
            for old in [k for k in labels_buf if k < t - 1]:
                del labels_buf[old]
            if mask_source is not None:
                mask_source.release(t - 1)
            if progress is not None:
                progress(t + 1, n)

        frames = iter_frames(info)
        next_t = 0
        while True:
            start = time.perf_counter()
            frame = next(frames, None)
            timer.add("decode", start)
            if frame is None:
                break
            frames_buf[frame.index] = frame
            if mask_source is not None:
                start = time.perf_counter()
                mask_source.push(frame)
                timer.add("masks", start)
            while next_t <= frame.index - lookahead:
                process(next_t)
                next_t += 1
        if mask_source is not None:
            mask_source.finish()
        while next_t < n:
            process(next_t)
            next_t += 1
        if on_frame is not None:
            emit(final=True)
        assert first_last is not None
        pose, cloud = first_last.result()
        scored = [r for f in pair_futures for r in f.result()] + skipped
        timeline_poses = [(w, f.result()) for w, f in window_futures]
        object_results = [r for f in object_futures for r in f.result()[0]]

    scored.sort(key=lambda r: (r.gap, r.t0, r.scale))
    object_results.sort(key=lambda r: (r[0], r[1], r[3]))
    record = replace(_assemble(str(path), info, cfg, K, backend, pose, timeline_poses, windows, scored), cloud=cloud)
    return _with_objects(record, cfg, mask_source, masks, masked_share, object_share, object_results)


def _aggregate(family: str, scored: list[_Scored], cfg: ScoreConfig) -> FamilySummary:
    def fit_of(r: _Scored) -> ModelFit | None:
        return r.h if family == "H" else r.f

    rows = []
    for r in scored:
        fit = None if r.skip else fit_of(r)
        rows.append(
            FitRow(r.gap, r.scale, False, None, None)
            if fit is None
            else FitRow(r.gap, r.scale, fit.valid, fit.ir, fit.ge)
        )
    per_gap, ir, ge = aggregate_gaps(rows, gaps=cfg.gaps, scales=cfg.scales, aggregation=cfg.aggregation)
    reasons: dict[str, int] = {}
    for r in scored:
        reason = r.skip or fit_of(r).reason
        if reason:
            reasons[reason] = reasons.get(reason, 0) + 1
    per_scale = []
    for s in cfg.scales:
        valid = [fit_of(r) for r in scored if r.scale == s and r.skip is None and fit_of(r).valid]
        f_valid = [r.f for r in scored if r.scale == s and r.skip is None and r.f.valid]
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
        family=family,  # type: ignore[arg-type]
        ir=ir,
        ge=ge,
        valid_pairs=sum(g.valid_pairs for g in per_gap),
        total_pairs=len(scored),
        per_gap=tuple(per_gap),
        per_scale=tuple(per_scale),
        invalid_reasons=dict(sorted(reasons.items())),
    )


def _assemble(clip, info, cfg, K, backend, pose, timeline_poses, windows, scored) -> ClipRecord:
    label, binary, margin = gate_decision(
        pose.t_inf, pose_present=pose.pose_present, tau_t=cfg.tau_t, low=cfg.tau_t_low, high=cfg.tau_t_high
    )
    fam = {f: _aggregate(f, scored, cfg) for f in ("H", "F")}
    warnings: list[str] = []
    model = choose_model(label, pose.pose_present, fam["H"].ir, fam["F"].ir)
    if not pose.pose_present:
        note = f"no pose ({pose.reason}): gated F by the fail->F policy"
        warnings.append(f"the first-last pose could not be recovered ({pose.reason}); the clip is gated F")
    elif label == "U":
        note = f"gray zone: both families fitted, kept {model} (IR H {fam['H'].ir}, IR F {fam['F'].ir})"
    else:
        note = f"t_inf {pose.t_inf:.4f} -> {label}"
    chosen, other = fam[model], fam["F" if model == "H" else "H"]
    consistent = report_verdict(chosen.ir, chosen.ge, cfg.ir_gate, cfg.ge_gate)
    if chosen.valid_pairs == 0:
        warnings.append("no valid pair: the background could not be judged")
    tau_f_px = fam["F"].per_scale[list(cfg.scales).index(max(cfg.scales))].tau_f_px
    background = BackgroundSummary(
        model=model,
        ir=chosen.ir,
        ge=chosen.ge,
        valid_pairs=chosen.valid_pairs,
        total_pairs=chosen.total_pairs,
        consistent=consistent,
        tau_f_px=tau_f_px,
        chosen=chosen,
        other=other,
        choice_note=note,
    )
    timeline = []
    for (s, e), est in timeline_poses:
        wl = (
            gate_decision(
                est.t_inf, pose_present=est.pose_present, tau_t=cfg.tau_t, low=cfg.tau_t_low, high=cfg.tau_t_high
            )[0]
            if est.pose_present
            else None
        )
        timeline.append(GateWindow(start=s, end=e, t_inf=est.t_inf, label=wl, pose_present=est.pose_present))
    if (0, info.num_frames - 1) in windows:
        timeline.append(
            GateWindow(0, info.num_frames - 1, pose.t_inf, label if pose.pose_present else None, pose.pose_present)
        )
    gate = GateRecord(
        label=label,
        binary_label=binary,
        model=model,
        t_inf=pose.t_inf,
        pose_present=pose.pose_present,
        margin=margin,
        backend=backend.name,
        thresholds={"tau_t": cfg.tau_t, "low": cfg.tau_t_low, "high": cfg.tau_t_high},
        pose=pose,
        timeline=tuple(timeline),
    )
    pairs, arrays = [], []
    for i, r in enumerate(scored):
        pairs.append(
            PairRecord(
                index=i,
                t0=r.t0,
                t1=r.t1,
                gap=r.gap,
                scale=r.scale,
                n_matches=len(r.x1),
                skip=r.skip,
                h=None if r.h is None else _fit_summary(r.h),
                f=None if r.f is None else _fit_summary(r.f),
            )
        )
        m = len(r.x1)
        z32, zb = np.zeros(m, np.float32), np.zeros(m, bool)
        arrays.append(
            {
                "x1": r.x1,
                "x2": r.x2,
                "h_res": z32 if r.h is None else r.h.residuals,
                "f_res": z32 if r.f is None else r.f.residuals,
                "f_res_px": z32 if r.f is None else r.f.residuals_px,
                "h_inl": zb if r.h is None else r.h.inliers,
                "f_inl": zb if r.f is None else r.f.inliers,
            }
        )
    if info.duplicates:
        warnings.append(f"{len(info.duplicates)} duplicated frame(s): pairs across them are not scored")
    if info.cuts:
        warnings.append(f"{len(info.cuts)} hard cut(s) at frame(s) {list(info.cuts)}: pairs across them are not scored")
    return ClipRecord(
        clip=clip,
        video=info,
        config=cfg,
        config_hash=config_hash(cfg),
        versions=software_versions(),
        gate=gate,
        background=background,
        pairs=tuple(pairs),
        matches=MatchArrays.concatenate(arrays),
        intrinsics=[[float(v) for v in row] for row in K],
        category=None,
        warnings=tuple(warnings),
    )


def _with_objects(
    record: ClipRecord,
    cfg: ScoreConfig,
    mask_source,
    masks_path,
    masked_share: np.ndarray,
    object_share: dict[int, dict[int, float]],
    results: list[tuple],
) -> ClipRecord:
    """Add object entries, per-object summaries, masked share and the category to a record."""
    entries: list[ObjectEntry] = []
    cells: list[dict | None] = []
    for oid, t0, t1, s, res in results:
        i = len(entries)
        if isinstance(res, str):
            entries.append(ObjectEntry(i, oid, t0, t1, s, False, res, None, None, 0, None))
            cells.append(None)
            continue
        affine = None if res.affine is None else [[float(v) for v in row] for row in res.affine]
        entries.append(ObjectEntry(i, oid, t0, t1, s, res.valid, res.reason, res.d_t, res.w2, res.n_pixels, affine))
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
    summaries = []
    s_max = max(cfg.scales)
    for oid in sorted({e.object_id for e in entries}):
        mine = [e for e in entries if e.object_id == oid]
        frames = sorted({e.t0 for e in mine})
        per_scale = []
        for s in cfg.scales:
            valid = [e for e in mine if e.scale == s and e.valid]
            skipped: dict[str, int] = {}
            for e in mine:
                if e.scale == s and not e.valid:
                    skipped[e.reason or "invalid"] = skipped.get(e.reason or "invalid", 0) + 1
            if valid:
                S, p90 = object_scores([e.d_t for e in valid])
                w2 = float(np.mean([e.w2 for e in valid]))
            else:
                S = p90 = w2 = None
            per_scale.append(ObjectScaleSummary(s, S, w2, p90, len(valid), dict(sorted(skipped.items()))))
        head = next(p for p in per_scale if p.scale == s_max)
        shares = [object_share.get(t, {}).get(oid, 0.0) for t in frames]
        summaries.append(
            ObjectSummary(
                object_id=oid,
                frames=len(frames),
                first_frame=frames[0],
                last_frame=frames[-1],
                masked_share=float(np.mean(shares)) if shares else 0.0,
                adadfrc=head.adadfrc,
                adadfrc_w2=head.adadfrc_w2,
                adap90=head.adap90,
                per_scale=tuple(per_scale),
            )
        )
    warnings = list(record.warnings) + (list(mask_source.warnings) if mask_source is not None else [])
    source = (
        "none" if mask_source is None else (f"external:{masks_path}" if masks_path is not None else mask_source.name)
    )
    category = _categorize(record, cfg, [o.frames for o in summaries])
    return replace(
        record,
        masks_source=source,
        masked_share=tuple(float(v) for v in masked_share),
        objects=tuple(summaries),
        object_entries=tuple(entries),
        cells=CellArrays.concatenate(cells),
        warnings=tuple(warnings),
        category=category,
    )


def _categorize(record: ClipRecord, cfg: ScoreConfig, object_frames: list[int]):
    """Inputs of the category rule, measured from the record (see :mod:`geocon_core.category`)."""
    s_max = max(cfg.scales)
    motions, matches = [], []
    for p in record.pairs:
        if p.gap != 1 or p.scale != s_max or p.skip is not None or p.h is None or not p.h.valid:
            continue
        arr = record.matches.pair(p.index)
        inl = arr["h_inl"]
        motions.append(float(np.median(np.linalg.norm(arr["x2"][inl] - arr["x1"][inl], axis=1))))
        matches.append(p.n_matches)
    bg = record.background
    return categorize(
        gate_model=record.gate.model,
        pose_present=record.gate.pose_present,
        t_inf=record.gate.t_inf,
        rotation_deg=record.gate.pose.rotation_deg,
        background_motion_px=float(np.median(motions)) if motions else None,
        valid_share=bg.valid_pairs / bg.total_pairs if bg.total_pairs else 0.0,
        median_matches=float(np.median(matches)) if matches else None,
        background_ir=bg.ir,
        object_frames=object_frames,
    )
