"""The multi-view check's camera path: rays and rotations of tracked pixels, the initial poses
(an essential matrix and PnP for a clip the gate calls F, chained rotations for H), points
triangulated from the posed keyframes and pycolmap's bundle adjustment."""

from __future__ import annotations

import contextlib
import ctypes
import signal
import sys
from collections.abc import Iterator
from typing import Any

import cv2
import numpy as np

from ..config import MultiViewConfig
from ..geometry import refine_points, triangulate_views
from .tracks import TrackTable

__all__ = [
    "FAR",
    "ba_subset",
    "bundle_adjust",
    "far_directions",
    "init_general",
    "init_rotation",
    "load_pycolmap",
    "project",
    "triangulated",
    "undistort",
    "with_focal",
]


FAR = 1e6
"""Distance of the points of a rotation-only reconstruction: so far that a camera's position
(left free by the adjuster) cannot move them in the image."""


def _bearings(xy: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Unit rays (N, 3) of pixels ``xy`` (N, 2) under ``K``."""
    h = np.c_[xy, np.ones(len(xy))] @ np.linalg.inv(K).T
    return h / np.linalg.norm(h, axis=1, keepdims=True)


def _kabsch(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rotation R with R a_i ~ b_i (unit vectors, least squares)."""
    u, _, vt = np.linalg.svd(b.T @ a)
    d = np.sign(np.linalg.det(u @ vt))
    return u @ np.diag([1.0, 1.0, d]) @ vt


def _robust_rotation(
    a: np.ndarray, b: np.ndarray, thr_rad: float, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """RANSAC over pairs of rays, then Kabsch on the inliers: R (3x3) and the inlier mask."""
    n = len(a)
    best = np.zeros(n, bool)
    for _ in range(200):
        i = rng.choice(n, size=2, replace=False)
        R = _kabsch(a[i], b[i])
        inl = np.einsum("ij,nj->ni", R, a)
        ok = np.arccos(np.clip(np.sum(inl * b, axis=1), -1, 1)) < thr_rad
        if ok.sum() > best.sum():
            best = ok
    if best.sum() < 3:
        return np.eye(3), best
    R = _kabsch(a[best], b[best])
    ok = np.arccos(np.clip(np.sum(np.einsum("ij,nj->ni", R, a) * b, axis=1), -1, 1)) < thr_rad
    return _kabsch(a[ok], b[ok]) if ok.sum() >= 3 else R, ok


def _spread_deg(centres: np.ndarray, X: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """(T,) widest angle (degrees) between the rays from the centres (K, 3) of the views that
    see each track to its point X (T, 3), taken between the first and the last such view."""
    T = len(X)
    first = np.argmax(seen, axis=1)
    last = seen.shape[1] - 1 - np.argmax(seen[:, ::-1], axis=1)
    a = X - centres[first]
    b = X - centres[last]
    cos = np.sum(a * b, axis=1) / np.maximum(np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1), 1e-12)
    return np.degrees(np.arccos(np.clip(cos, -1, 1))) if T else np.zeros(0)


def undistort(xy: np.ndarray, params: np.ndarray) -> np.ndarray:
    """Pixels of a SIMPLE_RADIAL camera (f, cx, cy, k) -> the pixels of its pinhole (f, cx, cy)."""
    if len(params) < 4 or params[3] == 0:
        return xy
    f, cx, cy, k = params[:4]
    d = (xy - (cx, cy)) / f
    u = d.copy()
    for _ in range(10):
        u = d / (1 + k * np.sum(u * u, axis=-1, keepdims=True))
    return u * f + (cx, cy)


def triangulated(
    table: TrackTable,
    K: np.ndarray,
    poses: dict[int, np.ndarray],
    rows: np.ndarray,
    min_angle: float,
    *,
    refine: bool = False,
) -> dict[int, np.ndarray]:
    """Points of the tracks ``rows`` seen at two posed keyframes or more, in front of every camera
    that sees them and wide enough (``min_angle`` degrees between the extreme rays); ``refine``
    moves each to its least reprojection error (:func:`_refine_points`)."""
    reg = np.asarray(sorted(poses))
    if len(reg) < 2 or not len(rows):
        return {}
    seen = table.seen()[np.ix_(rows, reg)]
    P = np.stack([K @ poses[k] for k in reg])
    X = triangulate_views(P, table.xy[np.ix_(rows, reg)], seen)
    centres = np.stack([-poses[k][:, :3].T @ poses[k][:, 3] for k in reg])
    ok = np.all(np.isfinite(X), axis=1)
    ok[ok] &= _spread_deg(centres, X[ok], seen[ok]) >= min_angle
    depth = (
        np.einsum("kij,tj->tki", np.stack([poses[k][:, :3] for k in reg]), np.nan_to_num(X))[..., 2]
        + np.stack([poses[k][:, 3] for k in reg])[None, :, 2]
    )
    ok &= np.all((depth > 0) | ~seen, axis=1)
    if refine and ok.any():
        X[ok] = refine_points(P, table.xy[np.ix_(rows, reg)][ok], seen[ok], X[ok])
        ok &= np.all(np.isfinite(X), axis=1)
    return {int(r): X[i] for i, r in enumerate(rows) if ok[i]}


# ---------------------------------------------------------------------------------------------
# initial poses


def init_general(
    table: TrackTable, K: np.ndarray, cfg: MultiViewConfig
) -> tuple[dict[int, np.ndarray], dict[int, np.ndarray]] | None:
    """Poses (keyframe index -> 3x4 cam_from_world) and points (track row -> xyz) of a general
    camera motion, or None when no keyframe pair has the baseline to start from."""
    seen = table.seen()
    nk = len(table.frames)
    start = None
    for b in range(nk - 1, 0, -1):
        common = seen[:, 0] & seen[:, b]
        if common.sum() < cfg.min_init_tracks:
            continue
        p0, p1 = table.xy[common, 0], table.xy[common, b]
        E, inl = cv2.findEssentialMat(p0, p1, K, cv2.RANSAC, 0.999, 1.0)
        if E is None or E.shape != (3, 3):
            continue
        n_in, R, t, inl2 = cv2.recoverPose(E, p0, p1, K, mask=inl)
        if n_in < cfg.min_init_tracks // 2:
            continue
        poses = {0: np.eye(3, 4), b: np.c_[R, t.ravel()]}
        rows = np.flatnonzero(common)[inl2.ravel() > 0]
        sub = TrackTable(
            table.frames, table.ids, np.where(np.isin(np.arange(nk), [0, b])[None, :, None], table.xy, np.nan)
        )
        pts = triangulated(sub, K, poses, rows, 0.0)
        if len(pts) < cfg.min_init_tracks // 2:
            continue
        X = np.array(list(pts.values()))
        angles = _spread_deg(np.stack([np.zeros(3), -R.T @ t.ravel()]), X, np.ones((len(X), 2), bool))
        if np.median(angles) < cfg.min_angle_deg:
            continue
        start = poses
        break
    if start is None:
        return None
    poses = start
    b = max(poses)
    points = triangulated(table, K, poses, np.arange(len(table.ids)), cfg.min_angle_deg / 2)
    order = [*range(1, b), *range(b + 1, nk)]
    for k in order:
        rows_k = [r for r in points if seen[r, k]]
        if len(rows_k) < 12:
            continue
        obj = np.array([points[r] for r in rows_k])
        img = table.xy[rows_k, k]
        ok, rvec, tvec, inl = cv2.solvePnPRansac(
            obj, img, K, None, iterationsCount=200, reprojectionError=2.0, confidence=0.999, flags=cv2.SOLVEPNP_EPNP
        )
        if not ok or inl is None or len(inl) < 10:
            continue
        rvec, tvec = cv2.solvePnPRefineLM(obj[inl.ravel()], img[inl.ravel()], K, None, rvec, tvec)
        poses[k] = np.c_[cv2.Rodrigues(rvec)[0], tvec.ravel()]
        pending = np.array([r for r in range(len(table.ids)) if r not in points and seen[r, k]], dtype=int)
        points.update(triangulated(table, K, poses, pending, cfg.min_angle_deg / 2))
    return poses, points


def init_rotation(
    table: TrackTable, K: np.ndarray, seed: int, min_common: int
) -> tuple[dict[int, np.ndarray], dict[int, float], np.ndarray]:
    """Rotations (keyframe index -> 3x3, world = first keyframe) and focal lengths: each keyframe
    against the earliest posed keyframe that shares ``min_common`` tracks with it (the longest
    baseline, where a slowly drifting layer has drifted furthest from the rest and the
    consensus leaves it out), a homography's scale giving the zoom. Also (T,) bool: the tracks
    no consensus left out (the first adjustment's candidates)."""
    seen = table.seen()
    agreed = np.ones(len(table.ids), bool)
    rng = np.random.default_rng(seed)
    rot, focal = {0: np.eye(3)}, {0: float(K[0, 0])}
    for k in range(1, len(table.frames)):
        ref = next((j for j in sorted(rot) if (seen[:, j] & seen[:, k]).sum() >= min_common), None)
        if ref is None:
            ref = max(rot)
            if (seen[:, ref] & seen[:, k]).sum() < 12:
                continue
        common = seen[:, ref] & seen[:, k]
        a, b = table.xy[common, ref], table.xy[common, k]
        Kp = with_focal(K, focal[ref])
        Hm, _ = cv2.findHomography(a, b, cv2.RANSAC, 1.0)
        zoom = 1.0
        if Hm is not None:
            # K^-1 H K = diag(s, s, 1) R up to scale for a turn and a zoom s: the rows of R have unit length
            M = np.linalg.inv(Kp) @ Hm @ Kp
            rows = np.linalg.norm(M, axis=1)
            zoom = float((rows[0] + rows[1]) / (2 * rows[2])) if rows[2] > 0 else 1.0
            zoom = zoom if 0.5 < zoom < 2.0 else 1.0
        fk = focal[ref] * zoom
        R, ok = _robust_rotation(_bearings(a, Kp), _bearings(b, with_focal(K, fk)), 1.0 / fk, rng)
        if ok.sum() < 10:
            continue
        rot[k], focal[k] = R @ rot[ref], fk
        agreed[np.flatnonzero(common)[~ok]] = False
    return rot, focal, agreed


def with_focal(K: np.ndarray, f: float) -> np.ndarray:
    out = K.copy()
    out[0, 0] = out[1, 1] = f
    return out


def far_directions(
    table: TrackTable, poses: dict[int, np.ndarray], params: dict[int, np.ndarray], K: np.ndarray
) -> np.ndarray:
    """(T, 3) each track's point in the world of a rotation-only reconstruction, at distance
    :data:`FAR`: the mean of its rays from the cameras that see it (NaN for a track seen at
    fewer than two posed keyframes). A camera's position, left free by the adjuster, is taken
    into account (it moves such far points by a near-uniform shift)."""
    seen = table.seen()
    acc = np.zeros((len(table.ids), 3))
    count = np.zeros(len(table.ids))
    for k, P in poses.items():
        rows = np.flatnonzero(seen[:, k])
        R, t = P[:, :3], P[:, 3]
        ray = _bearings(table.xy[rows, k], with_focal(K, float(params[k][0])))
        acc[rows] += (ray * FAR - t) @ R  # R^T (lambda ray - t)
        count[rows] += 1
    out = acc / np.maximum(count, 1)[:, None]
    out = out / np.maximum(np.linalg.norm(out, axis=1, keepdims=True), 1e-12) * FAR
    out[count < 2] = np.nan
    return out


# ---------------------------------------------------------------------------------------------
# bundle adjustment (pycolmap)

_GLOG_SIGNALS = ("SIGSEGV", "SIGILL", "SIGFPE", "SIGABRT", "SIGBUS", "SIGTERM")
"""The signals whose handlers glog's failure handler takes over."""


@contextlib.contextmanager
def _signal_handlers_kept() -> Iterator[None]:
    """The process's handlers of :data:`_GLOG_SIGNALS` as they were before the block, whatever it
    installed: saved and restored with the C library's ``sigaction`` (opaque bytes, from any thread;
    nothing where ctypes cannot reach it)."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        sigaction = libc.sigaction
    except (OSError, AttributeError):
        yield
        return
    numbers = [int(getattr(signal, name)) for name in _GLOG_SIGNALS if hasattr(signal, name)]
    saved = {}
    for num in numbers:
        buf = ctypes.create_string_buffer(512)  # larger than any platform's struct sigaction
        if sigaction(num, None, buf) == 0:
            saved[num] = buf
    try:
        yield
    finally:
        for num, buf in saved.items():
            sigaction(num, buf, None)


def load_pycolmap() -> Any:
    """pycolmap, imported with the process's signal handlers kept: importing it installs glog's
    failure handler, which answers ``kill`` (SIGTERM) with a native stack trace and the process's end,
    past GeoCon's own handler (which stops a run cleanly, keeping records and recordings whole)."""
    if "pycolmap" not in sys.modules:
        with _signal_handlers_kept():
            import pycolmap  # noqa: F401
    return sys.modules["pycolmap"]


def bundle_adjust(
    table: TrackTable,
    K: np.ndarray,
    size: tuple[int, int],
    poses: dict[int, np.ndarray],
    points: dict[int, np.ndarray],
    cfg: MultiViewConfig,
    loss_px: float,
    *,
    focal: dict[int, float] | None = None,
    refine_intrinsics: bool = False,
    k1: float = 0.0,
    fixed_points: bool = False,
) -> tuple[dict[int, np.ndarray], dict[int, np.ndarray], dict[int, np.ndarray]]:
    """One bundle adjustment with pycolmap over the posed keyframes and ``points`` (track row ->
    xyz); Cauchy loss of scale ``loss_px`` (working px). ``focal`` None: one shared SIMPLE_RADIAL
    camera (focal and k1 refined when ``refine_intrinsics``); otherwise one SIMPLE_PINHOLE camera
    per keyframe, its focal refined. ``fixed_points`` holds the points (the rotation-only model,
    whose points lie so far that a camera's position cannot move them). Returns the refined
    poses, points and each keyframe's camera parameters."""
    pycolmap = load_pycolmap()
    pycolmap.logging.minloglevel = 2  # Ceres' and COLMAP's warnings are not the user's
    rec = pycolmap.Reconstruction()
    W, H = size
    cx, cy = float(K[0, 2]), float(K[1, 2])
    reg = sorted(poses)
    cam_of: dict[int, int] = {}
    if focal is None:
        cam = pycolmap.Camera(
            model="SIMPLE_RADIAL", width=W, height=H, params=[float(K[0, 0]), cx, cy, k1], camera_id=1
        )
        rec.add_camera_with_trivial_rig(cam)
        cam_of = {k: 1 for k in reg}
    else:
        for i, k in enumerate(reg):
            cam = pycolmap.Camera(model="SIMPLE_PINHOLE", width=W, height=H, params=[focal[k], cx, cy], camera_id=i + 1)
            rec.add_camera_with_trivial_rig(cam)
            cam_of[k] = i + 1
    seen = table.seen()
    rows = sorted(points)
    index: dict[tuple[int, int], int] = {}
    for i, k in enumerate(reg):
        obs_rows = [r for r in rows if seen[r, k]]
        kp = table.xy[obs_rows, k] if obs_rows else np.zeros((0, 2))
        img = pycolmap.Image(
            name=str(table.frames[k]), keypoints=kp.astype(np.float64), camera_id=cam_of[k], image_id=i + 1
        )
        rec.add_image_with_trivial_frame(img, pycolmap.Rigid3d(np.asarray(poses[k], dtype=np.float64)))
        for j, r in enumerate(obs_rows):
            index[(r, k)] = j
    image_id = {k: i + 1 for i, k in enumerate(reg)}
    point_id: dict[int, int] = {}
    for r in rows:
        els = [pycolmap.TrackElement(image_id[k], index[(r, k)]) for k in reg if (r, k) in index]
        if len(els) >= 2:
            point_id[r] = rec.add_point3D(np.asarray(points[r], dtype=np.float64), pycolmap.Track(els))
    options = pycolmap.BundleAdjustmentOptions()
    options.print_summary = False
    options.refine_focal_length = focal is not None or refine_intrinsics or fixed_points
    options.refine_principal_point = False
    options.refine_extra_params = focal is None and refine_intrinsics
    options.refine_points3D = not fixed_points
    options.ceres.loss_function_type = pycolmap.LossFunctionType.CAUCHY
    options.ceres.loss_function_scale = float(loss_px)
    options.ceres.solver_options.max_num_iterations = cfg.max_iterations
    options.ceres.solver_options.num_threads = 1
    if fixed_points:  # the cameras alone: each keyframe's pose is its own block, tied to the others
        # by the shared focal only, so sparse normal equations solve it in a fraction of the time of
        # a dense QR of the whole Jacobian (the same cameras, the same residuals to 1e-8 px on the
        # validation clips), on one thread
        options.ceres.auto_select_solver_type = False
        solvers = type(options.ceres.solver_options.linear_solver_type)
        options.ceres.solver_options.linear_solver_type = solvers.SPARSE_NORMAL_CHOLESKY
    config = pycolmap.BundleAdjustmentConfig()
    for k in reg:
        config.add_image(image_id[k])
    if fixed_points:
        for pid in point_id.values():
            config.add_constant_point(pid)
    else:
        config.fix_gauge(pycolmap.BundleAdjustmentGauge.TWO_CAMS_FROM_WORLD)
    pycolmap.create_default_bundle_adjuster(options, config, rec).solve()
    out_poses = {k: rec.image(image_id[k]).cam_from_world().matrix() for k in reg}
    out_points = {r: np.asarray(rec.point3D(pid).xyz, dtype=np.float64) for r, pid in point_id.items()}
    params = {k: np.asarray(rec.camera(cam_of[k]).params, dtype=np.float64) for k in reg}
    return out_poses, out_points, params


def project(pose: np.ndarray, params: np.ndarray, X: np.ndarray) -> np.ndarray:
    """Pixels (N, 2) of points X (N, 3) under a SIMPLE_PINHOLE (f, cx, cy) or SIMPLE_RADIAL
    (f, cx, cy, k) camera; NaN behind the camera."""
    Xc = X @ pose[:, :3].T + pose[:, 3]
    z = Xc[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u, v = Xc[:, 0] / z, Xc[:, 1] / z
    if len(params) > 3:
        d = 1 + params[3] * (u * u + v * v)
        u, v = u * d, v * d
    out = np.c_[params[0] * u + params[1], params[0] * v + params[2]]
    out[~(z > 0)] = np.nan
    return out


def ba_subset(table: TrackTable, rows: list[int], n: int, size: tuple[int, int]) -> list[int]:
    """Up to ``n`` of ``rows`` for the bundle adjustment: the longest-lived tracks of each cell of
    an 8x8 grid over the frame, in turn (deterministic)."""
    if len(rows) <= n:
        return rows
    seen = table.seen()
    W, H = size
    life = seen[rows].sum(axis=1)
    first = np.nanmean(table.xy[rows], axis=1)
    cell = (np.clip(first[:, 1] * 8 // H, 0, 7) * 8 + np.clip(first[:, 0] * 8 // W, 0, 7)).astype(int)
    order = np.lexsort((np.asarray(rows), -life, cell))
    rank = np.zeros(len(rows), int)
    for c in np.unique(cell):
        members = order[cell[order] == c]
        rank[members] = np.arange(len(members))
    pick = np.lexsort((np.asarray(rows), -life, rank))[:n]
    return sorted(int(rows[i]) for i in pick)
