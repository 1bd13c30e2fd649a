"""Scoring one clip: composes reading, matching, model fitting and gating into a record.

The scorer streams frames: features of a frame are extracted once per scale and kept only
while a pair, the first-last pose or a gate window still needs them, so memory does not grow
with clip length beyond the per-match arrays of the record itself. Work runs on a small thread
pool (OpenCV releases the GIL) beside the mask lane, and no worker waits for another task's
result: pair fits and poses are submitted once their features are ready. Every random choice is
seeded from the config seed and the pair's identity, so results do not depend on scheduling.

:func:`score_clip` composes the stages: the clip is probed, the stages of :class:`_Pipeline`
(masks, features, pair fits, object rigidity, poses) run under the streaming schedule of
:mod:`geocon_core.scoring.schedule`, and :mod:`geocon_core.scoring.assemble` turns their results into the record
through the verdict rules of :mod:`geocon_core.scoring.verdict`.
"""

from __future__ import annotations

import contextlib
import importlib
import math
import os
import sys
import threading
import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import replace
from functools import partial
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

import cv2
import numpy as np

from ..config import ScoreConfig
from ..flow import FlowBackend, chained_flow, make_flow_backend
from ..geometry import (
    FAMILIES,
    FeatureSet,
    Matcher,
    ModelFit,
    PairFits,
    gross_mismatches,
    independent_motion,
    make_matcher,
    scale_intrinsics,
    scaled_inputs,
    two_view_cloud,
    with_independent,
)
from ..masks import MaskSource, check_masks_path, make_mask_source
from ..media import ClipInfo, Frame, iter_frames, probe_clip
from ..pose import (
    PoseBackend,
    PoseEstimate,
    chain_hops,
    chain_lengths,
    compose_chain,
    default_intrinsics,
    focal_of,
    load_pose_log,
    make_pose_backend,
    select_hops,
    still_pose,
    still_share,
)
from ..pose import failure as pose_failure
from ..reconstruction import (
    DenseCloudBuilder,
    DenseCloudConfig,
    LongTracks,
    MultiViewResult,
    TrackObservations,
    WindowCloud,
    reconstruct,
)
from ..record import ClipRecord, FrameDiagnostics, MatchArrays, ObjectFlow, PairRecord, PointCloud, PointMaps
from ..signals import ClipReadings, appearance_reading, content_gray, plan_pairs, unkept_share
from .assemble import assemble_record, object_parts, pair_tables, software_versions
from .judge import judge_background, judge_drift
from .rigidity import ObjectPairScore, adadfrc_pair, mask_interior, quiet_pot_backends, refine_object_mask
from .schedule import StreamSchedule, gate_windows

__all__ = ["score_clip", "software_versions", "read_readings"]

LARGE_PASS_PIXELS = 500_000
"""A feature pass on an image of this many pixels or more waits for any other such pass of the
clip to end (one at a time: their buffers are the scorer's largest); smaller passes run freely."""


def _pair_seed(seed: int, t0: int, t1: int, scale_index: int) -> int:
    return int(np.random.SeedSequence([seed, t0, t1, scale_index]).generate_state(1)[0])


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


class _SharedMatches:
    """Matches of the frame pairs two stages need alike (a chain hop that is also a gap-1 pair:
    the pose and the pair fit match the same top-scale features): made once by whichever stage
    asks first, handed to the second, then dropped. Matching is deterministic, so the numbers are
    those of matching twice."""

    def __init__(self, keys: set[tuple[int, int, float]]) -> None:
        self._uses = dict.fromkeys(keys, 2)
        self._made: dict[tuple[int, int, float], Future] = {}
        self._lock = threading.Lock()

    def get(self, key: tuple[int, int, float], make: Callable[[], tuple[np.ndarray, np.ndarray]]):
        """The matches of ``key`` (t0, t1, scale): ``make()`` unless another stage made them."""
        with self._lock:
            if key not in self._uses:
                fut = None
            else:
                fut = self._made.get(key)
                first = fut is None
                if first:
                    fut = self._made[key] = Future()
                self._uses[key] -= 1
                if not self._uses[key]:
                    del self._uses[key], self._made[key]
        if fut is None:
            return make()
        if first:
            try:
                fut.set_result(make())
            except BaseException as error:  # the second asker sees the same error
                fut.set_exception(error)
                raise
        return fut.result()


class _DeferredPose:
    """A chain hop's pose, estimated only when asked for (:meth:`result`): the hops of a clip or a
    shot stand in for its first-last pose only when that pose fails, so most clips never need
    them. The matches are kept (float32, as the features hold them; converted back exactly) with
    the pair's seed, so the estimate is the one made at once."""

    def __init__(self, backend: PoseBackend, x0: np.ndarray, x1: np.ndarray, K: np.ndarray, seed: int) -> None:
        self.backend, self.K, self.seed = backend, K, seed
        self.x0, self.x1 = x0.astype(np.float32), x1.astype(np.float32)

    def result(self) -> PoseEstimate:
        return self.backend.estimate(self.x0.astype(np.float64), self.x1.astype(np.float64), self.K, seed=self.seed)


