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
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Protocol

import numpy as np

from ._version import __version__
from .config import ScoreConfig, config_hash
from .features import FeatureSet, Matcher, make_matcher, scaled_inputs
from .gate import gate_decision
from .geometry import scale_intrinsics
from .models import ModelFit, fit_fundamental, fit_homography
from .pose import PoseBackend, PoseEstimate, default_intrinsics, load_pose_log, make_pose_backend
from .reader import ClipInfo, Frame, iter_frames, probe_clip
from .record import (
    BackgroundSummary,
    ClipRecord,
    FamilySummary,
    FitSummary,
    GapSummary,
    GateRecord,
    GateWindow,
    MatchArrays,
    PairRecord,
    ScaleSummary,
)

__all__ = ["score_clip", "BackgroundMasks", "software_versions"]


class BackgroundMasks(Protocol):
    """Hook for mask-first separation: the background mask ``B_t`` (H, W) bool at working
    resolution, or None to use the whole content."""

    def background(self, t: int) -> np.ndarray | None: ...


def software_versions() -> dict[str, str]:
    import cv2

    versions = {"geocon": __version__, "python": platform.python_version(), "numpy": np.__version__, "opencv": cv2.__version__}
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
        valid=fit.valid, reason=fit.reason, ir=fit.ir, ge=fit.ge, n_inliers=fit.n_inliers,
        tau=fit.tau, tau_px=fit.tau_px, model=model,
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
    def __init__(self, info: ClipInfo, config: ScoreConfig, matcher: Matcher, masks: BackgroundMasks | None, timer: _Timer) -> None:
        self.info, self.config, self.matcher, self.masks, self.timer = info, config, matcher, masks, timer
        self.s_max = max(config.scales)

    def extract(self, frame: Frame) -> dict[float, FeatureSet]:
        start = time.perf_counter()
        mask = frame.content
        if self.masks is not None:
            bg = self.masks.background(frame.index)
            if bg is not None:
                mask = mask & bg
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
            kw = dict(min_inliers=cfg.min_inliers, seed=seed, iters=cfg.ransac_iters, confidence=cfg.ransac_confidence)
            h = fit_homography(x1, x2, tau=cfg.tau_h, **kw)
            f = fit_fundamental(x1, x2, tau=cfg.tau_f, **kw)
            self.timer.add("model_fitting", start)
            results.append(_Scored(t0, t1, gap, s, None, x1, x2, h, f))
        return results

    def pose(self, fa: Future, fb: Future, backend: PoseBackend, K: np.ndarray, t0: int, t1: int) -> PoseEstimate:
        a, b = fa.result()[self.s_max], fb.result()[self.s_max]
        start = time.perf_counter()
        x0, x1 = self.matcher.match(a, b)
        est = backend.estimate(x0, x1, K, seed=_pair_seed(self.config.seed, t0, t1, 99))
        self.timer.add("pose", start)
        return est


def _windows(n: int, window: int, stride: int) -> list[tuple[int, int]]:
    if n - 1 <= window:
        return [(0, n - 1)]
    return [(s, s + window) for s in range(0, n - 1 - window + 1, stride)]


