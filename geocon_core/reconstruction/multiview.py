"""One camera for the whole clip: long tracks, one bundle adjustment, and the layers that drift.

The paper's protocol fits one model per frame pair, and a background layer that drifts slowly
against the rest (the "sliding wallpaper" of generated walk-throughs) is a valid static scene
at another depth in any two views. Over the whole clip it is not: the clip must agree with one
camera path and one set of 3D points. This module

1. follows corners through every frame with pyramidal Lucas-Kanade (:class:`LongTracks`, the
   object masks applied as for the pair fits) and keeps their positions at up to
   ``max_views`` evenly spread keyframes;
2. builds one reconstruction (:func:`reconstruct`): for a clip the gate calls F, an essential
   matrix between the first keyframe and the farthest one that shares enough tracks, then
   every other keyframe by PnP, points triangulated as they become visible; for a clip the gate
   calls H, rotations (and a focal length per keyframe, so zooms are judged) chained from
   keyframe to keyframe, every point at infinity. Both are refined by **pycolmap's bundle
   adjuster** (Ceres; a Cauchy loss): poses, points and the focal length (shared and with one
   radial term for F; per keyframe for H, whose camera centres stay at one point through a
   pose prior);
3. measures each track's reprojection residual over its life (source px), the share of tracks
   consistent with the reconstruction (MV-IR, residual at most ``tau_px``) and their median
   residual (MV-GE), and groups the inconsistent tracks into spatially coherent layers whose
   residuals drift the same way (:class:`DriftLayer`: "this region drifts ~N px against the
   camera path between frames a and b").

A reconstruction that leaves most tracks inconsistent, registers too few keyframes or has too
few tracks cannot judge the clip (``MultiViewResult.reason``); it never flags one.
"""

from __future__ import annotations

import contextlib
import ctypes
import math
import signal
import sys
import warnings
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

from ..config import MultiViewConfig
from ..geometry import good_corners, lk_forward_backward, refine_points, triangulate_views

__all__ = [
    "ARRAY_NAMES",
    "LongTracks",
    "TrackObservations",
    "DriftLayer",
    "MultiViewResult",
    "keyframes",
    "reconstruct",
]

_WIN, _LEVELS = 21, 3


def keyframes(num_frames: int, max_views: int) -> tuple[int, ...]:
    """Up to ``max_views`` frames spread evenly from the first to the last (both included)."""
    if num_frames <= 0:
        return ()
    k = max(2, min(num_frames, max_views))
    return tuple(sorted({int(round(i * (num_frames - 1) / (k - 1))) for i in range(k)}))


@dataclass
class TrackObservations:
    """Where each track was at each keyframe: ``frames`` (K,) the keyframes, and per keyframe
    the ids (N_k,) int64 and positions (N_k, 2) float64 in working px of the tracks alive there."""

    frames: list[int] = field(default_factory=list)
    ids: list[np.ndarray] = field(default_factory=list)
    xy: list[np.ndarray] = field(default_factory=list)


