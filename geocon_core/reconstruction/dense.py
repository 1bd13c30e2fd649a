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

While a clip is scored, :class:`DenseCloudBuilder` makes these clouds for the first/last pair and
for every window of the gate timeline at once: each frame is seen once, at a reduced size
(:class:`DenseCloudConfig`), one flow per consecutive pair is composed into every window that
spans it, and the windows are triangulated with their poses when the scoring is done. Residuals
are in pixels of the working resolution, as everywhere in a record.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from ..flow import FlowBackend, FlowChain, FlowField, chained_flow
from ..geometry import scale_intrinsics
from ..pose import PoseEstimate

__all__ = [
    "DenseCloud",
    "DenseCloudConfig",
    "DenseCloudBuilder",
    "WindowCloud",
    "dense_cloud",
    "triangulate_flow",
    "KIND_INLIER",
    "KIND_OUTLIER",
    "KIND_OBJECT",
]

KIND_INLIER = 0
"""A cloud point of the background that agrees with the pose (its reprojection error is small)."""
KIND_OUTLIER = 1
"""A cloud point of the background that does not agree with the pose."""
KIND_OBJECT = 2
"""A cloud point on a moving object (masked out of the background)."""
MIN_BASELINE = 1e-6
"""A translation shorter than this (unit mean scene distance) is no baseline at all."""
NO_PARALLAX = "rotation only: the camera did not move, so there is no parallax and no depth"
"""The note of a pair whose pose has no translation."""
MIN_SIDE = 16
"""Frames narrower or lower than this (px, reduced) get no dense cloud."""


@dataclass(frozen=True, eq=False)
class DenseCloud:
    """xyz: (N, 3) float32 points in first-camera coordinates (the pose's scale); rgb: (N, 3)
    uint8 colours of the first frame; pixel: (N, 2) float32 their pixels in the first frame;
    residual: (N,) float32 Sampson distance (px) to the pose's epipolar geometry; kind: (N,)
    uint8 (0 inlier, 1 outlier, 2 object); note: how it was made, or why it is empty; tau_px: the
    inlier threshold on the residual (NaN for an empty cloud)."""

    xyz: np.ndarray
    rgb: np.ndarray
    pixel: np.ndarray
    residual: np.ndarray
    kind: np.ndarray
    note: str
    tau_px: float = float("nan")

    def __post_init__(self) -> None:
        n = self.xyz.shape[0] if self.xyz.ndim == 2 else -1
        shapes = {"xyz": (n, 3), "rgb": (n, 3), "pixel": (n, 2), "residual": (n,), "kind": (n,)}
        for name, shape in shapes.items():
            if getattr(self, name).shape != shape:
                raise ValueError(f"DenseCloud.{name} must have shape {shape}, got {getattr(self, name).shape}")

    def __len__(self) -> int:
        return int(self.xyz.shape[0])

    def take(self, rows: np.ndarray) -> "DenseCloud":
        """The cloud of the points ``rows`` (indices or a mask), with the same note."""
        return DenseCloud(
            self.xyz[rows],
            self.rgb[rows],
            self.pixel[rows],
            self.residual[rows],
            self.kind[rows],
            self.note,
            self.tau_px,
        )

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


@dataclass(frozen=True)
class DenseCloudConfig:
    """How the dense clouds of a scored clip are made (:class:`DenseCloudBuilder`). They are a
    picture for the viewers, not a score: no field changes a recorded score."""

    long_side: int = 512
    """The frames are reduced to this long side (px; never enlarged) for the flow."""
    dis_preset: str = "medium"
    """The OpenCV DIS preset of the clouds' flow (when the scorer's flow backend is DIS)."""
    step: int = 2
    """Every ``step``-th pixel (both axes, reduced frame) of reliable flow is triangulated."""
    tau_px: float = 1.0
    """Inlier: Sampson distance to the pose's epipolar geometry at most this (working px) ..."""
    fb_gain: float = 2.0
    """... plus this many times the flow's forward-backward error at the point (working px):
    composed flow on real footage is noisier than one hop, and the noise is not a failure."""
    max_reproj_px: float = 2.0
    """A triangulated point is kept when it reprojects within this (reduced px) in both views."""
    max_points: int = 40000
    """At most this many points in the first/last cloud (a seeded subset)."""
    window_points: int = 10000
    """At most this many points in the cloud of each gate window."""
    seed: int = 0

    def __post_init__(self) -> None:
        if self.long_side < 32 or self.step < 1 or self.max_points < 1 or self.window_points < 1:
            raise ValueError("dense clouds: long_side >= 32, step >= 1 and point limits >= 1 are needed")
        if not (self.tau_px > 0 and self.max_reproj_px > 0):
            raise ValueError("dense clouds: tau_px and max_reproj_px must be positive")


