"""The reward's reading: short windows of fresh tracks, each against one background model.

A failure a generator makes (a region that slides, melts, breathes or is redrawn) grows over
several frames, while a real scene seen over a short stretch of the clip is one camera motion:
corners seeded on frame ``a`` and tracked to frame ``a + window`` (pyramidal Lucas-Kanade, frame
to frame, each step checked forward and backward) fit one homography when the camera turns, or
one fundamental matrix when the gate found it moving, up to the corners' own noise. Each window's
reading is the mean over its tracks of the soft share ``1 / (1 + (r / soft_px)^2)``, ``r`` the
track's residual to the window's robust fit (transfer error for H, Sampson distance for F, px of
the canvas). A window spans several frame steps, so damage that adds a fraction of a pixel per
step reaches the residual whole, and seeding anew at every window keeps tracks on content the
camera still sees. Every track counts, movers included: a reward must not let a failure pass
as a moving object.

By default each window is read under both models and the two shares are averaged. A fundamental
matrix fits any rigid scene, a moving camera's parallax included, but absorbs damage that moves
content along its epipolar lines; a homography sees that damage and also charges a moving
camera's parallax. Reading one model per clip, as the translation gate chooses it, lets a planted
failure tip the gate to F and buy the absorption; the mean does not flip, and charges half the
parallax. Known bias: within a group of clips, one whose camera translates fast past near
content reads a little lower than one that turns, and movers count against their clip.

Measured on the stick's tune half against the per-pair reading of the ``reward`` preset's
record (docs/training.md): the clean twin is preferred more often for breathing, morph and slide
and as often for redraw; on the check half the two readings lie within each other's intervals.
"""

from __future__ import annotations

import cv2
import numpy as np

from ..config import RewardConfig
from ..geometry import sampson_distance
from .guards import scaled_grey

__all__ = ["canvas_greys", "window_values"]


def canvas_greys(frames: np.ndarray, canvas: tuple[int, int]) -> list[np.ndarray]:
    """The grey frames on the reward's canvas: scaled (area filter) to fit ``canvas`` (w, h),
    never enlarged."""
    h, w = frames.shape[1:3]
    s = min(1.0, canvas[0] / w, canvas[1] / h) if w >= h else min(1.0, canvas[0] / h, canvas[1] / w)
    return [scaled_grey(bgr, s) for bgr in frames]


def _track(greys: list[np.ndarray], cfg: RewardConfig) -> tuple[np.ndarray, np.ndarray] | None:
    """Corners of ``greys[0]`` and where they are in ``greys[-1]``, the tracks that survived every
    forward-backward check; None without corners."""
    seeds = cv2.goodFeaturesToTrack(greys[0], cfg.window_corners, cfg.window_quality, cfg.window_spacing)
    if seeds is None:
        return None
    start = seeds.reshape(-1, 1, 2).astype(np.float32)
    lk = {
        "winSize": (cfg.window_lk_side, cfg.window_lk_side),
        "maxLevel": cfg.window_lk_levels,
        "criteria": (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01),
    }
    pts, alive = start.copy(), np.ones(len(start), bool)
    for prev, cur in zip(greys, greys[1:], strict=False):
        nxt, st, _ = cv2.calcOpticalFlowPyrLK(prev, cur, pts, None, **lk)  # type: ignore[call-overload]
        back, st2, _ = cv2.calcOpticalFlowPyrLK(cur, prev, nxt, None, **lk)  # type: ignore[call-overload]
        fb = np.linalg.norm((back - pts).reshape(-1, 2), axis=1)
        alive &= (st.ravel() == 1) & (st2.ravel() == 1) & (fb < cfg.window_fb_px)
        pts = nxt
    return start.reshape(-1, 2)[alive].astype(np.float64), pts.reshape(-1, 2)[alive].astype(np.float64)


def _residuals(a: np.ndarray, b: np.ndarray, family: str, cfg: RewardConfig) -> np.ndarray | None:
    """Each track's residual to the window's robust fit of ``family``; None when no model fits."""
    try:  # OpenCV's USAC asserts on some degenerate sets instead of returning no model
        if family == "H":
            H, _ = cv2.findHomography(a, b, cv2.USAC_MAGSAC, cfg.window_fit_px)
            if H is None:
                return None
            return np.asarray(np.linalg.norm(cv2.perspectiveTransform(a[None], H)[0] - b, axis=1))
        F, _ = cv2.findFundamentalMat(a, b, cv2.USAC_MAGSAC, cfg.window_fit_px, 0.999)
    except cv2.error:
        return None
    if F is None or F.shape != (3, 3):
        return None
    return np.asarray(sampson_distance(F, a, b))


def _share(r: np.ndarray, soft_px: float) -> float:
    r = r[np.isfinite(r)]
    return float(np.mean(1.0 / (1.0 + (r / soft_px) ** 2))) if len(r) else float("nan")


def window_values(frames: np.ndarray, family: str, cfg: RewardConfig) -> np.ndarray:
    """The reading of every window of a clip's sampled BGR ``frames`` ((T, h, w, 3) uint8):
    windows of ``cfg.window`` frame steps, one starting every ``cfg.window_step`` frames, read
    under ``cfg.window_models`` (``gate``: the background's ``family``, "H" or "F"); a window
    with fewer than ``cfg.window_min_tracks`` tracks or a model that does not fit is left out.
    Deterministic (OpenCV's generator seeded with ``cfg.seed``)."""
    if family not in ("H", "F"):
        raise ValueError(f"family must be 'H' or 'F', got {family!r}")
    models = {"both": ("H", "F"), "H": ("H",), "F": ("F",), "gate": (family,)}[cfg.window_models]
    cv2.setRNGSeed(cfg.seed)
    greys = canvas_greys(frames, cfg.canvas)
    values = []
    for a0 in range(0, len(greys) - cfg.window, cfg.window_step):
        tracked = _track(greys[a0 : a0 + cfg.window + 1], cfg)
        if tracked is None or len(tracked[0]) < cfg.window_min_tracks:
            continue
        shares = []
        for model in models:
            r = _residuals(*tracked, model, cfg)
            shares.append(float("nan") if r is None else _share(r, cfg.soft_px))
        if np.isfinite(shares).all():
            values.append(float(np.mean(shares)))
    return np.asarray(values, dtype=np.float64)