def _resolve(
    by_window: dict[tuple[int, int], Any], keys: Sequence[tuple[int, int]], workers: int, timer: _Timer
) -> None:
    """Estimate the deferred poses among ``keys`` of ``by_window`` (in place), ``workers`` at a time."""
    todo = [k for k in keys if isinstance(by_window.get(k), _DeferredPose)]
    if not todo:
        return
    start = time.perf_counter()
    with ThreadPoolExecutor(max_workers=workers) as pool:
        for k, est in zip(todo, pool.map(lambda k: by_window[k].result(), todo), strict=True):
            by_window[k] = est
    timer.add("pose", start)


class _Pipeline:
    """The scorer's stages (:class:`~geocon_core.scoring.schedule.Stages`): masks, features, pair fits,
    object rigidity and poses of one clip, plus the masked share measured from the labels."""

    def __init__(
        self,
        info: ClipInfo,
        config: ScoreConfig,
        matcher: Matcher,
        flow: FlowBackend | None,
        backend: PoseBackend,
        K: np.ndarray,
        mask_source: MaskSource | None,
        timer: _Timer,
        *,
        keep_flows: bool,
        dense: DenseCloudBuilder | None = None,
    ) -> None:
        self.info, self.config, self.matcher, self.flow, self.timer = info, config, matcher, flow, timer
        self.dense = dense
        self.backend, self.mask_source, self.keep_flows = backend, mask_source, keep_flows
        # a backend that reads frames (DUSt3R) gets the first and last; its point maps go to the record
        self.anchor_rgb: dict[int, np.ndarray] | None = {} if getattr(backend, "needs_frames", False) else None
        self.pointmaps: PointMaps | None = None
        self.s_max = max(config.scales)
        x0, y0, x1, y1 = info.content_box
        side = min(x1 - x0, y1 - y0)
        self.active = tuple(s for s in config.scales if s == self.s_max or s * side >= config.min_scale_side)
        self.large_pass = threading.BoundedSemaphore(1)  # see extract
        self.K_pose = scale_intrinsics(K, self.s_max)
        self.lookahead = 0 if mask_source is None else mask_source.lookahead
        self.content = info.content_mask
        self.content_px = max(1, int(np.count_nonzero(self.content)))
        self.masked_share = np.zeros(info.num_frames)
        self.object_share: dict[int, dict[int, float]] = {}
        self.still_frames: frozenset[int] = frozenset()
        """Frames the still-camera test compares (each shot's first and last)."""
        self.still: dict[int, tuple[np.ndarray, np.ndarray | None]] = {}
        """Those frames' content at the motion analysis size (grey) and their object masks."""
        self.still_maps: dict[tuple[int, int], np.ndarray] = {}
        """Per span (clip or shot) of a still camera, its pixels that did not move (test size)."""
        self.tracks = (
            LongTracks(config.multiview, info.num_frames, info.working_size) if config.multiview.enabled else None
        )
        """The multi-view check's long tracks (:mod:`geocon_core.reconstruction.multiview`), when it is on."""
        self.reading_frames: dict[int, np.ndarray] = {}
        """The frames the appearance readings use, on their canvas (:mod:`geocon_core.signals`)."""
        self.reading_needed: frozenset[int] = frozenset()
        if config.signals.enabled:
            far, near = plan_pairs(info.num_frames, config.signals)
            self.reading_needed = frozenset(t for pair in (*far, *near) for t in pair)
        self.shared = _SharedMatches(set())
        """Matches two stages need alike (set by :func:`score_clip` once the pose windows are known)."""
        self.object_scales = (self.s_max,) if config.object_scales == "top" else tuple(config.scales)
        """The scales objects are scored at (``ScoreConfig.object_scales``)."""
        self.deferred: frozenset[tuple[int, int]] = frozenset()
        """Pose windows whose estimate waits until asked for (chain hops: :class:`_DeferredPose`)."""

    # --- masks (the mask lane) -----------------------------------------------------------------
    def push(self, frame: Frame) -> None:
        if self.mask_source is not None:
            start = time.perf_counter()
            self.mask_source.push(frame)
            self.timer.add("masks", start)

    def finish(self) -> None:
        if self.mask_source is not None:
            self.mask_source.finish()

    def labels(self, t: int) -> np.ndarray | None:
        """The final labels of frame t, with the masked share of the frame and of each object."""
        if self.mask_source is None:
            return None
        labels = self.mask_source.labels(t)
        inside = labels[self.content]
        self.masked_share[t] = np.count_nonzero(inside) / self.content_px
        ids, counts = np.unique(inside[inside > 0], return_counts=True)
        self.object_share[t] = {int(i): int(c) / self.content_px for i, c in zip(ids, counts, strict=True)}
        return labels

    def release(self, t: int) -> None:
        if self.mask_source is not None:
            self.mask_source.release(t)

    def emit(self, on_frame: Callable[[FrameDiagnostics], None], frame: Frame, labels, flows: tuple) -> None:
        share = float(self.masked_share[frame.index])
        on_frame(FrameDiagnostics(frame.index, frame, self.info.fps, labels, share, flows))

    def observe(self, frame: Frame, labels: np.ndarray | None) -> None:
        """The dense clouds' share of frame t (:class:`~geocon_core.reconstruction.dense.DenseCloudBuilder`)."""
        if self.dense is not None:
            start = time.perf_counter()
            self.dense.observe(frame.index, frame.rgb, frame.gray, labels)
            self.timer.add("dense", start)
        if self.anchor_rgb is not None and frame.index in (0, self.info.num_frames - 1):
            self.anchor_rgb[frame.index] = frame.rgb
        if frame.index in self.still_frames:
            self.still[frame.index] = _reduced(frame.gray, labels, self.info, self.config.motion.analysis_size)
        if frame.index in self.reading_needed:
            self.reading_frames[frame.index] = content_gray(frame.gray, self.info.content_box, self.config.signals)
        if self.tracks is not None:
            start = time.perf_counter()
            self.tracks.observe(
                frame.index, frame.gray, frame.content if labels is None else frame.content & (labels == 0)
            )
            self.timer.add("multiview", start)

    def still_test(self, span: tuple[int, int], est: PoseEstimate, K: np.ndarray) -> PoseEstimate:
        """The still-camera test of frames ``span`` (``ScoreConfig.still_share``): when it passes,
        the span's still pixels are kept (:attr:`still_maps`) and, where the gate would not call
        ``est`` H, the still pose replaces it; otherwise ``est``."""
        cfg = self.config
        start, end = span
        if end == start or start not in self.still or end not in self.still:
            return est
        (g0, m0), (g1, m1) = self.still[start], self.still[end]
        ignore = None if m0 is None or m1 is None else (m0 | m1)
        test = still_share(g0, g1, still_px=cfg.still_px, ignore=ignore)
        if test.share < cfg.still_share:
            return est
        self.still_maps[span] = test.still
        if est.pose_present and est.t_inf is not None and est.t_inf <= cfg.tau_t_low:
            return est
        x0, _, x1, _ = self.info.content_box
        return still_pose(test.share, test.motion_px, (x1 - x0) / g0.shape[1], focal_of(K), span)

    # --- work on the pool ----------------------------------------------------------------------
    def extract(self, frame: Frame, labels: np.ndarray | None) -> dict[float, FeatureSet]:
        """Features of frame t inside ``B_t`` = content minus object masks, at every scale."""
        mask = frame.content if labels is None else frame.content & (labels == 0)
        out = {}
        start = time.perf_counter()
        inputs = {s: scaled_inputs(frame.gray, mask, s) for s in self.active}
        if hasattr(self.matcher, "extract_scales"):
            out = self.matcher.extract_scales(inputs, frame.index)
        else:
            for s, (g, m) in inputs.items():
                # one large pass at a time: SIFT's first octave (a doubled frame, eleven float
                # images) is the largest buffer of the scorer; deterministic, so the same numbers
                with self.large_pass if g.size >= LARGE_PASS_PIXELS else contextlib.nullcontext():
                    out[s] = self.matcher.extract(g, m, frame.index, s)
        self.timer.add("features", start)
        return out

    def score_pair(self, fa: Future, fb: Future, t0: int, t1: int, gap: int) -> list[PairFits]:
        """Both families fitted on the pair (t0, t1) at every scale, seeded by the pair."""
        a, b = fa.result(), fb.result()
        cfg = self.config
        results = []
        for si, s in enumerate(cfg.scales):
            if s not in self.active:
                results.extend(self.skip_pair(t0, t1, gap, "scale_too_small", scales=(s,)))
                continue
            start = time.perf_counter()
            x1, x2 = self.shared.get((t0, t1, s), partial(self.matcher.match, a[s], b[s]))
            n_gross = 0
            if cfg.gross_match_share > 0:
                h, w = a[s].mask.shape
                gross = gross_mismatches(x1, x2, cfg.gross_match_share * math.hypot(w, h), cfg.gross_match_neighbours)
                n_gross = int(gross.sum())
                x1, x2 = x1[~gross], x2[~gross]
            start = self.timer.add("matching", start)
            seed = _pair_seed(cfg.seed, t0, t1, si)
            kw = dict(min_inliers=cfg.min_inliers, iters=cfg.ransac_iters, confidence=cfg.ransac_confidence)
            fits = {
                name: spec.fit(x1, x2, tau=getattr(cfg, spec.threshold), seed=seed, **kw)
                for name, spec in FAMILIES.items()
            }
            if cfg.independent.enabled:
                fits = {name: _independent(fit, x1, cfg) for name, fit in fits.items()}
            self.timer.add("model_fitting", start)
            # kept as the record stores them (float32), so memory per match stays small
            results.append(
                PairFits(
                    t0, t1, gap, s, None, x1.astype(np.float32), x2.astype(np.float32), fits["H"], fits["F"], n_gross
                )
            )
        return results

    def skip_pair(
        self, t0: int, t1: int, gap: int, reason: str, scales: tuple[float, ...] | None = None
    ) -> list[PairFits]:
        empty = np.zeros((0, 2), np.float32)
        return [PairFits(t0, t1, gap, s, reason, empty, empty, None, None) for s in scales or self.config.scales]

    def score_objects(
        self, frames: Sequence[Frame], labels: Sequence[np.ndarray], skip: str | None
    ) -> tuple[list[ObjectPairScore], list[ObjectFlow]]:
        """AdaDFRC of every object of ``frames[0]`` (frame t0) on the pair (t0, t1) of the first and
        last of ``frames`` (consecutive frames, ``object_gap + 1`` of them, with their labels), at
        each scale of :attr:`object_scales`, and the flow slices at scale 1 (kept only when
        diagnostics are streamed). Over more than one hop the flow is composed over the consecutive frames
        (:func:`~geocon_core.flow.dense.chained_flow`) on the box of the object's masks in all of them."""
        start = time.perf_counter()
        out: list[ObjectPairScore] = []
        flows: list[ObjectFlow] = []
        f0, f1 = frames[0], frames[-1]
        ids = [int(i) for i in np.unique(labels[0]) if i]
        if skip is not None or not ids:
            out = [ObjectPairScore(oid, f0.index, f1.index, s, None, skip) for s in self.object_scales for oid in ids]
            self.timer.add("objects", start)
            return out, flows
        for s in self.object_scales:
            grays = [_scaled(f.gray, s, cv2.INTER_AREA) for f in frames]
            labs = [_scaled(lab, s, cv2.INTER_NEAREST) for lab in labels]
            lab = labs[0]
            for oid in ids:
                mask = lab == oid
                if not mask.any():
                    out.append(ObjectPairScore(oid, f0.index, f1.index, s, None, "empty_mask"))
                    continue
                assert self.flow is not None, "objects are scored only with a flow backend"
                # over one hop the object's box in t0 (the paper's crop, whose margin covers the
                # motion); over several, the box of its masks in all the frames
                box = _union_box([mask] if len(labs) == 2 else [m == oid for m in labs])
                field = chained_flow(self.flow, grays, box)
                x0, y0, x1, y1 = field.box
                crop = mask[y0:y1, x0:x1]
                if self.config.refine_object_masks:
                    crop = refine_object_mask(field.flow, crop, (lab[y0:y1, x0:x1] > 0) & ~crop)
                reliable = field.reliable & mask_interior(crop, self.config.object_edge_px)
                res = adadfrc_pair(
                    field.flow,
                    crop,
                    reliable,
                    grid=self.config.grid,
                    min_cells=self.config.min_cells,
                    origin=(float(x0), float(y0)),
                )
                out.append(ObjectPairScore(oid, f0.index, f1.index, s, res))
                if self.keep_flows and s == 1.0:
                    flows.append(ObjectFlow(oid, f0.index, f1.index, field.box, field.flow, reliable, crop))
        self.timer.add("objects", start)
        return out, flows

    def pose(self, fa: Future, fb: Future, t0: int, t1: int, first: Frame | None) -> Any:
        """The relative pose (t0 -> t1); with ``first`` (frame t0), also the two-view point cloud."""
        a, b = fa.result()[self.s_max], fb.result()[self.s_max]
        start = time.perf_counter()
        x0, x1 = self.shared.get((t0, t1, self.s_max), partial(self.matcher.match, a, b))
        seed = _pair_seed(self.config.seed, t0, t1, 99)
        if first is None and (t0, t1) in self.deferred:
            self.timer.add("pose", start)
            return _DeferredPose(self.backend, x0, x1, self.K_pose, seed)
        if first is not None and self.anchor_rgb is not None:
            frames_backend: Any = self.backend
            rgb1, box = self.anchor_rgb[t1], self.info.content_box
            est, self.pointmaps = frames_backend.estimate_frames(first.rgb, rgb1, box, self.K_pose, (t0, t1))
        else:
            est = self.backend.estimate(x0, x1, self.K_pose, seed=seed)
        self.timer.add("pose", start)
        if first is None:
            return est
        return est, _cloud(est, self.K_pose, x0, x1, first.rgb, self.s_max)


