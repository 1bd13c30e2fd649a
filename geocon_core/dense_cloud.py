"""Dense two-view point clouds without weights: the dense flow of a frame pair triangulated with
the pair's relative pose, every point marked by how well the background's rigid geometry explains
it, so an inspector sees in 3D where the background fails to be one rigid scene.

For the pair (first frame, other frame), with the flow composed over the frames between them, and
the pose ``T_cam0_camT`` (the other camera in
first-camera coordinates, :mod:`geocon_core.pose`), every ``step``-th reliable flow vector of the
content is a correspondence ``x0 -> x1 = x0 + F(x0)``. It is triangulated (linear, both views) and
kept when it lies in front of both cameras and reprojects within ``max_reproj_px`` in both. Its
residual is the Sampson distance (px) of the correspondence to the epipolar geometry of the pose,
``F = K^-T [t]x R K^-1``: a rigid background point has a residual at the flow's noise level, a
point of a breathing, sliding or boiling background does not. ``kind``: 0 background within
``tau_px``, 1 background beyond it, 2 a moving object (its depth is not a depth: it moved).

A pose without translation (a pan, a zoom, a still camera) has no parallax: nothing can be
triangulated, and the cloud is empty with a note saying so.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from .flow import FlowBackend, chained_flow

__all__ = ["DenseCloud", "dense_cloud", "KIND_INLIER", "KIND_OUTLIER", "KIND_OBJECT"]

KIND_INLIER, KIND_OUTLIER, KIND_OBJECT = 0, 1, 2
MIN_BASELINE = 1e-6
"""A translation shorter than this (unit mean scene distance) is no baseline at all."""


@dataclass(frozen=True, eq=False)
class DenseCloud:
    """xyz: (N, 3) float32 points in first-camera coordinates (the pose's scale); rgb: (N, 3)
    uint8 colours of the first frame; pixel: (N, 2) float32 their pixels in the first frame;
    residual: (N,) float32 Sampson distance (px) to the pose's epipolar geometry; kind: (N,)
    uint8 (0 inlier, 1 outlier, 2 object); note: how it was made, or why it is empty."""

    xyz: np.ndarray
    rgb: np.ndarray
    pixel: np.ndarray
    residual: np.ndarray
    kind: np.ndarray
    note: str

    def __len__(self) -> int:
        return int(self.xyz.shape[0])

    def share(self, kind: int) -> float:
        """Share of the background points (kinds 0 and 1) that are of ``kind``."""
        bg = self.kind != KIND_OBJECT
        return float(np.mean(self.kind[bg] == kind)) if bg.any() else float("nan")


def _empty(note: str) -> DenseCloud:
    return DenseCloud(
        np.zeros((0, 3), np.float32),
        np.zeros((0, 3), np.uint8),
        np.zeros((0, 2), np.float32),
        np.zeros(0, np.float32),
        np.zeros(0, np.uint8),
        note,
    )


def _skew(t: np.ndarray) -> np.ndarray:
    return np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])


def _sampson(F: np.ndarray, x0: np.ndarray, x1: np.ndarray) -> np.ndarray:
    h0 = np.column_stack([x0, np.ones(len(x0))])
    h1 = np.column_stack([x1, np.ones(len(x1))])
    Fx0, Ftx1 = h0 @ F.T, h1 @ F
    num = np.einsum("ij,ij->i", h1, Fx0) ** 2
    den = Fx0[:, 0] ** 2 + Fx0[:, 1] ** 2 + Ftx1[:, 0] ** 2 + Ftx1[:, 1] ** 2
    return np.sqrt(num / np.maximum(den, 1e-300))


def dense_cloud(
    rgb0: np.ndarray,
    grays: Sequence[np.ndarray],
    K: np.ndarray,
    T_cam0_camT: np.ndarray,
    flow: FlowBackend,
    *,
    content: np.ndarray | None = None,
    labels0: np.ndarray | None = None,
    step: int = 2,
    tau_px: float = 1.0,
    max_reproj_px: float = 2.0,
) -> DenseCloud:
    """The dense cloud of the pair (first, last of ``grays``) (see the module docstring). ``rgb0``
    (H, W, 3) uint8 the first frame; ``grays`` (H, W) uint8 the frames from the first to the last
    of the pair: the flow is composed over them (:func:`~geocon_core.flow.chained_flow`), so a
    displacement larger than one flow call's reach is followed; ``K`` (3, 3); ``T_cam0_camT``
    (4, 4) the last camera in first-camera coordinates; ``content`` (H, W) bool pixels of real
    image content; ``labels0`` (H, W) object ids of the first frame."""
    R, c = np.asarray(T_cam0_camT, float)[:3, :3], np.asarray(T_cam0_camT, float)[:3, 3]
    if not np.linalg.norm(c) > MIN_BASELINE:
        return _empty("rotation only: the camera did not move, so there is no parallax and no depth")
    field = chained_flow(flow, grays)
    h, w = grays[0].shape
    keep = field.reliable.copy()
    if content is not None:
        keep &= content
    grid = np.zeros_like(keep)
    grid[::step, ::step] = True
    ys, xs = np.nonzero(keep & grid)
    if len(xs) == 0:
        return _empty("no reliable flow on the content")
    x0 = np.column_stack([xs, ys]).astype(np.float64)
    x1 = x0 + field.flow[ys, xs].astype(np.float64)
    # the other camera: X_T = R^T (X_0 - c)
    R1, t1 = R.T, -R.T @ c
    P0 = K @ np.hstack([np.eye(3), np.zeros((3, 1))])
    P1 = K @ np.hstack([R1, t1[:, None]])
    Xh = cv2.triangulatePoints(P0, P1, x0.T, x1.T)
    with np.errstate(divide="ignore", invalid="ignore"):
        X = (Xh[:3] / Xh[3]).T
    X1 = X @ R1.T + t1
    ok = np.isfinite(X).all(axis=1) & (X[:, 2] > 0) & (X1[:, 2] > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        p0 = X @ K.T
        p1 = X1 @ K.T
        e0 = np.linalg.norm(p0[:, :2] / p0[:, 2:] - x0, axis=1)
        e1 = np.linalg.norm(p1[:, :2] / p1[:, 2:] - x1, axis=1)
    ok &= (e0 <= max_reproj_px) & (e1 <= max_reproj_px)
    Kinv = np.linalg.inv(K)
    F = Kinv.T @ _skew(t1) @ R1 @ Kinv
    residual = _sampson(F, x0, x1)
    kind = np.where(residual <= tau_px, KIND_INLIER, KIND_OUTLIER).astype(np.uint8)
    if labels0 is not None:
        kind[labels0[ys, xs] > 0] = KIND_OBJECT
        ok |= (labels0[ys, xs] > 0) & np.isfinite(X).all(axis=1) & (X[:, 2] > 0)  # objects shown where they land
    note = (
        f"dense flow of {w}x{h} px every {step} px, triangulated with the gate's pose; "
        f"inlier: epipolar residual <= {tau_px:g} px"
    )
    return DenseCloud(
        X[ok].astype(np.float32),
        rgb0[ys[ok], xs[ok]].astype(np.uint8),
        x0[ok].astype(np.float32),
        residual[ok].astype(np.float32),
        kind[ok],
        note,
    )
