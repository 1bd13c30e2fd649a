"""Pure multi-view geometry on numpy arrays.

Conventions (used everywhere in GeoCon):

- Camera coordinates follow OpenCV: x right, y down, z forward (viewing direction).
- Pixel coordinates put pixel *centres* at integer positions; (0, 0) is the centre of the
  top-left pixel.
- A 4x4 rigid transform is named after the frames it maps: ``T_a_b`` maps points expressed
  in frame ``b`` into frame ``a`` (``X_a = T_a_b @ X_b``). ``T_cam_world`` is therefore the
  world-to-camera transform, and the translation column of ``T_cam0_camT`` is the centre of
  camera ``T`` expressed in the coordinates of camera 0 (the DUSt3R cam-to-world convention
  with the first camera as world).
- A homography ``H_2from1`` (3x3) maps homogeneous pixels of image 1 to image 2; a
  fundamental matrix ``F_21`` satisfies ``x2^T F_21 x1 = 0``.
"""

from __future__ import annotations

import math
from typing import Callable

import cv2
import numpy as np

__all__ = [
    "triangulate_views",
    "refine_points",
    "intrinsics_from_fov",
    "rotation_xyz",
    "make_pose",
    "invert_pose",
    "relative_pose",
    "rotation_angle_deg",
    "skew",
    "rotation_from_axis_angle",
    "homography_from_rotation",
    "homography_from_plane",
    "fundamental_from_pose",
    "to_homogeneous",
    "apply_homography",
    "symmetric_transfer_error",
    "sampson_distance",
    "epipolar_line_distance",
    "t_inf_from_pose",
    "scale_intrinsics",
    "project",
    "triangulate_two_view",
    "two_view_cloud",
    "triangulate_dlt",
    "triangulate_normalised",
    "in_front_triangulated",
    "in_front_least_squares",
    "cheirality_pose",
]


def intrinsics_from_fov(width: float, height: float, fov_x_deg: float) -> np.ndarray:
    """Pinhole matrix ``K`` (3x3) with square pixels, principal point at the image centre
    (``((W-1)/2, (H-1)/2)`` in the integer-pixel-centre convention) and the focal length
    that gives a horizontal field of view of ``fov_x_deg`` degrees."""
    if not (0.0 < fov_x_deg < 180.0):
        raise ValueError(f"fov_x_deg must be in (0, 180), got {fov_x_deg}")
    f = 0.5 * width / math.tan(math.radians(fov_x_deg) / 2.0)
    return np.array([[f, 0.0, (width - 1) / 2.0], [0.0, f, (height - 1) / 2.0], [0.0, 0.0, 1.0]])


def rotation_xyz(yaw_deg: float = 0.0, pitch_deg: float = 0.0, roll_deg: float = 0.0) -> np.ndarray:
    """Camera-to-world rotation (3x3) of a camera that pans by ``yaw`` (about +y, positive turns
    right), tilts by ``pitch`` (about +x, positive looks up) and rolls by ``roll`` (about the
    viewing axis +z), applied as ``R = R_y(yaw) @ R_x(-pitch) @ R_z(roll)``."""
    y, p, r = (math.radians(v) for v in (yaw_deg, -pitch_deg, roll_deg))
    Ry = np.array([[math.cos(y), 0, math.sin(y)], [0, 1, 0], [-math.sin(y), 0, math.cos(y)]])
    Rx = np.array([[1, 0, 0], [0, math.cos(p), -math.sin(p)], [0, math.sin(p), math.cos(p)]])
    Rz = np.array([[math.cos(r), -math.sin(r), 0], [math.sin(r), math.cos(r), 0], [0, 0, 1]])
    return Ry @ Rx @ Rz