def _independent(fit: ModelFit, x1: np.ndarray, cfg: ScoreConfig) -> ModelFit:
    """``fit`` with the outliers that move on their own left out of its IR
    (:func:`~geocon_core.geometry.models.independent_motion`, ``cfg.independent``)."""
    if fit.model is None:
        return fit
    ind = cfg.independent
    mask = independent_motion(x1, fit.residuals_px, fit.inliers, neighbours=ind.neighbours, jump=ind.jump)
    return with_independent(fit, mask, min_inliers=cfg.min_inliers, max_share=ind.max_share)


def _keep_still(
    scored: list[PairFits], maps: dict[tuple[int, int], np.ndarray], info: ClipInfo, cfg: ScoreConfig
) -> list[PairFits]:
    """The pairs of a still camera judged on its still pixels: the matches of each pair inside a
    span of ``maps`` whose first-frame position moved between the span's first and last frame (a
    mover, seen by the motion segmentation or not) are left out of both families' IR and GE, as
    independent motion is (:func:`_leave_out`, :func:`~geocon_core.geometry.models.with_independent`)."""
    if not maps:
        return scored
    x0, y0, x1b, y1b = info.content_box
    out = []
    for r in scored:
        span = next(((a, b) for (a, b) in maps if a <= r.t0 and r.t1 <= b), None)
        if span is None or r.skip is not None or not len(r.x1):
            out.append(r)
            continue
        still = maps[span]
        h, w = still.shape
        px = np.clip(((r.x1[:, 0] / r.scale - x0) * w / (x1b - x0)).astype(int), 0, w - 1)
        py = np.clip(((r.x1[:, 1] / r.scale - y0) * h / (y1b - y0)).astype(int), 0, h - 1)
        moved = ~still[py, px]
        fits = {name: _leave_out(r.fit(name), moved, cfg) for name in FAMILIES}
        out.append(replace(r, h=fits["H"], f=fits["F"]))
    return out