def score_clip(
    path: str | Path,
    config: ScoreConfig | None = None,
    *,
    pose_log: str | Path | None = None,
    masks: BackgroundMasks | None = None,
    workers: int | None = None,
    progress: Callable[[int, int], None] | None = None,
    timings: dict[str, float] | None = None,
) -> ClipRecord:
    """Score one clip. ``pose_log`` replaces the pose backend by an external pose (JSON, see
    :mod:`geocon_core.pose`); ``progress(done, total)`` is called as frames are processed;
    ``timings``, if given, receives seconds per stage (summed over worker threads).
    Raises :class:`~geocon_core.reader.ClipError` for unusable input."""
    cfg = config or ScoreConfig()
    timer = _Timer(timings)
    start = time.perf_counter()
    info = probe_clip(path, cfg)
    start = timer.add("probe", start)
    matcher = make_matcher(cfg.matcher, max_features=cfg.max_features, ratio=cfg.ratio)
    backend: PoseBackend = load_pose_log(pose_log) if pose_log is not None else make_pose_backend(cfg.pose_backend)
    K = default_intrinsics(info.content_box, cfg.fov_x_deg)
    K_pose = scale_intrinsics(K, max(cfg.scales))
    n = info.num_frames
    windows = _windows(n, cfg.gate_window, cfg.gate_stride)
    window_ends: dict[int, list[tuple[int, int]]] = {}
    for w in windows:
        window_ends.setdefault(w[1], []).append(w)
    anchors = {0} | {w[0] for w in windows}
    max_gap = max(cfg.gaps)

    workers = workers or min(2, os.cpu_count() or 1)
    feats: dict[int, Future] = {}
    inflight: deque[Future] = deque()
    pair_futures: list[Future] = []
    skipped: list[_Scored] = []
    window_futures: list[tuple[tuple[int, int], Future]] = []
    first_last: Future | None = None
    with ThreadPoolExecutor(max_workers=workers) as pool:
        pipe = _Pipeline(info, cfg, matcher, masks, timer)
        frames = iter_frames(info)
        while True:
            start = time.perf_counter()
            frame = next(frames, None)
            timer.add("decode", start)
            if frame is None:
                break
            t = frame.index
            # bounded read-ahead: a few frames wait for features, a few pairs for fitting
            while len(inflight) > workers:
                inflight.popleft().result()
            while sum(not f.done() for f in pair_futures[-4 * workers :]) >= 2 * workers:
                next(f for f in pair_futures if not f.done()).result()
            feats[t] = pool.submit(pipe.extract, frame)
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
            for w in window_ends.get(t, []):
                if pose_log is None and w != (0, n - 1):
                    window_futures.append((w, pool.submit(pipe.pose, feats[w[0]], feats[t], backend, K_pose, w[0], t)))
            if t == n - 1:
                first_last = pool.submit(pipe.pose, feats[0], feats[t], backend, K_pose, 0, t)
            for old in [k for k in feats if k < t - max_gap and k not in anchors]:
                del feats[old]
            for a in [k for k in anchors if k in feats and all(e < t for s, e in windows if s == k) and k != 0]:
                del feats[a]
            if progress is not None:
                progress(t + 1, n)
        assert first_last is not None
        pose = first_last.result()
        scored = [r for f in pair_futures for r in f.result()] + skipped
        timeline_poses = [(w, f.result()) for w, f in window_futures]

    scored.sort(key=lambda r: (r.gap, r.t0, r.scale))
    return _assemble(str(path), info, cfg, K, backend, pose, timeline_poses, windows, scored)