def make_pose(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """4x4 rigid transform from a rotation (3x3) and a translation (3,)."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.asarray(t, dtype=float).reshape(3)
    return T


def invert_pose(T: np.ndarray) -> np.ndarray:
    """Inverse of a 4x4 rigid transform (exact for rotations: uses the transpose)."""
    R, t = T[:3, :3], T[:3, 3]
    return make_pose(R.T, -R.T @ t)


def relative_pose(T_cam0_world: np.ndarray, T_camT_world: np.ndarray) -> np.ndarray:
    """``T_cam0_camT``: the pose of camera T in the coordinates of camera 0 (4x4)."""
    return T_cam0_world @ invert_pose(T_camT_world)


def rotation_angle_deg(R: np.ndarray) -> float:
    """Rotation angle (degrees) of a 3x3 rotation matrix."""
    c = (np.trace(R) - 1.0) / 2.0
    return math.degrees(math.acos(float(np.clip(c, -1.0, 1.0))))


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrix ``[v]_x`` (3x3) with ``[v]_x @ w = v x w``."""
    x, y, z = np.asarray(v, dtype=float).reshape(3)
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def rotation_from_axis_angle(w: np.ndarray) -> np.ndarray:
    """Rotation (3x3) of the axis-angle vector ``w`` (3,) (Rodrigues' formula; angle ``|w|`` in
    radians); first order ``I + [w]_x`` below an angle of 1e-12."""
    th = float(np.linalg.norm(w))
    if th < 1e-12:
        return np.eye(3) + skew(w)
    Kx = skew(w / th)
    return np.eye(3) + math.sin(th) * Kx + (1 - math.cos(th)) * (Kx @ Kx)


def homography_from_rotation(K: np.ndarray, R_2from1: np.ndarray) -> np.ndarray:
    """``H_2from1 = K R K^-1`` for a camera that only rotates (``X_2 = R_2from1 X_1``)."""
    return K @ R_2from1 @ np.linalg.inv(K)


def homography_from_plane(K1: np.ndarray, K2: np.ndarray, T_2_1: np.ndarray, m_1: np.ndarray) -> np.ndarray:
    """Homography induced by the plane ``{X_1 : m_1 . X_1 = 1}`` (plane vector ``m = n / d`` in
    camera-1 coordinates) between two views with ``X_2 = T_2_1 X_1``:
    ``H_2from1 = K2 (R + t m^T) K1^-1``."""
    R, t = T_2_1[:3, :3], T_2_1[:3, 3]
    return K2 @ (R + np.outer(t, np.asarray(m_1, dtype=float))) @ np.linalg.inv(K1)


def fundamental_from_pose(K1: np.ndarray, K2: np.ndarray, T_2_1: np.ndarray) -> np.ndarray:
    """``F_21 = K2^-T [t]_x R K1^-1`` for ``X_2 = R X_1 + t``; normalised to unit Frobenius norm."""
    R, t = T_2_1[:3, :3], T_2_1[:3, 3]
    F = np.linalg.inv(K2).T @ skew(t) @ R @ np.linalg.inv(K1)
    return F / np.linalg.norm(F)


def to_homogeneous(x: np.ndarray) -> np.ndarray:
    """(N, 2) -> (N, 3) by appending ones."""
    x = np.asarray(x, dtype=float)
    return np.concatenate([x, np.ones((x.shape[0], 1))], axis=1)


def apply_homography(H: np.ndarray, x: np.ndarray, *, at_infinity: float = np.nan) -> np.ndarray:
    """Map (N, 2) pixels through a 3x3 homography; points mapped to infinity (a non-finite
    coordinate) become ``at_infinity`` (NaN by default; ``inf`` keeps them out of percentiles
    and medians as the largest values)."""
    y = to_homogeneous(x) @ np.asarray(H, dtype=float).T
    with np.errstate(divide="ignore", invalid="ignore"):
        out = y[:, :2] / y[:, 2:3]
    out[~np.isfinite(out).all(axis=1)] = at_infinity
    return out


def symmetric_transfer_error(H_2from1: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    """Per-match symmetric transfer error in pixels, shape (N,):
    ``0.5 * ||x2 - H x1|| + 0.5 * ||x1 - H^-1 x2||``."""
    fwd = np.linalg.norm(x2 - apply_homography(H_2from1, x1), axis=1)
    bwd = np.linalg.norm(x1 - apply_homography(np.linalg.inv(H_2from1), x2), axis=1)
    return 0.5 * fwd + 0.5 * bwd


def sampson_distance(F_21: np.ndarray, x1: np.ndarray, x2: np.ndarray, *, signed: bool = False) -> np.ndarray:
    """First-order geometric (Sampson) distance of each match to the epipolar geometry, shape
    (N,), in the units of the coordinates given (NOT squared):
    ``|x2^T F x1| / sqrt((F x1)_1^2 + (F x1)_2^2 + (F^T x2)_1^2 + (F^T x2)_2^2)``; ``inf`` where
    the denominator vanishes. With ``signed`` the sign of ``x2^T F x1`` is kept and the
    denominator is floored at 1e-300 (a finite residual for least squares)."""
    h1, h2 = to_homogeneous(x1), to_homogeneous(x2)
    Fx1 = h1 @ F_21.T
    Ftx2 = h2 @ F_21
    num = np.sum(h2 * Fx1, axis=1)
    den = np.sqrt(Fx1[:, 0] ** 2 + Fx1[:, 1] ** 2 + Ftx2[:, 0] ** 2 + Ftx2[:, 1] ** 2)
    if signed:
        return num / np.maximum(den, 1e-300)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(den > 0, np.abs(num) / den, np.inf)


def epipolar_line_distance(F_21: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    """Distance (N,) of each x2 (N, 2) to its epipolar line ``F_21 x1`` in image 2, in the units
    of the coordinates given (one-sided, unlike :func:`sampson_distance`)."""
    line = x1 @ F_21[:, :2].T + F_21[:, 2]
    num = np.abs(np.sum(x2 * line[:, :2], axis=1) + line[:, 2])
    return num / np.maximum(np.hypot(line[:, 0], line[:, 1]), 1e-12)


def t_inf_from_pose(T_cam0_camT: np.ndarray, mean_scene_distance: float) -> float:
    """``t_inf = max(|tx|, |ty|, |tz|)`` of the first->last relative pose on the DUSt3R scale,
    i.e. after scaling the scene so that the mean distance of the visible scene points from
    the first camera is 1."""
    if not mean_scene_distance > 0:
        raise ValueError(f"mean_scene_distance must be positive, got {mean_scene_distance}")
    return float(np.max(np.abs(T_cam0_camT[:3, 3])) / mean_scene_distance)


def scale_intrinsics(K: np.ndarray, scale: float) -> np.ndarray:
    """Intrinsics of an image resized by ``scale`` (pixel centres at integers, so a pixel x maps
    to ``(x + 0.5) * scale - 0.5``, as ``cv2.resize`` does)."""
    S = np.array([[scale, 0.0, 0.5 * scale - 0.5], [0.0, scale, 0.5 * scale - 0.5], [0.0, 0.0, 1.0]])
    return S @ K


def project(K: np.ndarray, T_cam_world: np.ndarray, X_world: np.ndarray) -> np.ndarray:
    """Pixels (N, 2) of world points (N, 3) seen by a camera with intrinsics K and world-to-camera
    pose ``T_cam_world`` (points behind the camera are projected all the same)."""
    X = np.asarray(X_world, dtype=float) @ T_cam_world[:3, :3].T + T_cam_world[:3, 3]
    x = X @ np.asarray(K, dtype=float).T
    return x[:, :2] / x[:, 2:3]


def triangulate_two_view(
    K: np.ndarray, T_cam0_cam1: np.ndarray, x0: np.ndarray, x1: np.ndarray, *, max_reproj_px: float = 2.0
) -> tuple[np.ndarray, np.ndarray]:
    """Linear (DLT) triangulation of (N, 2) matches between camera 0 (at the origin) and camera 1
    with pose ``T_cam0_cam1`` (camera 1 in camera-0 coordinates), both with intrinsics K.
    Returns points (N, 3) in camera-0 coordinates and a mask (N,) of the points in front of
    both cameras whose reprojection error is at most ``max_reproj_px`` in both images."""
    x0, x1 = np.asarray(x0, dtype=float).reshape(-1, 2), np.asarray(x1, dtype=float).reshape(-1, 2)
    if x0.shape[0] == 0:
        return np.zeros((0, 3)), np.zeros(0, bool)
    T_1_0 = invert_pose(T_cam0_cam1)
    X = triangulate_dlt(K @ np.hstack([np.eye(3), np.zeros((3, 1))]), K @ T_1_0[:3, :], x0, x1)
    finite = np.isfinite(X).all(axis=1)
    X = np.where(finite[:, None], X, 0.0)
    z0 = X[:, 2]
    z1 = X @ T_1_0[2, :3] + T_1_0[2, 3]
    e0 = np.linalg.norm(project(K, np.eye(4), X) - x0, axis=1)
    e1 = np.linalg.norm(project(K, T_1_0, X) - x1, axis=1)
    ok = finite & (z0 > 0) & (z1 > 0) & (e0 <= max_reproj_px) & (e1 <= max_reproj_px)
    return X, ok


def two_view_cloud(
    K: np.ndarray,
    T_cam0_camT: np.ndarray,
    x0: np.ndarray,
    x1: np.ndarray,
    rgb0: np.ndarray,
    scale: float,
    *,
    focal_scale: float = 1.0,
) -> tuple[np.ndarray, np.ndarray]:
    """The coloured point cloud of a two-view pose: (N, 2) matches ``x0``/``x1`` in pixels of
    ``scale`` triangulated (:func:`triangulate_two_view`) with intrinsics K (of that scale, focal
    lengths times ``focal_scale``) and the pose ``T_cam0_camT``. Returns the kept points (M, 3)
    float32 in first-camera coordinates and their (M, 3) uint8 colours, sampled from the first
    frame ``rgb0`` (H, W, 3) at working resolution (pixels of the scale mapped back by
    ``1 / scale``)."""
    T = np.asarray(T_cam0_camT, dtype=float)
    Ks = K.copy()
    Ks[0, 0] *= focal_scale
    Ks[1, 1] *= focal_scale
    X, ok = triangulate_two_view(Ks, T, x0, x1)
    X, px = X[ok], x0[ok]
    h, w = rgb0.shape[:2]
    u = np.clip(np.round((px[:, 0] + 0.5) / scale - 0.5).astype(int), 0, w - 1)
    v = np.clip(np.round((px[:, 1] + 0.5) / scale - 0.5).astype(int), 0, h - 1)
    return X.astype(np.float32), rgb0[v, u].astype(np.uint8)


def triangulate_dlt(P0: np.ndarray, P1: np.ndarray, x0: np.ndarray, x1: np.ndarray) -> np.ndarray:
    """Linear (DLT, ``cv2.triangulatePoints``) triangulation of (N, 2) matches seen by the 3x4
    projection matrices P0 and P1; points (N, 3) in the frame the matrices map from (non-finite
    where the homogeneous coordinate vanishes)."""
    a = np.ascontiguousarray(np.asarray(x0).T, dtype=float)
    b = np.ascontiguousarray(np.asarray(x1).T, dtype=float)
    Xh = cv2.triangulatePoints(P0, P1, a, b)
    with np.errstate(divide="ignore", invalid="ignore"):
        return (Xh[:3] / Xh[3]).T


def triangulate_normalised(n0: np.ndarray, n1: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """DLT triangulation of (N, 2) normalised camera coordinates between camera 0 at the origin
    and camera 1 with ``X_1 = R X_0 + t``; points (N, 3) in camera-0 coordinates."""
    P0 = np.hstack([np.eye(3), np.zeros((3, 1))])
    P1 = np.hstack([R, np.asarray(t, dtype=float).reshape(3, 1)])
    return triangulate_dlt(P0, P1, n0, n1)


def in_front_triangulated(n0: np.ndarray, n1: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(N,) bool: the DLT triangulation of the (N, 2) normalised matches is finite and in front
    of both cameras (``X_1 = R X_0 + t``)."""
    X = triangulate_normalised(n0, n1, R, t)
    z1 = X @ R.T + t
    return np.isfinite(X).all(axis=1) & (X[:, 2] > 0) & (z1[:, 2] > 0)


def in_front_least_squares(r0: np.ndarray, r1: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(N,) bool: the least-squares depths ``z0, z1`` of ``z1 r1 = z0 R r0 + t`` for the (N, 3)
    rays ``r0``, ``r1`` (homogeneous normalised coordinates) are both positive."""
    u, v = r0 @ R.T, -r1
    uu, uv, vv = np.sum(u * u, 1), np.sum(u * v, 1), np.sum(v * v, 1)
    ut, vt = u @ t, v @ t
    det = uu * vv - uv * uv
    with np.errstate(divide="ignore", invalid="ignore"):
        z0 = (-ut * vv + vt * uv) / det
        z1 = (-vt * uu + ut * uv) / det
    return (z0 > 0) & (z1 > 0)


def cheirality_pose(
    E: np.ndarray, in_front: Callable[[np.ndarray, np.ndarray], np.ndarray]
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The decomposition ``(R, t)`` of the essential matrix E (``X_1 = R X_0 + t``, t of unit
    length up to sign) that puts the most points in front of both cameras, as counted by
    ``in_front(R, t)`` ((N,) bool, e.g. :func:`in_front_triangulated`), with that mask; the first
    of the four candidates wins a tie. None when E cannot be decomposed."""
    try:
        R1, R2, tt = cv2.decomposeEssentialMat(E)
    except cv2.error:
        return None
    tt = tt.ravel().astype(float)
    best: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
    for R, t in ((R1, tt), (R1, -tt), (R2, tt), (R2, -tt)):
        ok = in_front(R, t)
        if best is None or ok.sum() > best[2].sum():
            best = (np.asarray(R, dtype=float), t, ok)
    return best


def triangulate_views(P: np.ndarray, xy: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """Linear (DLT) triangulation of many points, each from the views that see it: projections
    ``P`` (K, 3, 4), pixels ``xy`` (T, K, 2) and where each point is seen ``seen`` (T, K);
    (T, 3), NaN where a point is seen fewer than twice or lies at infinity (the two-view case
    is :func:`triangulate_dlt`)."""
    x = np.nan_to_num(xy)
    A = np.concatenate(
        [x[..., 0:1] * P[None, :, 2] - P[None, :, 0], x[..., 1:2] * P[None, :, 2] - P[None, :, 1]], axis=1
    )  # (T, 2K, 4)
    w = np.concatenate([seen, seen], axis=1).astype(float)[..., None]
    A = A * w
    A = A / np.maximum(np.linalg.norm(A, axis=2, keepdims=True), 1e-12)
    _, _, vt = np.linalg.svd(A)
    X = vt[:, -1]
    with np.errstate(divide="ignore", invalid="ignore"):
        out = X[:, :3] / X[:, 3:4]
    out[(seen.sum(axis=1) < 2) | (np.abs(X[:, 3]) < 1e-12)] = np.nan
    return out


def refine_points(P: np.ndarray, xy: np.ndarray, seen: np.ndarray, X: np.ndarray, iterations: int = 6) -> np.ndarray:
    """Each point moved to minimise its reprojection error over the views that see it, the
    cameras ``P`` (K, 3, 4) held: damped Gauss-Newton, all points at once. A linear (DLT)
    point is not the one that fits best, and a track that slides across its epipolar lines
    reads a larger residual from it than it has."""
    X = X.copy()
    x = np.nan_to_num(xy)
    for _ in range(iterations):
        q = np.einsum("kij,tj->tki", P, np.c_[X, np.ones(len(X))])  # (T, K, 3)
        z = q[..., 2:3]
        ok = (z > 1e-9) & seen[..., None]
        zs = np.where(ok, z, 1.0)
        proj = q[..., :2] / zs
        r = np.where(ok, proj - x, 0.0)
        A = (P[None, :, :2, :3] - proj[..., None] * P[None, :, 2:3, :3]) / zs[..., None]  # d proj / d X
        A = np.where(ok[..., None], A, 0.0)
        JtJ = np.einsum("tkai,tkaj->tij", A, A)
        Jtr = np.einsum("tkai,tka->ti", A, r)
        damp = (1e-4 * np.trace(JtJ, axis1=1, axis2=2) + 1e-12)[:, None, None] * np.eye(3)
        X = X - np.linalg.solve(JtJ + damp, Jtr[..., None])[..., 0]
    return X