def _leave_out(fit: ModelFit | None, moved: np.ndarray, cfg: ScoreConfig) -> ModelFit | None:
    """``fit`` with the matches on pixels that ``moved`` over the span left out (as well as its
    independent motion), except those that sit within ``still_keep_px`` of the model in this
    pair (a mover that stood still here still shows the still camera); more than
    ``independent.max_share`` of the matches left out and the pair cannot be judged."""
    if fit is None or fit.model is None:
        return fit
    moved = moved & ~(fit.residuals_px <= np.float32(cfg.still_keep_px))
    ind = moved if fit.independent is None else (fit.independent | moved)
    return with_independent(fit, ind, min_inliers=cfg.min_inliers, max_share=cfg.independent.max_share)


def _reduced(
    gray: np.ndarray, labels: np.ndarray | None, info: ClipInfo, size: tuple[int, int]
) -> tuple[np.ndarray, np.ndarray | None]:
    """A frame's content at the largest size inside ``size`` (never up) and its object mask."""
    x0, y0, x1, y1 = info.content_box
    w, h = x1 - x0, y1 - y0
    f = min(1.0, size[0] / w, size[1] / h)
    dst = (max(16, round(w * f)), max(16, round(h * f)))
    g = cv2.resize(gray[y0:y1, x0:x1], dst, interpolation=cv2.INTER_AREA)
    if labels is None:
        return g, None
    m = cv2.resize((labels[y0:y1, x0:x1] > 0).astype(np.uint8), dst, interpolation=cv2.INTER_NEAREST) > 0
    return g, m