@dataclass(frozen=True, eq=False)
class WindowCloud:
    """The dense cloud of frames ``start -> end`` (the first/last pair, or a gate window), in the
    coordinates of camera ``start`` on that pair's pose scale; ``T_cam0_camT`` (4, 4) is camera
    ``end`` in those coordinates (None without a pose)."""

    start: int
    end: int
    cloud: DenseCloud
    T_cam0_camT: np.ndarray | None = None


def triangulate_flow(
    rgb0: np.ndarray,
    field: FlowField,
    K: np.ndarray,
    T_cam0_camT: np.ndarray,
    *,
    content: np.ndarray | None = None,
    labels0: np.ndarray | None = None,
    step: int = 2,
    tau_px: float = 1.0,
    max_reproj_px: float = 2.0,
    px_scale: float = 1.0,
    fb_gain: float = 0.0,
    hops: int = 1,
) -> DenseCloud:
    """The dense cloud of a full-frame forward flow ``field`` from the frame ``rgb0`` to a frame
    seen from ``T_cam0_camT`` (see the module docstring); ``px_scale`` is the size of the flow's
    pixels in the pixels residuals are reported in (working px per flow px), ``tau_px`` is in
    reported pixels. A point is an outlier when its residual exceeds ``tau_px + fb_gain *
    fb_error / sqrt(hops)``: with ``fb_gain > 0`` the flow's own forward-backward error at the
    point is noise the residual may have before it counts (``fb_error`` of a flow composed of
    ``hops`` flows is the sum of theirs, which grows with ``hops`` while independent errors of the
    composed flow grow with its square root)."""
    R, c = np.asarray(T_cam0_camT, float)[:3, :3], np.asarray(T_cam0_camT, float)[:3, 3]
    if not np.linalg.norm(c) > MIN_BASELINE:
        return _empty(NO_PARALLAX)
    h, w = field.reliable.shape
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
    residual = _sampson(F, x0, x1) * px_scale
    tolerance = tau_px + fb_gain * field.fb_error[ys, xs].astype(np.float64) * px_scale / math.sqrt(hops)
    kind = np.where(residual <= tolerance, KIND_INLIER, KIND_OUTLIER).astype(np.uint8)
    if labels0 is not None:
        kind[labels0[ys, xs] > 0] = KIND_OBJECT
        ok |= (labels0[ys, xs] > 0) & np.isfinite(X).all(axis=1) & (X[:, 2] > 0)  # objects shown where they land
    noise = f" + {fb_gain:g} x the flow's forward-backward error / sqrt(hops)" if fb_gain > 0 else ""
    note = (
        f"dense flow of {w}x{h} px every {step} px, triangulated with the pair's pose; "
        f"inlier: epipolar residual <= {tau_px:g} px{noise}"
    )
    return DenseCloud(
        X[ok].astype(np.float32),
        rgb0[ys[ok], xs[ok]].astype(np.uint8),
        x0[ok].astype(np.float32),
        residual[ok].astype(np.float32),
        kind[ok],
        note,
        float(tau_px),
    )


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
    of the pair: the flow is composed over them (:func:`~geocon_core.flow.dense.chained_flow`), so a
    displacement larger than one flow call's reach is followed; ``K`` (3, 3); ``T_cam0_camT``
    (4, 4) the last camera in first-camera coordinates; ``content`` (H, W) bool pixels of real
    image content; ``labels0`` (H, W) object ids of the first frame."""
    c = np.asarray(T_cam0_camT, float)[:3, 3]
    if not np.linalg.norm(c) > MIN_BASELINE:  # no flow is needed to say so
        return _empty(NO_PARALLAX)
    return triangulate_flow(
        rgb0,
        chained_flow(flow, grays),
        K,
        T_cam0_camT,
        content=content,
        labels0=labels0,
        step=step,
        tau_px=tau_px,
        max_reproj_px=max_reproj_px,
    )


def _subset(cloud: DenseCloud, limit: int, rng: np.random.Generator) -> DenseCloud:
    if len(cloud) <= limit:
        return cloud
    return cloud.take(np.sort(rng.choice(len(cloud), size=limit, replace=False)))


class DenseCloudBuilder:
    """The dense clouds of the pairs ``windows`` (``(start, end)`` frame indices, the first/last
    pair among them) of a clip whose frames are shown once each, in order, by :meth:`observe`
    (working resolution (H, W) of ``content``); :meth:`clouds` triangulates them with their poses.
    Holds the reduced first frame, labels and composed flow of each window until then."""

    def __init__(
        self,
        content: np.ndarray,
        windows: Sequence[tuple[int, int]],
        flow: FlowBackend,
        config: DenseCloudConfig | None = None,
    ) -> None:
        self.config = cfg = config or DenseCloudConfig()
        h, w = content.shape
        self.scale = min(1.0, cfg.long_side / max(h, w))
        self.size = (max(1, round(w * self.scale)), max(1, round(h * self.scale)))
        self.content = self._reduce(content.astype(np.uint8), cv2.INTER_NEAREST) > 0
        self.windows = list(dict.fromkeys((int(a), int(b)) for a, b in windows if b > a))
        self.flow = flow
        self.too_small = min(self.size) < MIN_SIDE  # no flow worth triangulating
        self._prev: np.ndarray | None = None
        self._first: dict[tuple[int, int], tuple[np.ndarray, np.ndarray | None]] = {}
        self._chains: dict[tuple[int, int], FlowChain] = {}
        self._fields: dict[tuple[int, int], FlowField] = {}

    def _reduce(self, image: np.ndarray, interpolation: int) -> np.ndarray:
        if self.scale == 1.0:
            return image
        return cv2.resize(image, self.size, interpolation=interpolation)

    def observe(self, index: int, rgb: np.ndarray, gray: np.ndarray, labels: np.ndarray | None) -> None:
        """Frame ``index`` (frames come in order 0, 1, ...) and its object ids (or None)."""
        if self.too_small:
            return
        g = self._reduce(gray, cv2.INTER_AREA)
        starts = [w for w in self.windows if w[0] == index]
        for w in starts:
            small = None if labels is None else self._reduce(labels.astype(np.uint16), cv2.INTER_NEAREST)
            self._first[w] = (self._reduce(rgb, cv2.INTER_AREA), small)
        spanning = [w for w in self.windows if w[0] < index <= w[1]]
        if spanning and self._prev is not None:
            hop = self.flow.compute(self._prev, g, None)
            for w in spanning:
                chain = self._chains.get(w)
                if chain is None:
                    self._chains[w] = FlowChain(hop)
                else:
                    chain.extend(hop)
                if w[1] == index:
                    self._fields[w] = self._chains.pop(w).field()
        self._prev = g

    def clouds(self, K: np.ndarray, poses: Mapping[tuple[int, int], PoseEstimate]) -> tuple[WindowCloud, ...]:
        """The cloud of every window, triangulated with ``poses[window]`` (intrinsics ``K`` of the
        working resolution, times the pose's focal scale); a window without a pose, or whose frames
        were not all seen, has an empty cloud whose note says why."""
        cfg = self.config
        rng = np.random.default_rng(cfg.seed)
        out = []
        for i, w in enumerate(self.windows):
            pose, field = poses.get(w), self._fields.get(w)
            if self.too_small:
                cloud = _empty(f"frames of {self.size[0]}x{self.size[1]} px are too small for a dense cloud")
            elif field is None:
                cloud = _empty(f"frames {w[0]}-{w[1]} were not all read")
            elif pose is None or not pose.pose_present or pose.T_cam0_camT is None:
                reason = "no pose" if pose is None else f"no pose ({pose.reason})"
                cloud = _empty(f"{reason} for frames {w[0]}-{w[1]}: nothing to triangulate")
            else:
                Kd = scale_intrinsics(K, self.scale)
                Kd[:2, :2] *= pose.focal_scale
                rgb0, labels0 = self._first[w]
                cloud = triangulate_flow(
                    rgb0,
                    field,
                    Kd,
                    pose.T_cam0_camT,
                    content=self.content,
                    labels0=labels0,
                    step=cfg.step,
                    tau_px=cfg.tau_px,
                    max_reproj_px=cfg.max_reproj_px,
                    px_scale=1.0 / self.scale,
                    fb_gain=cfg.fb_gain,
                    hops=w[1] - w[0],
                )
            limit = cfg.max_points if i == 0 else cfg.window_points
            T = None if pose is None or pose.T_cam0_camT is None else np.asarray(pose.T_cam0_camT, float)
            out.append(WindowCloud(w[0], w[1], _subset(cloud, limit, rng), T))
        return tuple(out)
