"""A still camera, told from the dense motion between a clip's first and last frame.

The classical pose backend reads the camera from sparse matches, and matches cluster where the
texture is: in front of a still camera, a person, a pair of hands or a guitar can hold most of
them while the wall behind holds few. The matches that moved (the mover) then outvote the still
ones, and an essential matrix with a translation explains both: a still camera gated F, whose
fundamental matrix absorbs the movers too. Dense optical flow weighs the image by area instead:
between the first and last frame of a still camera a large share of the content does not move
at all, while on every moving camera of the validation footage (walk-throughs, drones, vehicles,
handheld phones, pans) less than 3 % of it stays within a pixel. :func:`still_share` measures that
share (object masks left out); :func:`still_pose` is the gate's pose when it is large enough, and
the still pixels are the background the scorer judges: what moved between the first and last
frame of a still camera is a mover, whether or not the motion segmentation saw it.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .base import PoseEstimate

__all__ = ["StillTest", "still_share", "still_pose"]


@dataclass(frozen=True, eq=False)
class StillTest:
    """The dense motion between two frames of a clip: ``share`` (0..1) of the content that moves
    by at most the test's ``still_px``, moving objects left out; ``motion_px`` those pixels'
    median motion (inf when none is still); ``still`` the (h, w) bool map of those pixels at the
    test's size (objects included: they are never matched for the background)."""

    share: float
    motion_px: float
    still: np.ndarray


def still_share(
    g0: np.ndarray,
    g1: np.ndarray,
    *,
    still_px: float,
    ignore: np.ndarray | None = None,
) -> StillTest:
    """The :class:`StillTest` of two grey frames (same size, uint8) under dense DIS flow (medium
    preset); ``ignore`` (bool, same size) marks pixels left out of the share (moving objects)."""
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)  # type: ignore[attr-defined]  # missing from the cv2 stubs
    flow = dis.calc(np.ascontiguousarray(g0), np.ascontiguousarray(g1), None)
    mag = np.hypot(flow[..., 0], flow[..., 1])
    still = mag <= still_px
    keep = np.ones(mag.shape, bool) if ignore is None else ~ignore
    if not (keep & still).any():
        return StillTest(0.0, float("inf"), still)
    return StillTest(float(np.mean(still[keep])), float(np.median(mag[keep & still])), still)


def still_pose(share: float, motion_px: float, scale: float, focal_px: float, frames: tuple[int, int]) -> PoseEstimate:
    """The pose of a still camera: identity, ``t_inf`` the first-order bound of the still pixels'
    median motion (``motion_px`` at the test's size, ``scale`` working px per test px) over the
    focal length, and a note saying why."""
    motion = motion_px * scale
    return PoseEstimate(
        pose_present=True,
        t_inf=motion / focal_px if np.isfinite(motion) else 0.0,
        T_cam0_camT=np.eye(4),
        method="still",
        reason=None,
        n_matches=0,
        n_inliers=0,
        rotation_deg=0.0,
        parallax_px=motion if np.isfinite(motion) else None,
        focal_px=focal_px,
        note=(
            f"still camera: {share:.0%} of the content (moving objects left out) moves by less than a pixel "
            f"between frames {frames[0]} and {frames[1]}"
        ),
    )