def _scaled(img: np.ndarray, s: float, interpolation: int) -> np.ndarray:
    """``img`` at scale ``s`` (area resampling for grey frames, nearest for labels)."""
    if s == 1.0:
        return img
    h, w = img.shape[:2]
    return cv2.resize(img, (max(1, round(w * s)), max(1, round(h * s))), interpolation=interpolation)


def _union_box(masks: Sequence[np.ndarray]) -> tuple[int, int, int, int]:
    """The end-exclusive box (x0, y0, x1, y1) of every pixel set in any of ``masks`` (the first
    is not empty)."""
    ys, xs = np.nonzero(np.logical_or.reduce(masks))
    return int(xs.min()), int(ys.min()), int(xs.max()) + 1, int(ys.max()) + 1


def _cloud(
    est: PoseEstimate, K: np.ndarray, x0: np.ndarray, x1: np.ndarray, rgb0: np.ndarray, scale: float
) -> PointCloud:
    """The first-last point cloud (:func:`~geocon_core.geometry.twoview.two_view_cloud`), or an empty one
    whose note says why there is none."""
    empty = PointCloud(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.uint8), "")
    if not est.pose_present:
        return replace(empty, note=f"no point cloud: no first-last pose ({est.reason})")
    T = np.asarray(est.T_cam0_camT, dtype=float)
    if not np.linalg.norm(T[:3, 3]) > 0:
        return replace(
            empty, note=f"no point cloud: {est.method} pose without translation (no parallax to triangulate)"
        )
    xyz, rgb = two_view_cloud(K, T, x0, x1, rgb0, scale, focal_scale=est.focal_scale)
    note = (
        f"{len(xyz)} of {len(x0)} first-last matches triangulated with the {est.method} pose "
        "(front of both cameras, reprojection <= 2 px)"
    )
    return PointCloud(xyz, rgb, note)


def _chain_windows(span: tuple[int, int], cfg: ScoreConfig) -> list[tuple[int, int]]:
    """Every chain hop inside frames ``span`` (inclusive): hops of ``chain_hop`` frames and of
    the longer lengths up to ``chain_longest`` (none when chains are off or the span is one hop)."""
    start, end = span
    if cfg.chain_hop == 0 or end - start < 1:
        return []
    out: list[tuple[int, int]] = []
    for length in chain_lengths(cfg.chain_hop, cfg.chain_longest):
        out += [(start + a, start + b) for a, b in chain_hops(end - start + 1, length)]
    return list(dict.fromkeys(out))


def _chain_pose(
    span: tuple[int, int],
    by_window: dict[tuple[int, int], PoseEstimate],
    hops: list[tuple[int, int]],
    failed: PoseEstimate,
    cfg: ScoreConfig,
) -> PoseEstimate | None:
    """The pose over ``span`` composed from its hops (:func:`~geocon_core.pose.chain.select_hops`,
    :func:`~geocon_core.pose.chain.compose_chain`), or None when they span too little."""
    start, end = span
    local = {(a - start, b - start): by_window[(a, b)] for a, b in hops}
    chosen = select_hops(local, end - start + 1)
    return compose_chain(chosen, end - start + 1, failed, min_share=cfg.chain_min_share)