def _aggregate(family: str, scored: list[_Scored], cfg: ScoreConfig) -> FamilySummary:
    def fit_of(r: _Scored) -> ModelFit | None:
        return r.h if family == "H" else r.f

    def valid_fits(rows: list[_Scored]) -> list[ModelFit]:
        return [fit_of(r) for r in rows if r.skip is None and fit_of(r).valid]

    def med(values: list[float]) -> float | None:
        return float(np.median(values)) if values else None

    reasons: dict[str, int] = {}
    per_gap = []
    for gap in cfg.gaps:
        rows = [r for r in scored if r.gap == gap]
        valid = valid_fits(rows)
        if cfg.aggregation == "median":
            ir, ge = med([f.ir for f in valid]), med([f.ge for f in valid])
        else:  # worst scale of this gap, each scale a median over pairs
            cells = [valid_fits([r for r in rows if r.scale == s]) for s in cfg.scales]
            irs = [m for m in (med([f.ir for f in c]) for c in cells) if m is not None]
            ges = [m for m in (med([f.ge for f in c]) for c in cells) if m is not None]
            ir, ge = (min(irs) if irs else None), (max(ges) if ges else None)
        per_gap.append(GapSummary(gap=gap, ir=ir, ge=ge, valid_pairs=len(valid), total_pairs=len(rows)))
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
    irs = [g.ir for g in per_gap if g.ir is not None]
    ges = [g.ge for g in per_gap if g.ge is not None]
    return FamilySummary(
        family=family,  # type: ignore[arg-type]
        ir=min(irs) if irs else None,
        ge=max(ges) if ges else None,
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
    if label == "U":
        ir_h = -1.0 if fam["H"].ir is None else fam["H"].ir
        ir_f = -1.0 if fam["F"].ir is None else fam["F"].ir
        model = "H" if ir_h >= ir_f else "F"
        note = f"gray zone: both families fitted, kept {model} (IR H {fam['H'].ir}, IR F {fam['F'].ir})"
    elif not pose.pose_present:
        model = "F"
        note = f"no pose ({pose.reason}): gated F by the fail->F policy"
        warnings.append(f"the first-last pose could not be recovered ({pose.reason}); the clip is gated F")
    else:
        model = label
        note = f"t_inf {pose.t_inf:.4f} -> {label}"
    chosen, other = fam[model], fam["F" if model == "H" else "H"]
    consistent = None if chosen.ir is None else bool(chosen.ir >= cfg.ir_gate and chosen.ge <= cfg.ge_gate)
    if chosen.valid_pairs == 0:
        warnings.append("no valid pair: the background could not be judged")
    tau_f_px = fam["F"].per_scale[list(cfg.scales).index(max(cfg.scales))].tau_f_px
    background = BackgroundSummary(
        model=model, ir=chosen.ir, ge=chosen.ge, valid_pairs=chosen.valid_pairs, total_pairs=chosen.total_pairs,
        consistent=consistent, tau_f_px=tau_f_px, chosen=chosen, other=other, choice_note=note,
    )
    timeline = []
    for (s, e), est in timeline_poses:
        wl = gate_decision(est.t_inf, pose_present=est.pose_present, tau_t=cfg.tau_t, low=cfg.tau_t_low, high=cfg.tau_t_high)[0] if est.pose_present else None
        timeline.append(GateWindow(start=s, end=e, t_inf=est.t_inf, label=wl, pose_present=est.pose_present))
    if (0, info.num_frames - 1) in windows:
        timeline.append(GateWindow(0, info.num_frames - 1, pose.t_inf, label if pose.pose_present else None, pose.pose_present))
    gate = GateRecord(
        label=label, binary_label=binary, model=model, t_inf=pose.t_inf, pose_present=pose.pose_present, margin=margin,
        backend=backend.name, thresholds={"tau_t": cfg.tau_t, "low": cfg.tau_t_low, "high": cfg.tau_t_high},
        pose=pose.to_dict(), timeline=tuple(timeline),
    )
    pairs, arrays = [], []
    for i, r in enumerate(scored):
        pairs.append(
            PairRecord(
                index=i, t0=r.t0, t1=r.t1, gap=r.gap, scale=r.scale, n_matches=len(r.x1), skip=r.skip,
                h=None if r.h is None else _fit_summary(r.h), f=None if r.f is None else _fit_summary(r.f),
            )
        )
        m = len(r.x1)
        z32, zb = np.zeros(m, np.float32), np.zeros(m, bool)
        arrays.append({
            "x1": r.x1, "x2": r.x2,
            "h_res": z32 if r.h is None else r.h.residuals, "f_res": z32 if r.f is None else r.f.residuals,
            "f_res_px": z32 if r.f is None else r.f.residuals_px,
            "h_inl": zb if r.h is None else r.h.inliers, "f_inl": zb if r.f is None else r.f.inliers,
        })
    if info.duplicates:
        warnings.append(f"{len(info.duplicates)} duplicated frame(s): pairs across them are not scored")
    if info.cuts:
        warnings.append(f"{len(info.cuts)} hard cut(s) at frame(s) {list(info.cuts)}: pairs across them are not scored")
    return ClipRecord(
        clip=clip, video=info.to_dict(), config=cfg, config_hash=config_hash(cfg), versions=software_versions(),
        gate=gate, background=background, pairs=tuple(pairs), matches=MatchArrays.concatenate(arrays),
        intrinsics=[[float(v) for v in row] for row in K], category=None, warnings=tuple(warnings),
    )
