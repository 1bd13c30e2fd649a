"""The stages a clip runs through while it streams (:class:`Pipeline`): masks, features, pair
fits, object rigidity and poses, each seeded from the config seed and the pair's identity, run by
:func:`~geocon_core.scoring.scorer.score_clip` under the schedule of
:mod:`geocon_core.scoring.schedule`; and what the composition needs of them afterwards: the
deferred chain poses (:func:`resolve_deferred`), the still-camera rule (:func:`keep_still`) and the
per-stage timer (:class:`Timer`)."""

from __future__ import annotations

import contextlib
import math
import threading
import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import replace
from functools import partial
from typing import Any, Callable, Sequence

import cv2
import numpy as np

from ..config import ScoreConfig
from ..flow import FlowBackend, chained_flow
from ..geometry import (
    FAMILIES,
    FeatureSet,
    Matcher,
    ModelFit,
    PairFits,
    gross_mismatches,
    independent_motion,
    scale_intrinsics,
    scaled_inputs,
    two_view_cloud,
    with_independent,
)
from ..masks import MaskSource
from ..media import ClipInfo, Frame
from ..pose import (
    PoseBackend,
    PoseEstimate,
    focal_of,
    still_pose,
    still_share,
)
from ..reconstruction import (
    DenseCloudBuilder,
    LongTracks,
)
from ..record import FrameDiagnostics, ObjectFlow, PointCloud, PointMaps
from ..regions import RegionTracker
from ..signals import content_gray, plan_pairs
from .rigidity import ObjectPairScore, adadfrc_pair, mask_interior, refine_object_mask

__all__ = [
    "LARGE_PASS_PIXELS",
    "DeferredPose",
    "Pipeline",
    "SharedMatches",
    "Timer",
    "keep_still",
    "pair_seed",
    "resolve_deferred",
]


LARGE_PASS_PIXELS = 500_000
"""A feature pass on an image of this many pixels or more waits for any other such pass of the
clip to end (one at a time: their buffers are the scorer's largest); smaller passes run freely."""


def pair_seed(seed: int, t0: int, t1: int, scale_index: int) -> int:
    return int(np.random.SeedSequence([seed, t0, t1, scale_index]).generate_state(1)[0])


class Timer:
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


class SharedMatches:
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


class DeferredPose:
    """A chain hop's pose, estimated only when asked for (:meth:`result`): the hops of a clip or a
    shot stand in for its first-last pose only when that pose fails, so most clips never need
    them. The matches are kept (float32, as the features hold them; converted back exactly) with
    the pair's seed, so the estimate is the one made at once."""

    def __init__(self, backend: PoseBackend, x0: np.ndarray, x1: np.ndarray, K: np.ndarray, seed: int) -> None:
        self.backend, self.K, self.seed = backend, K, seed
        self.x0, self.x1 = x0.astype(np.float32), x1.astype(np.float32)

    def result(self) -> PoseEstimate:
        return self.backend.estimate(self.x0.astype(np.float64), self.x1.astype(np.float64), self.K, seed=self.seed)


def resolve_deferred(
    by_window: dict[tuple[int, int], Any], keys: Sequence[tuple[int, int]], workers: int, timer: Timer
) -> None:
    """Estimate the deferred poses among ``keys`` of ``by_window`` (in place), ``workers`` at a time."""
    todo = [k for k in keys if isinstance(by_window.get(k), DeferredPose)]
    if not todo:
        return
    start = time.perf_counter()
    with ThreadPoolExecutor(max_workers=workers) as pool:
        for k, est in zip(todo, pool.map(lambda k: by_window[k].result(), todo), strict=True):
            by_window[k] = est
    timer.add("pose", start)


class Pipeline:
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
        timer: Timer,
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
        self.regions = (
            RegionTracker(config.regions, info.num_frames, info.working_size) if config.regions.enabled else None
        )
        """The region readings' tracks over the whole frame, movers included (:mod:`geocon_core.regions`)."""
        self.reading_frames: dict[int, np.ndarray] = {}
        """The frames the appearance readings use, on their canvas (:mod:`geocon_core.signals`)."""
        self.reading_needed: frozenset[int] = frozenset()
        if config.signals.enabled:
            far, near = plan_pairs(info.num_frames, config.signals)
            self.reading_needed = frozenset(t for pair in (*far, *near) for t in pair)
        self.shared = SharedMatches(set())
        """Matches two stages need alike (set by :func:`score_clip` once the pose windows are known)."""
        self.object_scales = (self.s_max,) if config.object_scales == "top" else tuple(config.scales)
        """The scales objects are scored at (``ScoreConfig.object_scales``)."""
        self.deferred: frozenset[tuple[int, int]] = frozenset()
        """Pose windows whose estimate waits until asked for (chain hops: :class:`DeferredPose`)."""

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
        if self.regions is not None:
            start = time.perf_counter()
            self.regions.observe(frame.index, frame.gray, frame.content, labels)
            self.timer.add("regions", start)

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
            seed = pair_seed(cfg.seed, t0, t1, si)
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
        seed = pair_seed(self.config.seed, t0, t1, 99)
        if first is None and (t0, t1) in self.deferred:
            self.timer.add("pose", start)
            return DeferredPose(self.backend, x0, x1, self.K_pose, seed)
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


def keep_still(
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