def _shot_pose(
    shot: tuple[int, int],
    by_window: dict[tuple[int, int], PoseEstimate],
    hops: list[tuple[int, int]],
    K: np.ndarray,
    cfg: ScoreConfig,
) -> PoseEstimate:
    """The pose of a shot's first and last frame, composed from its hops when that pair failed
    (as for a whole clip); a failure with reason ``single_frame`` for a shot of one frame."""
    start, end = shot
    if end == start:
        return pose_failure("single_frame", 0, float(np.sqrt(K[0, 0] * K[1, 1])))
    est: PoseEstimate = by_window[shot]
    if not est.pose_present and hops:
        est = _chain_pose(shot, by_window, hops, est, cfg) or est
    return est


def _mask_source(
    cfg: ScoreConfig, info: ClipInfo, masks: str | Path | None, flow: FlowBackend | None, sam2_model: Any = None
):
    if cfg.masks == "sam2":
        return make_mask_source("sam2", info, cfg.motion, model=sam2_model, sam2=cfg.sam2, flow=flow, seed=cfg.seed)
    if cfg.masks == "external":
        if masks is None:
            raise ValueError("config.masks is 'external' but no masks path was given")
        return make_mask_source("external", info, path=masks)
    if cfg.masks == "motion":
        return make_mask_source("motion", info, cfg.motion, flow=flow, seed=cfg.seed)
    return None


def _multiview(
    obs: TrackObservations, K: np.ndarray, cfg: ScoreConfig, info: ClipInfo, spans: list[tuple[int, int, str]]
) -> MultiViewResult:
    """The multi-view check (:mod:`geocon_core.reconstruction.multiview`): one reconstruction per
    span (each shot, or the whole clip; ``(start, end, model)``) under the model its gate chose.
    With cuts, the result kept is that of the first shot with a drifting layer, else of the
    longest shot."""
    results = []
    for start, end, model in spans:
        keep = [i for i, t in enumerate(obs.frames) if start <= t <= end]
        part = TrackObservations([obs.frames[i] for i in keep], [obs.ids[i] for i in keep], [obs.xy[i] for i in keep])
        results.append(
            (
                end - start,
                reconstruct(
                    part, K, info.working_size, "H" if model == "H" else "F", cfg.multiview, px_scale=info.scale
                ),
            )
        )
    flagged = [r for _, r in results if r.flagged]
    return flagged[0] if flagged else max(results, key=lambda lr: lr[0])[1]


def _import_aside(module: str) -> None:
    """Start importing ``module`` on a side thread. POT takes about a second to import (it loads
    much of SciPy); imported where first used, on a worker in the middle of the clip, it stalls
    the other threads, while during the probe pass, which decodes with the GIL released, one core
    is idle. A later ``import`` of the module simply waits for this one."""
    if module not in sys.modules:
        threading.Thread(target=_import_quietly, args=(module,), name=f"import-{module}", daemon=True).start()


def _import_quietly(module: str) -> None:
    """Import ``module``; a failure is left to the import where the module is used, which says why.
    Any failure is silent here: a short run may end while this side import is still going, and an
    import cut off by the interpreter's shutdown must not print a traceback after a finished run."""
    try:
        importlib.import_module(module)
    except Exception:  # noqa: BLE001  # re-raised by the real import, where it matters
        pass


def _timed(frames: Iterator[Frame], timer: _Timer) -> Iterator[Frame]:
    """``frames``, with the time spent decoding each added to the timer."""
    while True:
        start = time.perf_counter()
        frame = next(frames, None)
        timer.add("decode", start)
        if frame is None:
            return
        yield frame


def _flow_backend(cfg: ScoreConfig, checkpoint: str | Path | None) -> FlowBackend | None:
    """The dense flow of the masks and objects (None without masks); a checkpoint only for a
    backend that loads one."""
    weighted = cfg.flow.strip().lower() == "raft"
    if checkpoint is not None and not weighted:
        raise ValueError(f"a flow checkpoint was given but the flow backend is {cfg.flow!r} (use --flow raft)")
    if cfg.masks == "none":
        return None
    return make_flow_backend(cfg.flow, cfg.flow_params, **({"checkpoint": checkpoint} if weighted else {}))


def _sam2_model(cfg: ScoreConfig, checkpoint: str | Path | None) -> Any:
    """SAM-2's model for ``masks = "sam2"`` (None otherwise), loaded before the clip is decoded."""
    if cfg.masks != "sam2":
        if checkpoint is not None:
            raise ValueError(f"a SAM-2 checkpoint was given but the masks are {cfg.masks!r} (use --masks sam2)")
        return None
    from ..masks import load_sam2

    return load_sam2(checkpoint, cfg.sam2)


def _pose_backend(cfg: ScoreConfig, checkpoint: str | Path | None, clone: str | Path | None) -> PoseBackend:
    """The pose backend ``cfg.pose_backend`` names, built (and its weights loaded) before decoding."""
    if cfg.pose_backend.strip().lower() == "dust3r":
        return make_pose_backend("dust3r", cfg.dust3r, checkpoint=checkpoint, clone=clone)
    if checkpoint is not None or clone is not None:
        raise ValueError(
            f"a DUSt3R checkpoint or path was given but the pose backend is {cfg.pose_backend!r} (use --pose dust3r)"
        )
    return make_pose_backend(cfg.pose_backend, cfg.pose)


