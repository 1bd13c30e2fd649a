"""Guards against reward hacking: what a clip must show before its geometry can be rewarded.

A frozen clip, a nearly static one, a slideshow of repeated frames, a blurred or textureless one
fits any geometry perfectly, so a geometric reward alone would prefer it to every honest clip
of its prompt. Each guard reads a physical quantity on a small grey copy of the frames, with its
threshold in :class:`~geocon_core.config.RewardConfig`; a clip that trips one "cannot judge"
and carries the guard's name and its measured value.

- ``motion``: corners tracked from the first frame (pyramidal Lucas-Kanade, frame to frame); the
  90th percentile of their displacement from the first frame at its largest over the clip, in
  px of the 854-px canvas. Movers count: a still camera filming a walker moves enough.
- ``repeated``: the share of frame steps that repeat the frame before (the probe's duplicates).
- ``texture``: corners on the first frame.
- ``sharpness``: the median over the frames of the variance of the Laplacian.
- ``cut``: a hard cut or a cross-fade (the probe's cuts).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..config import RewardConfig
from ..media import ClipInfo

__all__ = ["GUARD_NAMES", "GuardReading", "read_guards", "guard_image", "REWARD_CANVAS_SIDE"]

GUARD_NAMES = ("motion", "repeated", "texture", "sharpness", "cut")
"""The guards, in the order they are checked (the first that trips names the reason)."""
REWARD_CANVAS_SIDE = 854
"""Long side of the canvas the motion guard's pixels refer to (the ``reward`` preset's)."""


@dataclass(frozen=True)
class GuardReading:
    """The guards' measurements of one clip, and the first that tripped (None: every guard passed)."""

    motion_px: float
    repeated_share: float
    corners: int
    sharpness: float
    cuts: int
    tripped: str | None
    reason: str | None

    def to_dict(self) -> dict[str, object]:
        return {
            "motion_px": round(self.motion_px, 3),
            "repeated_share": round(self.repeated_share, 4),
            "corners": self.corners,
            "sharpness": round(self.sharpness, 2),
            "cuts": self.cuts,
            "tripped": self.tripped,
        }


def scaled_grey(bgr: np.ndarray, s: float) -> np.ndarray:
    """The frame in grey, scaled by ``s`` (area filter) when ``s`` < 1; never enlarged."""
    h, w = bgr.shape[:2]
    grey = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    if s < 1.0:
        grey = cv2.resize(grey, (max(1, round(w * s)), max(1, round(h * s))), interpolation=cv2.INTER_AREA)
    return grey


def guard_image(bgr: np.ndarray, side: int) -> tuple[np.ndarray, float]:
    """The grey image the guards read (long side at most ``side``) and its scale from the frame."""
    s = min(1.0, side / max(bgr.shape[:2]))
    return scaled_grey(bgr, s), s


def _motion(greys: list[np.ndarray], corners: np.ndarray | None) -> float:
    """The 90th percentile of the corners' displacement from the first frame, at its largest (px
    of the guard image); tracks lost on the way stop counting."""
    if corners is None or len(corners) == 0:
        return 0.0
    start = corners.reshape(-1, 1, 2).astype(np.float32)
    pts, alive, largest = start.copy(), np.ones(len(start), bool), 0.0
    for prev, cur in zip(greys, greys[1:], strict=False):
        nxt, status, _ = cv2.calcOpticalFlowPyrLK(  # type: ignore[call-overload]
            prev, cur, pts, None, winSize=(15, 15), maxLevel=3
        )
        if nxt is None:
            break
        alive &= status.ravel() == 1
        if not alive.any():
            break
        pts = nxt
        d = np.linalg.norm((pts - start).reshape(-1, 2)[alive], axis=1)
        largest = max(largest, float(np.percentile(d, 90)))
    return largest


def read_guards(frames: np.ndarray, info: ClipInfo, cfg: RewardConfig) -> GuardReading:
    """The guards on a clip's BGR ``frames`` ((T, h, w, 3) uint8, as scored) and the probe ``info``
    of the whole clip before sampling (its repeated frames and cuts)."""
    greys, s = [], 1.0
    for bgr in frames:
        grey, s = guard_image(bgr, cfg.guard_side)
        greys.append(grey)
    corners = cv2.goodFeaturesToTrack(greys[0], 400, cfg.corner_quality, 7)
    n_corners = 0 if corners is None else len(corners)
    to_canvas = REWARD_CANVAS_SIDE / (max(frames.shape[1:3]) * s)
    motion = _motion(greys, corners) * to_canvas
    repeated = len(info.duplicates) / max(1, info.num_frames - 1)
    sharp = float(np.median([cv2.Laplacian(g, cv2.CV_64F).var() for g in greys[:: max(1, len(greys) // 8)]]))
    cuts = len(info.cuts)
    checks = (
        (
            "motion",
            motion < cfg.min_motion_px,
            f"too little motion to judge: the tracked corners move {motion:.2f} px at most (90th percentile), "
            f"under {cfg.min_motion_px:g} px; a frozen or nearly static clip fits any geometry",
        ),
        (
            "repeated",
            repeated > cfg.max_repeated_share,
            f"repeated frames: {repeated:.0%} of the frame steps repeat the frame before (a slideshow or a slowed "
            f"copy), above {cfg.max_repeated_share:.0%}",
        ),
        (
            "texture",
            n_corners < cfg.min_corners,
            f"too little texture: {n_corners} corners on the first frame, under {cfg.min_corners}",
        ),
        (
            "sharpness",
            sharp < cfg.min_sharpness,
            f"too blurred: the Laplacian's variance is {sharp:.1f}, under {cfg.min_sharpness:g}",
        ),
        (
            "cut",
            cuts > 0 and not cfg.judge_cuts,
            f"{cuts} hard cut{'s' if cuts != 1 else ''} or fade{'s' if cuts != 1 else ''}: a cut makes two scenes",
        ),
    )
    tripped = next(((name, why) for name, bad, why in checks if bad), None)
    return GuardReading(
        motion,
        repeated,
        n_corners,
        sharp,
        cuts,
        None if tripped is None else tripped[0],
        None if tripped is None else tripped[1],
    )