class LongTracks:
    """Corners followed through every frame (pyramidal Lucas-Kanade, forward-backward checked)
    on a grey image whose long side is at most ``config.track_side``; a track ends where it
    leaves the usable mask (content minus objects). Corners are detected again, away from the
    live tracks, when fewer than 80% of ``config.max_tracks`` are left. :meth:`observe` must see
    the frames in order; the positions at the keyframes are kept (:attr:`observations`)."""

    def __init__(self, config: MultiViewConfig, num_frames: int, working_size: tuple[int, int]) -> None:
        self.config = config
        self.keyframes = frozenset(keyframes(num_frames, config.max_views))
        W, H = working_size
        self.scale = min(1.0, config.track_side / max(W, H))
        self._size = (max(16, round(W * self.scale)), max(16, round(H * self.scale)))
        self._prev: np.ndarray | None = None
        self._prev_t = -2
        self._ids = np.zeros(0, np.int64)
        self._xy = np.zeros((0, 2), np.float32)
        self._next_id = 0
        self.observations = TrackObservations()

    def observe(self, t: int, gray: np.ndarray, usable: np.ndarray) -> None:
        """Follow the tracks into frame ``t`` (grey, working px) whose usable pixels are ``usable`` (bool)."""
        cfg = self.config
        g = gray if self.scale == 1.0 else cv2.resize(gray, self._size, interpolation=cv2.INTER_AREA)
        m = (
            usable
            if self.scale == 1.0
            else cv2.resize(usable.astype(np.uint8), self._size, interpolation=cv2.INTER_NEAREST) > 0
        )
        m = cv2.erode(m.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0  # away from mask edges
        ids, xy = self._ids[:0], self._xy[:0]
        if self._prev is not None and self._prev_t == t - 1 and len(self._ids):
            p1, ok = lk_forward_backward(self._prev, g, self._xy, m, cfg.fb_px, _WIN, _LEVELS)
            ids, xy = self._ids[ok], p1[ok].astype(np.float32)
        if len(ids) < 0.8 * cfg.max_tracks:
            free = m.astype(np.uint8) * 255
            for x, y in np.round(xy).astype(int):
                cv2.circle(free, (int(x), int(y)), cfg.min_distance, 0, -1)
            new = good_corners(g, free, cfg.max_tracks - len(ids), cfg.min_distance)
            ids = np.concatenate([ids, np.arange(self._next_id, self._next_id + len(new), dtype=np.int64)])
            xy = np.concatenate([xy, new]).astype(np.float32)
            self._next_id += len(new)
        self._prev, self._prev_t, self._ids, self._xy = g, t, ids, xy
        if t in self.keyframes:
            obs = self.observations
            obs.frames.append(t)
            obs.ids.append(ids.copy())
            obs.xy.append(xy.astype(np.float64) / self.scale)


@dataclass(frozen=True)
class DriftLayer:
    """A spatially coherent group of tracks whose residuals drift the same way against the
    one reconstruction: a background layer that slides against the camera path."""

    tracks: int
    """Tracks in the layer."""
    share: float
    """Their share of the judged tracks."""
    drift_px: float
    """How far their residuals drift over the frames the layer spans (the median slope of a line
    fitted to each track's residual, times those frames), source px: the drift against the best
    static explanation of each track, which can exceed the planted one (a track's best static
    point trades the part of a slide along its epipolar line for depth)."""
    direction: tuple[float, float]
    """Unit image direction of that drift (x right, y down)."""
    box: tuple[float, float, float, float]
    """(x0, y0, x1, y1) of the layer's tracks at their middle keyframe, source px."""
    frames: tuple[int, int]
    """First and last frame the layer's tracks were seen at."""
    track_ids: tuple[int, ...] = ()
    """The ids of the layer's tracks (:attr:`MultiViewResult.track_ids`)."""

    def describe(self) -> str:
        return (
            f"one layer drifts against the camera path: {self.tracks} tracks "
            f"({100 * self.share:.0f}%) around x {self.box[0]:.0f}-{self.box[2]:.0f}, "
            f"y {self.box[1]:.0f}-{self.box[3]:.0f} "
            f"drift ~{self.drift_px:.1f} px from where one camera path puts them, "
            f"between frames {self.frames[0]} and {self.frames[1]}"
        )

    def to_dict(self) -> dict[str, Any]:
        return {
            "tracks": self.tracks,
            "share": self.share,
            "drift_px": self.drift_px,
            "direction": list(self.direction),
            "box": list(self.box),
            "frames": list(self.frames),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "DriftLayer":
        return cls(
            int(d["tracks"]),
            float(d["share"]),
            float(d["drift_px"]),
            (float(d["direction"][0]), float(d["direction"][1])),
            tuple(float(v) for v in d["box"]),  # type: ignore[arg-type]
            (int(d["frames"][0]), int(d["frames"][1])),
        )


@dataclass(frozen=True)
class MultiViewResult:
    """The clip's one reconstruction and what it measures. Image quantities in source px."""

    model: str
    """``F`` (general motion, shared focal and radial term) or ``H`` (rotation only, points at
    infinity, a focal per keyframe)."""
    frames: tuple[int, ...]
    """The keyframes."""
    registered: tuple[int, ...]
    """The keyframes the reconstruction holds a pose for."""
    mv_ir: float | None
    """Share of judged tracks whose RMS residual is at most ``tau_px``."""
    mv_ge: float | None
    """Median RMS residual of the judged tracks, source px."""
    tracks: int
    """Tracks judged (seen at ``min_views`` registered keyframes or more)."""
    layers: tuple[DriftLayer, ...] = ()
    """Drifting layers, largest first."""
    reason: str | None = None
    """Why the reconstruction cannot judge the clip (None: it can)."""
    focal_px: float | None = None
    """Refined focal length (F: the shared one; H: the first keyframe's), working px."""
    floor_px: float | None = None
    """The noise floor: median residual of the judged tracks outside any layer, source px."""
    cam_from_world: np.ndarray | None = field(default=None, repr=False, compare=False)
    """(R, 3, 4) poses of the registered keyframes (the world is the first keyframe's camera)."""
    points: np.ndarray | None = field(default=None, repr=False, compare=False)
    """(P, 3) 3D points of the judged tracks (H: unit directions)."""
    residual: np.ndarray | None = field(default=None, repr=False, compare=False)
    """(P,) RMS residual of each judged track, source px."""
    track_ids: np.ndarray | None = field(default=None, repr=False, compare=False)
    """(P,) the judged tracks' ids."""
    track_xy: np.ndarray | None = field(default=None, repr=False, compare=False)
    """(P, 2) each judged track's position at its middle keyframe, source px."""
    track_frame: np.ndarray | None = field(default=None, repr=False, compare=False)
    """(P,) that middle keyframe (frame index)."""
    layer_of: np.ndarray | None = field(default=None, repr=False, compare=False)
    """(P,) index into :attr:`layers` of each judged track's layer, -1 for none."""

    @property
    def judged(self) -> bool:
        return self.reason is None

    @property
    def flagged(self) -> bool:
        return self.judged and bool(self.layers)

    def summary(self) -> dict[str, Any]:
        """The short JSON form kept in a record's summary."""
        return {
            "model": self.model,
            "keyframes": len(self.frames),
            "registered": len(self.registered),
            "mv_ir": self.mv_ir,
            "mv_ge": self.mv_ge,
            "tracks": self.tracks,
            "focal_px": self.focal_px,
            "floor_px": self.floor_px,
            "layers": [layer.to_dict() for layer in self.layers],
            "reason": self.reason,
        }

    def to_json_dict(self) -> dict[str, Any]:
        """The JSON form kept in ``record.json`` (the arrays go to ``matches.npz``, :meth:`arrays`)."""
        return {**self.summary(), "frames": list(self.frames), "registered": list(self.registered)}

    def arrays(self) -> dict[str, np.ndarray]:
        """The arrays kept in ``matches.npz`` (names of :data:`ARRAY_NAMES`), empty when there are none."""
        if (
            self.cam_from_world is None
            or self.points is None
            or self.residual is None
            or self.track_ids is None
            or self.track_xy is None
            or self.track_frame is None
            or self.layer_of is None
        ):
            return {}
        return {
            "mv_cam_from_world": self.cam_from_world,
            "mv_points": self.points,
            "mv_residual": self.residual,
            "mv_track_ids": self.track_ids,
            "mv_track_xy": self.track_xy,
            "mv_track_frame": self.track_frame,
            "mv_layer_of": self.layer_of,
        }

    @classmethod
    def from_parts(cls, d: dict[str, Any], z: dict[str, np.ndarray]) -> "MultiViewResult":
        """The result of its :meth:`to_json_dict` form and the record's arrays."""
        has = "mv_points" in z
        return cls(
            model=str(d["model"]),
            frames=tuple(int(v) for v in d["frames"]),
            registered=tuple(int(v) for v in d["registered"]),
            mv_ir=None if d["mv_ir"] is None else float(d["mv_ir"]),
            mv_ge=None if d["mv_ge"] is None else float(d["mv_ge"]),
            tracks=int(d["tracks"]),
            layers=tuple(DriftLayer.from_dict(layer) for layer in d["layers"]),
            reason=d["reason"],
            focal_px=None if d.get("focal_px") is None else float(d["focal_px"]),
            floor_px=None if d.get("floor_px") is None else float(d["floor_px"]),
            cam_from_world=z["mv_cam_from_world"] if has else None,
            points=z["mv_points"] if has else None,
            residual=z["mv_residual"] if has else None,
            track_ids=z["mv_track_ids"] if has else None,
            track_xy=z["mv_track_xy"] if has else None,
            track_frame=z["mv_track_frame"] if has else None,
            layer_of=z["mv_layer_of"] if has else None,
        )


ARRAY_NAMES = (
    "mv_cam_from_world",
    "mv_points",
    "mv_residual",
    "mv_track_ids",
    "mv_track_xy",
    "mv_track_frame",
    "mv_layer_of",
)
"""The arrays of a multi-view result in a record's ``matches.npz``."""


# ---------------------------------------------------------------------------------------------
# the track table


@dataclass
class _Table:
    """Tracks x keyframes: ``xy`` (T, K, 2) working px (NaN where unseen) and ``ids`` (T,)."""

    frames: tuple[int, ...]
    ids: np.ndarray
    xy: np.ndarray

    @classmethod
    def of(cls, obs: TrackObservations, min_views: int) -> "_Table":
        frames = tuple(obs.frames)
        all_ids = np.unique(np.concatenate(obs.ids)) if obs.ids else np.zeros(0, np.int64)
        xy = np.full((len(all_ids), len(frames), 2), np.nan)
        for k, (ids, pts) in enumerate(zip(obs.ids, obs.xy, strict=True)):
            xy[np.searchsorted(all_ids, ids), k] = pts
        seen = np.isfinite(xy[..., 0]).sum(axis=1)
        keep = seen >= min_views
        return cls(frames, all_ids[keep], xy[keep])

    def seen(self) -> np.ndarray:
        return np.isfinite(self.xy[..., 0])


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


def _undistort(xy: np.ndarray, params: np.ndarray) -> np.ndarray:
    """Pixels of a SIMPLE_RADIAL camera (f, cx, cy, k) -> the pixels of its pinhole (f, cx, cy)."""
    if len(params) < 4 or params[3] == 0:
        return xy
    f, cx, cy, k = params[:4]
    d = (xy - (cx, cy)) / f
    u = d.copy()
    for _ in range(10):
        u = d / (1 + k * np.sum(u * u, axis=-1, keepdims=True))
    return u * f + (cx, cy)


def _points(
    table: _Table,
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


def _init_general(
    table: _Table, K: np.ndarray, cfg: MultiViewConfig
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
        sub = _Table(table.frames, table.ids, np.where(np.isin(np.arange(nk), [0, b])[None, :, None], table.xy, np.nan))
        pts = _points(sub, K, poses, rows, 0.0)
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
    points = _points(table, K, poses, np.arange(len(table.ids)), cfg.min_angle_deg / 2)
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
        points.update(_points(table, K, poses, pending, cfg.min_angle_deg / 2))
    return poses, points


def _init_rotation(
    table: _Table, K: np.ndarray, seed: int, min_common: int
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
        Kp = _with_focal(K, focal[ref])
        Hm, _ = cv2.findHomography(a, b, cv2.RANSAC, 1.0)
        zoom = 1.0
        if Hm is not None:
            # K^-1 H K = diag(s, s, 1) R up to scale for a turn and a zoom s: the rows of R have unit length
            M = np.linalg.inv(Kp) @ Hm @ Kp
            rows = np.linalg.norm(M, axis=1)
            zoom = float((rows[0] + rows[1]) / (2 * rows[2])) if rows[2] > 0 else 1.0
            zoom = zoom if 0.5 < zoom < 2.0 else 1.0
        fk = focal[ref] * zoom
        R, ok = _robust_rotation(_bearings(a, Kp), _bearings(b, _with_focal(K, fk)), 1.0 / fk, rng)
        if ok.sum() < 10:
            continue
        rot[k], focal[k] = R @ rot[ref], fk
        agreed[np.flatnonzero(common)[~ok]] = False
    return rot, focal, agreed


def _with_focal(K: np.ndarray, f: float) -> np.ndarray:
    out = K.copy()
    out[0, 0] = out[1, 1] = f
    return out


def _directions(
    table: _Table, poses: dict[int, np.ndarray], params: dict[int, np.ndarray], K: np.ndarray
) -> np.ndarray:
    """(T, 3) each track's point in the world of a rotation-only reconstruction, at distance
    :data:`_FAR`: the mean of its rays from the cameras that see it (NaN for a track seen at
    fewer than two posed keyframes). A camera's position, left free by the adjuster, is taken
    into account (it moves such far points by a near-uniform shift)."""
    seen = table.seen()
    acc = np.zeros((len(table.ids), 3))
    count = np.zeros(len(table.ids))
    for k, P in poses.items():
        rows = np.flatnonzero(seen[:, k])
        R, t = P[:, :3], P[:, 3]
        ray = _bearings(table.xy[rows, k], _with_focal(K, float(params[k][0])))
        acc[rows] += (ray * _FAR - t) @ R  # R^T (lambda ray - t)
        count[rows] += 1
    out = acc / np.maximum(count, 1)[:, None]
    out = out / np.maximum(np.linalg.norm(out, axis=1, keepdims=True), 1e-12) * _FAR
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


def _pycolmap() -> Any:
    """pycolmap, imported with the process's signal handlers kept: importing it installs glog's
    failure handler, which answers ``kill`` (SIGTERM) with a native stack trace and the process's end,
    past GeoCon's own handler (which stops a run cleanly, keeping records and recordings whole)."""
    if "pycolmap" not in sys.modules:
        with _signal_handlers_kept():
            import pycolmap  # noqa: F401
    return sys.modules["pycolmap"]


def _adjust(
    table: _Table,
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
    pycolmap = _pycolmap()
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


def _project(pose: np.ndarray, params: np.ndarray, X: np.ndarray) -> np.ndarray:
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


def _subset(table: _Table, rows: list[int], n: int, size: tuple[int, int]) -> list[int]:
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


# ---------------------------------------------------------------------------------------------
# what the reconstruction measures


def reconstruct(
    obs: TrackObservations,
    K: np.ndarray,
    size: tuple[int, int],
    model: str,
    config: MultiViewConfig,
    *,
    px_scale: float = 1.0,
    seed: int = 0,
) -> MultiViewResult:
    """One reconstruction of the tracks ``obs`` (working px, frame size ``size`` = (W, H), prior
    intrinsics ``K``) under ``model`` (the gate's ``F`` or ``H``), and what it measures.
    ``px_scale`` is working px per source px (residuals and drifts are reported in source px)."""
    cfg = config
    frames = tuple(obs.frames)
    table = _Table.of(obs, cfg.min_views)

    def cannot(reason: str, registered: tuple[int, ...] = ()) -> MultiViewResult:
        return MultiViewResult(model, frames, registered, None, None, 0, reason=reason)

    if len(frames) < cfg.min_views:
        return cannot(f"{len(frames)} keyframes, fewer than {cfg.min_views}")
    if len(table.ids) < cfg.min_tracks:
        return cannot(f"{len(table.ids)} tracks seen at {cfg.min_views} keyframes or more, fewer than {cfg.min_tracks}")
    loss_px = cfg.loss_px * px_scale
    need = max(cfg.min_views, math.ceil(cfg.min_registered * len(frames)))
    if model == "H":
        rot, focal, keep = _init_rotation(table, K, seed, cfg.min_init_tracks)
        if len(rot) < need:
            return cannot(f"{len(rot)} of {len(frames)} keyframes chained", tuple(frames[k] for k in sorted(rot)))
        poses = {k: np.c_[R, np.zeros(3)] for k, R in rot.items()}
        zoom = max(abs(f / float(K[0, 0]) - 1) for f in focal.values()) > cfg.zoom_share
        params = {k: np.array([focal[k] if zoom else float(K[0, 0]), K[0, 2], K[1, 2]]) for k in rot}
        for _ in range(cfg.rotation_rounds):  # alternate: cameras with the points held, then the points
            poses, params, pts, keep = _rotation_round(table, K, size, poses, params, keep, zoom, cfg, px_scale)
        result = _measure(table, poses, pts, params, model, cfg, px_scale)
        if result.layers:  # once more without the layers: the cameras judge them from the rest
            keep &= ~np.isin(table.ids, _layer_ids(result))
            poses, params, pts, _ = _rotation_round(table, K, size, poses, params, keep, zoom, cfg, px_scale)
            result = _measure(table, poses, pts, params, model, cfg, px_scale)
        return result
    init = _init_general(table, K, cfg)
    if init is None:
        return cannot("no keyframe pair has the baseline to start a reconstruction")
    poses, points = init
    if len(poses) < need:
        return cannot(f"{len(poses)} of {len(frames)} keyframes registered", tuple(frames[k] for k in sorted(poses)))
    rows = _subset(table, sorted(points), cfg.ba_tracks, size)
    poses, sub, params = _adjust(table, K, size, poses, {r: points[r] for r in rows}, cfg, loss_px)
    # the tracks that agree with the first adjustment make the second (a drifting layer is
    # left out of the cameras that judge it), which may refine the intrinsics
    X = _stack({**points, **sub}, len(table.ids))
    rms = _rms(table, poses, params, X, px_scale)
    keep = rms <= min(cfg.tau_px, cfg.keep_factor * float(np.median(rms[np.isfinite(rms)])))
    rows = _subset(table, [r for r in sorted(points) if keep[r]], cfg.ba_tracks, size)
    poses, sub, params = _adjust(table, K, size, poses, {r: sub.get(r, points[r]) for r in rows}, cfg, loss_px)
    if cfg.refine_intrinsics:  # kept only where the clip pins them down (see MultiViewConfig)
        refined = _adjust(table, K, size, poses, sub, cfg, loss_px, refine_intrinsics=True)
        f = float(next(iter(refined[2].values()))[0]) / float(K[0, 0])
        before, after = (
            float(np.median(_rms(table, p, c, _stack(pts, len(table.ids)), px_scale)[rows]))
            for p, pts, c in ((poses, sub, params), refined)
        )
        if 1 / cfg.max_focal_ratio <= f <= cfg.max_focal_ratio and after <= (1 - cfg.refine_gain) * before:
            poses, sub, params = refined
    result = _measure(table, poses, _all_points(table, K, poses, params, sub), params, model, cfg, px_scale)
    if result.layers:  # once more without the layers: the cameras judge them from the rest
        out = np.isin(table.ids, _layer_ids(result))
        rows = [r for r in rows if not out[r]]
        poses, sub, params = _adjust(
            table, K, size, poses, {r: sub[r] for r in rows if r in sub}, cfg, loss_px, k1=_k1(params)
        )
        result = _measure(table, poses, _all_points(table, K, poses, params, sub), params, model, cfg, px_scale)
    return result


def _k1(params: dict[int, np.ndarray]) -> float:
    cam = next(iter(params.values()))
    return float(cam[3]) if len(cam) > 3 else 0.0


def _layer_ids(result: MultiViewResult) -> np.ndarray:
    """The ids of the tracks in any of ``result``'s layers."""
    if result.track_ids is None or result.layer_of is None:
        return np.zeros(0, np.int64)
    return result.track_ids[result.layer_of >= 0]


def _all_points(
    table: _Table,
    K: np.ndarray,
    poses: dict[int, np.ndarray],
    params: dict[int, np.ndarray],
    adjusted: dict[int, np.ndarray],
) -> dict[int, np.ndarray]:
    """Every track's point: the adjusted ones as adjusted, the others triangulated with the
    adjusted cameras (their pixels undistorted)."""
    cam = next(iter(params.values()))
    undistorted = _Table(table.frames, table.ids, _undistort(table.xy, cam))
    pts = _points(undistorted, _with_focal(K, float(cam[0])), poses, np.arange(len(table.ids)), 0.0, refine=True)
    pts.update(adjusted)
    return pts


def _rotation_round(
    table: _Table,
    K: np.ndarray,
    size: tuple[int, int],
    poses: dict[int, np.ndarray],
    params: dict[int, np.ndarray],
    keep: np.ndarray,
    zoom: bool,
    cfg: MultiViewConfig,
    px_scale: float,
) -> tuple[dict[int, np.ndarray], dict[int, np.ndarray], dict[int, np.ndarray], np.ndarray]:
    """One round of the rotation-only model: the cameras adjusted to the far points of the
    ``keep`` tracks (held), then every point again from its rays. Returns the cameras, their
    parameters, the points and the tracks to keep in the next round."""
    far = _directions(table, poses, params, K)
    rows = _subset(table, [int(r) for r in np.flatnonzero(keep & np.isfinite(far[:, 0]))], cfg.ba_tracks, size)
    focal = {k: float(p[0]) for k, p in params.items()} if zoom else None
    poses, _, params = _adjust(
        table, K, size, poses, {r: far[r] for r in rows}, cfg, cfg.loss_px * px_scale, focal=focal, fixed_points=True
    )
    far = _directions(table, poses, params, K)
    rms = _rms(table, poses, params, far, px_scale)
    keep = keep & (rms <= min(cfg.tau_px, cfg.keep_factor * float(np.median(rms[np.isfinite(rms)]))))
    pts = {int(r): far[r] for r in np.flatnonzero(np.isfinite(far[:, 0]))}
    return poses, params, pts, keep


def _stack(points: dict[int, np.ndarray], n: int) -> np.ndarray:
    """(n, 3) the points of rows ``points`` (NaN for the others)."""
    X = np.full((n, 3), np.nan)
    for r, x in points.items():
        X[r] = x
    return X


def _rms(
    table: _Table, poses: dict[int, np.ndarray], params: dict[int, np.ndarray], X: np.ndarray, px_scale: float
) -> np.ndarray:
    """(T,) RMS reprojection residual (source px) of each track's point ``X`` (T, 3) over the
    posed keyframes that see it; inf where it has no point."""
    seen = table.seen()
    sq = np.zeros(len(table.ids))
    count = np.zeros(len(table.ids))
    for k in poses:
        d = table.xy[:, k] - _project(poses[k], params[k], np.nan_to_num(X))
        e = np.sum(d * d, axis=1)
        ok = seen[:, k] & np.isfinite(e)
        sq[ok] += e[ok]
        count[ok] += 1
    out = np.sqrt(sq / np.maximum(count, 1)) / px_scale
    out[(count < 2) | ~np.all(np.isfinite(X), axis=1)] = np.inf
    return out


_FAR = 1e6
"""Distance of the points of a rotation-only reconstruction: so far that a camera's position
(left free by the adjuster) cannot move them in the image."""


def _measure(
    table: _Table,
    poses: dict[int, np.ndarray],
    points: dict[int, np.ndarray],
    params: dict[int, np.ndarray],
    model: str,
    cfg: MultiViewConfig,
    px_scale: float,
) -> MultiViewResult:
    frames = table.frames
    reg = sorted(poses)
    seen = table.seen()
    rows = [r for r in sorted(points) if sum(seen[r, k] for k in reg) >= cfg.min_views]
    nk = len(frames)
    err = np.full((len(rows), nk, 2), np.nan)
    X = np.array([points[r] for r in rows]) if rows else np.zeros((0, 3))
    for k in reg:
        proj = _project(poses[k], params[k], X)
        err[:, k] = np.where(seen[rows, k][:, None], table.xy[rows, k] - proj, np.nan)
    err /= px_scale  # working -> source px
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        rms = np.sqrt(np.nanmean(np.sum(err**2, axis=2), axis=1))
    good = np.isfinite(rms)
    rows = [r for r, g in zip(rows, good, strict=True) if g]
    err, rms, X = err[good], rms[good], X[good]
    registered = tuple(frames[k] for k in reg)
    focal_px = float(params[reg[0]][0]) if reg else None
    if len(rows) < cfg.min_tracks:
        return MultiViewResult(
            model,
            frames,
            registered,
            None,
            None,
            len(rows),
            reason=f"{len(rows)} tracks judged, fewer than {cfg.min_tracks}",
        )
    inlier = rms <= cfg.tau_px
    mv_ir, mv_ge = float(inlier.mean()), float(np.median(rms))
    # each track's middle keyframe position, and the drift of its residual: a line fitted to the
    # residual over the frames it was seen at (a drifting layer's tracks share its slope,
    # however long each of them lives)
    mid = np.zeros((len(rows), 2))
    mid_frame = np.zeros(len(rows), np.int64)
    slope = np.zeros((len(rows), 2))
    sig = np.zeros(len(rows), bool)
    span = np.zeros((len(rows), 2), int)
    fr = np.asarray(frames, dtype=float)
    for i, r in enumerate(rows):
        ks = [k for k in reg if seen[r, k]]
        mid[i] = table.xy[r, ks[len(ks) // 2]] / px_scale
        mid_frame[i] = frames[ks[len(ks) // 2]]
        span[i] = (frames[ks[0]], frames[ks[-1]])
        t = fr[ks] - fr[ks].mean()
        e = err[i, ks]
        tt = float(t @ t)
        if tt <= 0:
            continue
        slope[i] = t @ (e - e.mean(axis=0)) / tt
        fit = e.mean(axis=0) + t[:, None] * slope[i]
        dof = max(1, len(ks) - 2)
        stderr = math.sqrt(float(np.sum((e - fit) ** 2)) / (2 * dof) / tt)
        drift = float(np.linalg.norm(slope[i])) * (span[i, 1] - span[i, 0])
        sig[i] = drift >= cfg.track_drift_px and float(np.linalg.norm(slope[i])) >= cfg.slope_sigmas * stderr
    layers, layer_of = _layers(mid, slope, span, sig, cfg, table.ids[rows])
    floor = float(np.median(rms[layer_of < 0])) if np.any(layer_of < 0) else None
    reason = None
    if floor is not None and floor > cfg.max_floor_px:
        reason = (
            f"the tracks fit one camera path to within {floor:.2f} px only (median outside any layer; "
            f"more than {cfg.max_floor_px:g} px): a slow drift cannot be told from that noise"
        )
        layers, layer_of = (), np.full(len(rows), -1)
    elif 1 - mv_ir > cfg.max_outlier_share:
        reason = (
            f"{100 * (1 - mv_ir):.0f}% of the tracks disagree with the reconstruction "
            f"(more than {100 * cfg.max_outlier_share:.0f}%)"
        )
        layers, layer_of = (), np.full(len(rows), -1)
    return MultiViewResult(
        model,
        frames,
        registered,
        mv_ir,
        mv_ge,
        len(rows),
        layers,
        reason,
        focal_px,
        floor,
        np.stack([poses[k] for k in reg]),
        X / np.linalg.norm(X, axis=1, keepdims=True) if model == "H" else X,
        rms,
        table.ids[rows],
        mid,
        mid_frame,
        layer_of,
    )


def _layers(
    mid: np.ndarray,
    slope: np.ndarray,
    span: np.ndarray,
    drifting: np.ndarray,
    cfg: MultiViewConfig,
    ids: np.ndarray,
) -> tuple[tuple[DriftLayer, ...], np.ndarray]:
    """Group the drifting tracks into layers: neighbours closer than ``layer_radius`` of the
    tracks' extent whose drifts (``slope``, source px per frame) point the same way (cosine >=
    ``layer_cosine``) are joined; a group is a layer when it holds ``layer_min_tracks`` and
    ``layer_min_share`` of the tracks and its median slope carries it ``drift_px`` or more over
    the frames its tracks span."""
    n = len(mid)
    layer_of = np.full(n, -1)
    if drifting.sum() < cfg.layer_min_tracks:
        return (), layer_of
    extent = mid.max(axis=0) - mid.min(axis=0)
    radius = cfg.layer_radius * float(np.hypot(*extent))
    mag = np.linalg.norm(slope, axis=1)
    unit = slope / np.maximum(mag, 1e-12)[:, None]
    near = np.linalg.norm(mid[:, None] - mid[None], axis=2) <= radius
    np.fill_diagonal(near, False)
    agree = near & drifting[None, :] & drifting[:, None] & ((unit @ unit.T) >= cfg.layer_cosine)
    # a core track drifts with most of its neighbours (a region that slides, not stray tracks)
    core = drifting & (agree.sum(axis=1) >= np.maximum(3, cfg.layer_core_share * near.sum(axis=1)))
    idx = np.flatnonzero(core)
    parent = np.arange(len(idx))
    pos = {int(t): i for i, t in enumerate(idx)}
    d = slope[idx]
    p = mid[idx]
    mag = mag[idx]

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return int(i)

    for i, j in zip(*np.nonzero(np.triu(agree[np.ix_(idx, idx)], 1)), strict=True):
        ri, rj = root(int(i)), root(int(j))
        if ri != rj:
            parent[max(ri, rj)] = min(ri, rj)
    members_of: dict[int, list[int]] = {}
    for i in range(len(idx)):
        members_of.setdefault(root(i), []).append(int(idx[i]))
    # a drifting track beside a core track of a layer joins it
    for t in np.flatnonzero(drifting & ~core):
        cores = [pos[int(j)] for j in np.flatnonzero(agree[t] & core)]
        if cores:
            members_of[root(cores[0])].append(int(t))
    idx = np.arange(n)
    d, p, mag = slope, mid, np.linalg.norm(slope, axis=1)
    groups = {g: m for g, m in members_of.items()}
    found = []
    for members in groups.values():
        m = np.asarray(members)
        if len(m) < cfg.layer_min_tracks or len(m) / n < cfg.layer_min_share:
            continue
        vec = np.median(d[m], axis=0)
        frames_spanned = int(span[idx[m], 1].max() - span[idx[m], 0].min())
        size = float(np.linalg.norm(vec)) * frames_spanned
        if size < cfg.drift_px:
            continue
        box = (*p[m].min(axis=0), *p[m].max(axis=0))
        found.append((len(m), m, vec, size, box))
    found.sort(key=lambda f: -f[0])
    layers = []
    for li, (count, m, vec, size, box) in enumerate(found):
        layer_of[idx[m]] = li
        direction = vec / max(1e-9, float(np.linalg.norm(vec)))
        layers.append(
            DriftLayer(
                count,
                count / n,
                size,
                (float(direction[0]), float(direction[1])),
                tuple(float(v) for v in box),  # type: ignore[arg-type]
                (int(span[idx[m], 0].min()), int(span[idx[m], 1].max())),
                tuple(int(v) for v in ids[idx[m]]),
            )
        )
    return tuple(layers), layer_of