def score_clip(
    path: str | Path,
    config: ScoreConfig | None = None,
    *,
    pose_log: str | Path | None = None,
    masks: str | Path | None = None,
    flow_checkpoint: str | Path | None = None,
    sam2_checkpoint: str | Path | None = None,
    dense: DenseCloudConfig | None = None,
    dust3r_checkpoint: str | Path | None = None,
    dust3r_path: str | Path | None = None,
    workers: int | None = None,
    progress: Callable[[int, int], None] | None = None,
    timings: dict[str, float] | None = None,
    on_frame: Callable[[FrameDiagnostics], None] | None = None,
) -> ClipRecord:
    """Score one clip. ``pose_log`` replaces the pose backend by an external pose (JSON, see
    :mod:`geocon_core.pose`); ``masks`` is a path to external object masks (see
    :mod:`geocon_core.masks`), otherwise ``config.masks`` chooses the built-in segmentation or
    none; ``flow_checkpoint`` is the weights file of a neural flow backend (``config.flow ==
    "raft"``: a ``raft-small.pth``); ``sam2_checkpoint`` is SAM-2's weights file for ``config.masks
    == "sam2"`` (its model configuration is ``config.sam2.model``); ``dense``, if given, also
    makes the dense point clouds of the first/last pair and of every gate window
    (:mod:`geocon_core.reconstruction.dense`, no score changes);
    ``dust3r_checkpoint`` (and ``dust3r_path``, a DUSt3R checkout) serve ``config.pose_backend ==
    "dust3r"`` (:mod:`geocon_core.pose.dust3r`), which poses the first and last frame only;
    ``progress(done, total)`` is called as frames are processed; ``timings``, if given,
    receives seconds per stage (summed over worker threads); ``on_frame``, if given, receives a
    :class:`~geocon_core.record.overlays.FrameDiagnostics` per frame, in frame order, on the calling
    thread. Raises :class:`~geocon_core.media.reader.ClipError` for unusable input."""
    cfg = config or ScoreConfig()
    if masks is not None:
        cfg = cfg.with_(masks="external")
    timer = _Timer(timings)
    if cfg.masks != "none":
        quiet_pot_backends()
        _import_aside("ot")  # AdaDFRC's transport solver
    # a pose log, external masks and flow weights are checked before the clip is decoded
    backend = load_pose_log(pose_log) if pose_log is not None else _pose_backend(cfg, dust3r_checkpoint, dust3r_path)
    if masks is not None:
        check_masks_path(masks)
    flow = _flow_backend(cfg, flow_checkpoint)  # shared: thread-safe per instance
    sam2_model = _sam2_model(cfg, sam2_checkpoint)
    start = time.perf_counter()
    info = probe_clip(path, cfg)
    timer.add("probe", start)
    n = info.num_frames
    matcher = make_matcher(cfg.matcher, max_features=cfg.max_features, ratio=cfg.ratio, anchors=(0, n - 1))
    mask_source = _mask_source(cfg, info, masks, flow, sam2_model)
    K = default_intrinsics(info.content_box, cfg.fov_x_deg)
    windows = gate_windows(n, cfg.gate_window, cfg.gate_stride)
    first_last_only = pose_log is not None or getattr(backend, "needs_frames", False)  # a log, DUSt3R
    hops = [] if first_last_only or cfg.chain_hop == 0 else _chain_windows((0, n - 1), cfg)
    pose_windows = [] if first_last_only else [w for w in windows if w != (0, n - 1)]
    builder = None
    if dense is not None and n >= 2:
        dense_flow = (
            flow
            if flow is not None and cfg.flow.strip().lower() != "dis"  # a neural flow serves the clouds too
            else make_flow_backend("dis", cfg.flow_params, preset=dense.dis_preset)
        )
        builder = DenseCloudBuilder(info.content_mask, [(0, n - 1), *pose_windows], dense_flow, dense)
    stages = _Pipeline(
        info, cfg, matcher, flow, backend, K, mask_source, timer, keep_flows=on_frame is not None, dense=builder
    )
    if cfg.still_share > 0 and not first_last_only:
        stages.still_frames = frozenset(t for shot in info.shots for t in shot)
    shots = info.shots if cfg.judge_shots and len(info.shots) > 1 and not first_last_only else ()
    shot_hops = {shot: _chain_windows(shot, cfg) for shot in shots}
    for shot in shots:
        pose_windows += [w for w in (shot, *shot_hops[shot]) if w[1] > w[0] and w != (0, n - 1)]
    pose_windows += [h for h in hops if h not in pose_windows]
    pose_windows = list(dict.fromkeys(pose_windows))
    # a chain hop is estimated only if the first-last pose of its clip or shot fails
    stages.deferred = frozenset(set(hops).union(*shot_hops.values()) - {*windows, *shots, (0, n - 1)})
    stages.shared = _SharedMatches(
        {
            (t0, t1, stages.s_max)
            for t0, t1 in [*pose_windows, (0, n - 1)]
            if t1 - t0 in cfg.gaps and info.pair_skip_reason(t0, t1) is None
        }
    )
    emit = None if on_frame is None else partial(stages.emit, on_frame)
    workers = workers or min(2, os.cpu_count() or 1)
    object_gap = min(cfg.object_gap, max(1, n - 1))  # a clip shorter than the gap: its first and last frame
    with ThreadPoolExecutor(max_workers=workers) as pool:
        schedule = StreamSchedule(
            stages, pool, n, cfg.gaps, pose_windows, info.pair_skip_reason, workers, emit, progress, object_gap
        )
        out = schedule.run(_timed(iter_frames(info), timer))
    pose, cloud = out.first_last
    by_window = dict(out.windows)
    if not pose.pose_present and hops:
        _resolve(by_window, hops, workers, timer)
        pose = _chain_pose((0, n - 1), by_window, hops, pose, cfg) or pose
    if stages.still_frames and not shots:  # with cuts, each shot is tested on its own
        pose = stages.still_test((0, n - 1), pose, K)
    timeline = [(w, by_window[w]) for w in windows if w in by_window]
    for shot in shots:
        if shot[1] > shot[0] and not by_window[shot].pose_present:
            _resolve(by_window, shot_hops[shot], workers, timer)
    shot_poses = [(shot, _shot_pose(shot, by_window, shot_hops[shot], K, cfg)) for shot in shots]
    if stages.still_frames:
        shot_poses = [(shot, stages.still_test(shot, est, K)) for shot, est in shot_poses]
    scored = _keep_still(sorted(out.pairs, key=lambda r: (r.gap, r.t0, r.scale)), stages.still_maps, info, cfg)
    # the verdicts, read once from the finished stages; the record is assembled last
    judgement = judge_background(cfg, n, pose, timeline, scored, shot_poses)
    multiview = None
    if stages.tracks is not None:
        start = time.perf_counter()
        multiview = _multiview(stages.tracks.observations, K, cfg, info, judgement.spans(n))
        judgement = judge_drift(judgement, multiview)
        timer.add("multiview", start)
    tables = pair_tables(scored)
    readings = _readings(stages.reading_frames, tables, info, cfg, timer)
    objects = object_parts(
        cfg,
        sorted(out.objects, key=lambda r: r.key),
        scales=stages.object_scales,
        masked_share=stages.masked_share,
        object_share=stages.object_share,
        mask_source=mask_source,
        masks_path=masks,
    )
    notes = []
    if object_gap < cfg.object_gap and mask_source is not None:
        notes.append(f"objects scored on frames {object_gap} apart: the clip has {n} frames, fewer than object_gap + 1")
    clouds: tuple[WindowCloud, ...] = ()
    if builder is not None:
        start = time.perf_counter()
        resolved = {w: est for w, est in by_window.items() if not isinstance(est, _DeferredPose)}
        clouds = builder.clouds(K, {**resolved, (0, n - 1): pose})
        timer.add("dense", start)
    return assemble_record(
        str(path),
        info,
        cfg,
        K,
        backend.name,
        judgement,
        timeline,
        windows,
        tables,
        objects,
        notes=notes,
        multiview=multiview,
        readings=readings,
        dense=clouds,
        cloud=cloud,
        pointmaps=stages.pointmaps,
    )


