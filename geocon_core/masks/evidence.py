"""Motion evidence of the built-in segmentation: per frame pair, dense flow in both directions,
a robust background model per direction and the residual of every reduced pixel against it
(steps 1-3 of :class:`~geocon_core.masks.MotionSegmenter`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..config import MotionConfig
from ..flow import FlowBackend, FlowField
from ..geometry import (
    apply_homography,
    cheirality_pose,
    epipolar_line_distance,
    fit_fundamental,
    fit_homography,
    in_front_least_squares,
    intrinsics_from_fov,
)

__all__ = ["Side", "Evidence"]


@dataclass
class Side:
    """Motion evidence of one frame from one pair: residual / threshold per reduced pixel, the
    flow to the other frame, and the model that explained the background."""

    score: np.ndarray
    flow: np.ndarray
    reliable: np.ndarray
    direction: int  # +1: flow to a later frame, -1: to an earlier one
    regime: str  # "H", "F" or "static"
    threshold: float  # px at the reduced scale


class Evidence:
    """Evidence of frame pairs on a reduced (rw x rh) canvas; ``s`` converts the pixel settings
    to reduced px (``MotionConfig.px_reference``), ``seed`` is the clip's seed (each direction of
    each pair gets its own)."""

    def __init__(self, config: MotionConfig, flow: FlowBackend, seed: int, rw: int, rh: int, s: float) -> None:
        self.config, self.flow, self.seed = config, flow, seed
        self._rw, self._rh, self._s = rw, rh, s
        self._K = intrinsics_from_fov(rw, rh, config.fov_deg)
        self._Kinv = np.linalg.inv(self._K)
        self._gxy: tuple[np.ndarray, np.ndarray] | None = None

    def pair(self, g0: np.ndarray, g1: np.ndarray, t0: int, t1: int) -> tuple[Side | None, Side | None]:
        """Forward evidence of frame t0 and backward evidence of frame t1 (None where the
        background cannot be modelled)."""
        both = getattr(self.flow, "compute_both", None)
        if both is not None:
            fwd, bwd = both(g0, g1)
        else:
            fwd, bwd = self.flow.compute(g0, g1), self.flow.compute(g1, g0)
        f = self.side(fwd, +1, self.seed * 7919 + 2 * t0)
        b = self.side(bwd, -1, self.seed * 7919 + 2 * t1 + 1)
        return f, b

    def slow(self, g1: np.ndarray, g0: np.ndarray, t1: int) -> Side | None:
        """Backward evidence of frame t1 (grey ``g1``) against an earlier frame ``g0``."""
        both = getattr(self.flow, "compute_both", None)
        bwd = both(g1, g0)[0] if both is not None else self.flow.compute(g1, g0)
        return self.side(bwd, -1, self.seed * 7919 + 2 * t1 + 1)

    def side(self, field: FlowField, direction: int, seed: int) -> Side | None:
        cfg = self.config
        flow, rel = field.flow, field.reliable
        h, w = rel.shape
        st = cfg.fit_step
        ys, xs = np.mgrid[st // 2 : h : st, st // 2 : w : st]
        ok = rel[ys, xs]
        if np.count_nonzero(ok) < cfg.fit_min_inliers:
            return None
        p1 = np.stack([xs[ok], ys[ok]], axis=1).astype(np.float64)
        p2 = p1 + flow[ys[ok], xs[ok]].astype(np.float64)
        tau = cfg.fit_tau_px * self._s
        seed &= 0x7FFFFFFF
        fh = fit_homography(p1, p2, tau=tau, min_inliers=cfg.fit_min_inliers, seed=seed, iters=cfg.fit_iters)
        if fh.model is None or not fh.valid:
            return None
        Hm = fh.model
        n = p1.shape[0]
        n_h = fh.n_inliers
        # where the data are: extrapolated corners are noisy
        moved = apply_homography(Hm, p1, at_infinity=np.inf) - p1
        static = bool(np.percentile(np.hypot(moved[:, 0], moved[:, 1]), 95) <= cfg.static_px * self._s)
        regime = "static" if static else "H"
        Fm = None
        if not static and n - n_h >= cfg.f_gain * n:
            sub = slice(None, None, max(1, n // cfg.f_fit_points))  # every k-th vector: F fits are costly
            ff = fit_fundamental(
                p1[sub],
                p2[sub],
                tau=cfg.f_fit_tau,
                min_inliers=cfg.fit_min_inliers,
                iters=cfg.fit_iters,
                proposal_px=tau,
            )
            if ff.model is not None:
                d = epipolar_line_distance(ff.model, p1, p2)
                n_f = int(np.count_nonzero(d <= tau))
                if n_f - n_h >= max(cfg.f_gain * n, 0.5 * (n - n_h)):
                    Fm, regime = ff.model, "F"
        gx, gy = self.grid()
        x2, y2 = gx + flow[..., 0], gy + flow[..., 1]
        M = (Fm if Fm is not None else Hm).astype(np.float32)
        a = M[0, 0] * gx + M[0, 1] * gy + M[0, 2]
        b = M[1, 0] * gx + M[1, 1] * gy + M[1, 2]
        c = M[2, 0] * gx + M[2, 1] * gy + M[2, 2]
        # per-pixel maps in float32 (memory); the same formulas as the geometry functions used on the grid
        if Fm is not None:  # distance of x2 to the epipolar line (a, b, c) = F x1
            res = np.abs(a * x2 + b * y2 + c) / np.maximum(np.sqrt(a * a + b * b), np.float32(1e-12))
            grid = epipolar_line_distance(Fm, p1, p2)
            inl = grid <= tau
            wrong = self.wrong_way(Fm, p1[inl], p2[inl], x2, y2)
            if wrong is not None:
                res = np.maximum(res, wrong)
            if cfg.parallax_share > 0:  # flow errors grow with the displacement: discount the parallax
                h = Hm.astype(np.float32)
                hc = h[2, 0] * gx + h[2, 1] * gy + h[2, 2]
                hx = (h[0, 0] * gx + h[0, 1] * gy + h[0, 2]) / hc
                hy = (h[1, 0] * gx + h[1, 1] * gy + h[1, 2]) / hc
                parallax = np.hypot(x2 - hx, y2 - hy)
                res = np.maximum(res - np.float32(cfg.parallax_share) * parallax, np.float32(0.0))
        else:  # transfer error |x2 - H x1|
            res = np.hypot(x2 - a / c, y2 - b / c)
            grid = np.hypot(*(p2 - apply_homography(Hm, p1, at_infinity=np.inf)).T)
        sigma = 1.4826 * float(np.median(grid))
        thr = max(cfg.k_sigma * sigma, cfg.min_px * self._s)
        score = (res * np.float32(1.0 / thr)).astype(np.float32)
        return Side(score=score, flow=flow, reliable=rel, direction=direction, regime=regime, threshold=thr)

    def wrong_way(
        self, Fm: np.ndarray, p1: np.ndarray, p2: np.ndarray, x2: np.ndarray, y2: np.ndarray
    ) -> np.ndarray | None:
        """Parallax against cheirality (px, (h, w)), or None when the pose is ambiguous.

        The epipolar distance cannot see motion along the epipolar lines, e.g. an object
        moving against the flow of a translating camera. With the default intrinsics ``K``
        (``fov_deg`` horizontal field of view over the content, principal point at its
        centre), ``E = K^T F K`` is decomposed into the (R, t) that puts most grid vectors
        (``p1 -> p2``, the fundamental matrix's inliers) in front of both cameras. A static
        point at depth Z then maps to ``x2 ~ Z a + e`` with ``a = K R K^-1 x1`` and ``e = K t``:
        its parallax from the point at infinity ``a`` points along ``e_xy - e_z a``
        (normalised ``a``), never against it. The component against it is returned."""
        K, Kinv = self._K, self._Kinv
        n1 = np.c_[p1, np.ones(len(p1))] @ Kinv.T
        n2 = np.c_[p2, np.ones(len(p2))] @ Kinv.T
        best = cheirality_pose(K.T @ Fm @ K, lambda R, t: in_front_least_squares(n1, n2, R, t))
        if best is None or int(np.count_nonzero(best[2])) < self.config.cheirality_min_share * len(p1):
            return None
        R, t, _ = best
        Hinf = (K @ R @ Kinv).astype(np.float32)
        e = (K @ t).astype(np.float32)
        gx, gy = self.grid()
        c = Hinf[2, 0] * gx + Hinf[2, 1] * gy + Hinf[2, 2]
        ax = (Hinf[0, 0] * gx + Hinf[0, 1] * gy + Hinf[0, 2]) / c
        ay = (Hinf[1, 0] * gx + Hinf[1, 1] * gy + Hinf[1, 2]) / c
        dx, dy = e[0] - e[2] * ax, e[1] - e[2] * ay
        along = ((x2 - ax) * dx + (y2 - ay) * dy) / np.maximum(np.sqrt(dx * dx + dy * dy), np.float32(1e-12))
        return np.maximum(-along, np.float32(0.0))

    def grid(self) -> tuple[np.ndarray, np.ndarray]:
        """Pixel coordinates (x, y) of the reduced canvas, float32 (rh, rw) each."""
        if self._gxy is None:
            gx, gy = np.meshgrid(np.arange(self._rw, dtype=np.float32), np.arange(self._rh, dtype=np.float32))
            self._gxy = (gx, gy)
        return self._gxy