def read_readings(record: ClipRecord, record_dir: str | Path, config: ScoreConfig) -> ClipRecord:
    """``record`` with the readings ``config.signals`` makes (:mod:`geocon_core.signals`), read from its
    clip again (found as :func:`~geocon_core.media.locate_clip` finds it) and its stored matches:
    the numbers :func:`score_clip` would have recorded beside the same background fit. Raises
    :class:`~geocon_core.media.ClipError` when the clip is gone."""
    from ..media import locate_clip

    cfg = replace(record.config, signals=replace(config.signals, enabled=True))
    info = locate_clip(record.video, record_dir)
    far, near = plan_pairs(info.num_frames, cfg.signals)
    needed = {t for pair in (*far, *near) for t in pair}
    frames: dict[int, np.ndarray] = {}
    for frame in iter_frames(info):
        if frame.index in needed:
            frames[frame.index] = content_gray(frame.gray, info.content_box, cfg.signals)
        if len(frames) == len(needed):
            break
    return replace(record, readings=_readings(frames, (record.pairs, record.matches), record.video, cfg, _Timer(None)))


def _readings(
    frames: dict[int, np.ndarray],
    tables: tuple[tuple[PairRecord, ...], MatchArrays],
    video: ClipInfo,
    cfg: ScoreConfig,
    timer: _Timer,
) -> ClipReadings | None:
    """The readings beside the background fit (:mod:`geocon_core.signals`), when ``cfg.signals``
    is on: the appearance readings of the frames kept for them and the keep reading of the
    background matches (``tables``: the record's pairs and per-match arrays)."""
    if not cfg.signals.enabled:
        return None
    start = time.perf_counter()
    n = video.num_frames
    far, near = plan_pairs(n, cfg.signals)
    readable = all(t in frames for pair in (*far, *near) for t in pair) and bool(far or near)
    appearance = appearance_reading(frames, n, cfg.signals) if readable else None
    pairs, matches = tables
    offsets = matches.offsets
    rows = [(p.gap, p.scale, int(offsets[p.index]), int(offsets[p.index + 1])) for p in pairs if p.skip is None]
    unkept = unkept_share(rows, matches.f_res_px, video.working_size[0], cfg.signals)
    timer.add("signals", start)
    return ClipReadings(appearance, unkept)
