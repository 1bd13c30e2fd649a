"""Relative camera pose first -> last frame, the evidence of the translation gate (SPEC section 1).

The gate needs ``t_inf = max(|tx|, |ty|, |tz|)`` of the relative pose between the first and the
last frame, on the DUSt3R scale: the scene is scaled so that the mean distance of the visible
scene points from the first camera is 1. A pose backend turns matched pixels of the two frames
into a :class:`PoseEstimate` that carries ``t_inf``, the pose ``T_cam0_camT`` (the last camera in
first-camera coordinates; its translation column is the last camera centre on that unit scale,
see :mod:`geocon_core.geometry`) and the diagnostics needed to audit the decision.

Backends
--------
``classical`` (:class:`ClassicalPose`, default, no weights)
    Two models are fitted to the matches (which should come from the background), both with
    the intrinsics ``K`` given (known, or :func:`default_intrinsics` when unknown):

    1. *Rotation only*: ``x1 ~ K R K^-1 x0``. Seeded 2-point RANSAC on unit rays (orthogonal
       Procrustes / Kabsch on each minimal sample; inlier threshold ``rot_ransac_px`` = 2 px
       on the pixel transfer error), then Levenberg-Marquardt refinement on the inliers that
       minimises the pixel transfer error. With ``fit_focal`` (default) it also fits a common
       scale s of the focal lengths (principal point fixed, prior ``log s ~ N(0, 0.2^2)``,
       bounded by ``max_focal_ratio``): the images of a rotating camera are related by
       ``K R K^-1`` for the *true* K only: with a field of view 20 % off, 12-18 degree
       rotations left 1.6-3.8 px of median residual and read as translation (t_inf up to
       0.12, i.e. F); with the focal scale free the residual is back at the noise (0.2 px). The
       per-match transfer error of this model is the *rotation-compensated parallax*.
    2. *Essential matrix*: OpenCV USAC (MAGSAC++ scoring, uniform sampling, inner local
       optimisation, seeded with ``randomGeneratorState = seed``, single-threaded, so the same
       input gives bit-identical results) on normalised camera coordinates with an inlier
       threshold of ``essential_px`` = 1 px (Sampson distance); Levenberg-Marquardt polish of
       (R, t) on the inliers (Sampson distance); the decomposition of E with the most inliers
       in front of both cameras (no distance cut-off, unlike ``cv2.recoverPose``, which drops
       points beyond 50 baselines: those far points set the mean scene distance, and dropping
       them overestimated t_inf by 3x for small translations). With ``fit_focal`` the polish
       is repeated with the focal scale s free; s is adopted only when it lowers the Sampson
       cost by at least ``focal_min_gain`` = 100 times the residual variance (a
       likelihood-ratio statistic). A field of view 20 % off under rotation + translation gives
       statistics of 140-1100 in the synthetic tests and the fitted s recovers the true focal
       ratio (0.77-0.81 for fov 48, 1.22-1.28 for fov 72); it restores t_inf (a lateral move of
       true t_inf 0.08 with 3.9 degrees of rotation reads 0.046 at fov 48 with s fixed, 0.073
       with s fitted). Noise and lens distortion in real footage stay below ~85 on
       RealEstate10K, where a freely fitted focal did more harm than good. Under pure
       translation s is not observable and stays 1; t_inf then scales with the focal error
       (about x0.8 / x1.2 for fov 48 / 72).

    *Decision.* The rotation model explains the matches when, over the geometrically
    consistent matches (the union of the inliers of both models), the median parallax is at
    most ``rot_median_px`` (1 px) and at least ``rot_share`` (80 %) of them lie within
    ``rot_share_px`` (2 px). The noise level of SIFT on rendered and real video is 0.1-0.4 px
    median, while 1 px of median parallax is a translation of about ``1/f`` (0.002-0.005 for
    f = 200-550 px), an order of magnitude below the gate thresholds (0.03 / 0.05). Then
    ``method = "rotation"`` and, to first order (mean depth 1 on the DUSt3R scale,
    ``|t_perp| / Z ~ parallax / f``), ``t_inf = median_parallax_px / f`` with
    ``f = sqrt(fx fy)`` of the given K; the translation column of ``T_cam0_camT`` is zero (a
    translation below the noise is not observable), so ``t_inf`` is the noise bound. (A
    forward move parallaxes by ``r t_z / Z`` at radius r from the principal point, so at low
    resolution t_z up to ~0.02 can stay under 1 px and read as rotation: still H, as it
    should be.)

    Otherwise (``method = "essential"``) the inliers in front of both cameras are triangulated
    (DLT, ``cv2.triangulatePoints``) with the baseline ``|t| = 1`` and the scene is scaled to
    unit mean distance from camera 0: points behind either camera are dropped, the distances
    are sorted and the ``trim`` share (5 %) at each end is dropped before the mean (near-epipole
    points with almost no parallax triangulate to wild distances). ``t_inf`` is the max-abs
    component of ``c / mean_distance`` where ``c = -R^T t`` is the last camera centre in
    camera-0 coordinates. The mean runs over the matched points, so it estimates the mean
    distance of the scene seen in both frames.

    *Failures* (``pose_present = False``, never an exception, never NaN):
    ``too_few_matches`` (fewer than ``min_matches`` = 30 finite matches), ``too_few_inliers``
    (the models keep fewer than ``max(min_inliers, min_inlier_share * n)`` = max(15, 25 %)
    matches), ``degenerate`` (the matches have no spatial extent, or E cannot be estimated or
    is not finite), ``no_cheirality`` (fewer than ``min_inliers`` inliers triangulate in
    front of both cameras).

``log`` (:class:`PoseLog`)
    A pose computed elsewhere (DUSt3R, COLMAP, ...), read from a JSON file; the matches are
    ignored. Schema (``POSE_LOG_FORMAT = "geocon-pose/1"``)::

        {
          "format": "geocon-pose/1",                  # required
          "T_cam0_camT": [[r11, r12, r13, tx], ..., [0, 0, 0, 1]],
                                                      # 4x4, last camera in first-camera
                                                      # coordinates (cam-to-world with camera
                                                      # 0 as world); required when
                                                      # pose_present is true
          "scale": "unit_mean_distance" | "metric",   # required with a pose: is the
                                                      # translation already on the DUSt3R
                                                      # scale, or in scene units?
          "mean_scene_distance": 3.7,                 # required when scale = "metric": mean
                                                      # distance of the visible scene points
                                                      # from camera 0, in the same units; the
                                                      # translation is divided by it
          "pose_present": true,                       # optional, default true; false means
                                                      # the external tool failed (the gate
                                                      # then applies fail->F)
          "source": "dust3r ViTLarge_512"             # optional free text
        }

    The rotation block must be a rotation (``R^T R = I`` and ``det R = 1`` within 1e-6) and
    the last row ``[0, 0, 0, 1]``; anything else raises ``ValueError``. A GeoCon synthetic
    ground-truth file (``"format": "geocon-synth-gt/1"``, written as ``<clip>.gt.json`` by
    ``geocon synth``) is accepted too: its ``T_cam0_camT`` is metric and its
    ``mean_scene_distance`` gives the scale, so clips can be gated with their true pose.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Protocol, runtime_checkable

import cv2
import numpy as np

from .geometry import make_pose, rotation_angle_deg
from .models import usac_params

__all__ = [
    "PoseEstimate",
    "PoseBackend",
    "ClassicalPose",
    "PoseLog",
    "POSE_BACKENDS",
    "POSE_LOG_FORMAT",
    "POSE_METHODS",
    "default_intrinsics",
    "make_pose_backend",
    "load_pose_log",
]

POSE_LOG_FORMAT = "geocon-pose/1"
_SYNTH_GT_FORMAT = "geocon-synth-gt/1"
POSE_METHODS = ("essential", "rotation", "log", "none")
_ROT_TOL = 1e-6


# --------------------------------------------------------------------------- result record


@dataclass(frozen=True, eq=False)
class PoseEstimate:
    """Relative pose first -> last frame and the evidence behind it.

    pose_present: False when no pose could be estimated (the gate then applies fail->F).
    t_inf: ``max |t|`` on the unit-mean-distance scale; None when not present.
    T_cam0_camT: (4, 4) pose of the last camera in first-camera coordinates, translation on
        the unit-mean-distance scale; None when not present. For ``method = "rotation"`` the
        translation column is zero (a translation below the noise is not observable) and
        ``t_inf`` is the first-order bound ``parallax_px / focal_px``.
    method: ``"essential"``, ``"rotation"``, ``"log"`` or ``"none"``.
    reason: reason code when not present (``"too_few_matches"``, ``"too_few_inliers"``,
        ``"degenerate"``, ``"no_cheirality"``, ``"log_no_pose"``), else None.
    n_matches: finite matches given to the backend.
    n_inliers: inliers of the model used (0 for logs and for failures before any fit).
    rotation_deg: rotation angle of the relative pose, degrees (None when unknown).
    parallax_px: median rotation-compensated parallax of the consistent matches, pixels.
    focal_px: focal length ``sqrt(fx fy)`` of the intrinsics given, pixels.
    focal_scale: focal scale adopted by self-calibration (1.0 = K as given); an addition to
        the minimal interface, defaulted so that older records still load.
    """

    pose_present: bool
    t_inf: float | None
    T_cam0_camT: np.ndarray | None
    method: str
    reason: str | None
    n_matches: int
    n_inliers: int
    rotation_deg: float | None
    parallax_px: float | None
    focal_px: float
    focal_scale: float = 1.0

    def __post_init__(self) -> None:
        if self.method not in POSE_METHODS:
            raise ValueError(f"unknown pose method {self.method!r}; valid: {', '.join(POSE_METHODS)}")
        if self.T_cam0_camT is not None:
            T = np.array(self.T_cam0_camT, dtype=float)
            if T.shape != (4, 4):
                raise ValueError(f"T_cam0_camT must be 4x4, got shape {T.shape}")
            object.__setattr__(self, "T_cam0_camT", T)
        if self.pose_present:
            if self.t_inf is None or not math.isfinite(self.t_inf) or self.t_inf < 0:
                raise ValueError(f"a present pose needs a finite, non-negative t_inf, got {self.t_inf!r}")
            if self.T_cam0_camT is None:
                raise ValueError("a present pose needs T_cam0_camT")
        elif self.t_inf is not None or self.T_cam0_camT is not None or not self.reason:
            raise ValueError("an absent pose has t_inf = None, T_cam0_camT = None and a reason code")

    def to_dict(self) -> dict[str, Any]:
        """JSON-able dict; :meth:`from_dict` inverts it exactly (arrays become nested lists)."""

        def opt(v: float | None) -> float | None:
            return None if v is None else float(v)

        return {
            "pose_present": bool(self.pose_present),
            "t_inf": opt(self.t_inf),
            "T_cam0_camT": None if self.T_cam0_camT is None else np.asarray(self.T_cam0_camT, dtype=float).tolist(),
            "method": self.method,
            "reason": self.reason,
            "n_matches": int(self.n_matches),
            "n_inliers": int(self.n_inliers),
            "rotation_deg": opt(self.rotation_deg),
            "parallax_px": opt(self.parallax_px),
            "focal_px": float(self.focal_px),
            "focal_scale": float(self.focal_scale),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "PoseEstimate":
        d = dict(d)
        T = d.get("T_cam0_camT")
        d["T_cam0_camT"] = None if T is None else np.array(T, dtype=float)
        return cls(**d)


def _failure(
    reason: str,
    n_matches: int,
    focal_px: float,
    *,
    n_inliers: int = 0,
    method: str = "none",
    parallax_px: float | None = None,
) -> PoseEstimate:
    return PoseEstimate(
        pose_present=False,
        t_inf=None,
        T_cam0_camT=None,
        method=method,
        reason=reason,
        n_matches=int(n_matches),
        n_inliers=int(n_inliers),
        rotation_deg=None,
        parallax_px=parallax_px,
        focal_px=float(focal_px),
    )


# --------------------------------------------------------------------------- intrinsics


def default_intrinsics(content_box: tuple[int, int, int, int], fov_x_deg: float) -> np.ndarray:
    """K (3x3) for unknown intrinsics: principal point at the centre of the content box
    (x0, y0, x1, y1 end-exclusive, pixel centres at integers -> cx = (x0 + x1 - 1) / 2), square
    pixels, focal from the horizontal field of view over the content width:
    ``f = (x1 - x0) / 2 / tan(fov_x / 2)``."""
    x0, y0, x1, y1 = (float(v) for v in content_box)
    if not (x1 > x0 and y1 > y0):
        raise ValueError(f"content box must have positive size, got {content_box}")
    if not (0.0 < fov_x_deg < 180.0):
        raise ValueError(f"fov_x_deg must be in (0, 180), got {fov_x_deg}")
    f = 0.5 * (x1 - x0) / math.tan(math.radians(fov_x_deg) / 2.0)
    return np.array([[f, 0.0, (x0 + x1 - 1.0) / 2.0], [0.0, f, (y0 + y1 - 1.0) / 2.0], [0.0, 0.0, 1.0]])


def _focal(K: np.ndarray) -> float:
    return float(math.sqrt(abs(K[0, 0] * K[1, 1])))


# --------------------------------------------------------------------------- protocol


@runtime_checkable
class PoseBackend(Protocol):
    name: str

    def estimate(self, x0: np.ndarray, x1: np.ndarray, K: np.ndarray, *, seed: int = 0) -> PoseEstimate:
        """x0, x1: (N, 2) matched pixel coordinates in the first and last frame."""
        ...


def _check_inputs(x0: np.ndarray, x1: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    x0 = np.asarray(x0, dtype=float)
    x1 = np.asarray(x1, dtype=float)
    x0 = np.zeros((0, 2)) if x0.size == 0 else x0
    x1 = np.zeros((0, 2)) if x1.size == 0 else x1
    if x0.ndim != 2 or x0.shape[1] != 2 or x0.shape != x1.shape:
        raise ValueError(f"x0 and x1 must both have shape (N, 2), got {x0.shape} and {x1.shape}")
    K = np.asarray(K, dtype=float)
    if K.shape != (3, 3) or not np.isfinite(K).all() or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ValueError(f"K must be a finite 3x3 intrinsic matrix with positive focal lengths, got {K!r}")
    keep = np.isfinite(x0).all(axis=1) & np.isfinite(x1).all(axis=1)
    return x0[keep], x1[keep], K


# --------------------------------------------------------------------------- small maths


def _rodrigues(w: np.ndarray) -> np.ndarray:
    th = float(np.linalg.norm(w))
    if th < 1e-12:
        return np.eye(3) + _skew(w)
    k = w / th
    Kx = _skew(k)
    return np.eye(3) + math.sin(th) * Kx + (1 - math.cos(th)) * (Kx @ Kx)


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _kabsch_batch(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Rotations R (M, 3, 3) minimising sum ||R a - b||^2 for point sets A, B (M, k, 3)."""
    H = np.einsum("mki,mkj->mij", B, A)  # sum b a^T
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(U @ Vt))
    D = np.ones((len(A), 3))
    D[:, 2] = d
    return (U * D[:, None, :]) @ Vt


def _transfer(K: np.ndarray, R: np.ndarray, s: float, x0: np.ndarray) -> np.ndarray:
    """Pixels of x0 mapped by ``K_s R K_s^-1`` (focal lengths of K scaled by s)."""
    Ks = K.copy()
    Ks[0, :2] *= s
    Ks[1, 1] *= s
    H = Ks @ R @ np.linalg.inv(Ks)
    y = np.c_[x0, np.ones(len(x0))] @ H.T
    with np.errstate(divide="ignore", invalid="ignore"):
        out = y[:, :2] / y[:, 2:3]
    bad = ~(np.isfinite(out).all(axis=1) & (y[:, 2] > 0))
    out[bad] = 1e9
    return out


def _sampson(E: np.ndarray, n0: np.ndarray, n1: np.ndarray) -> np.ndarray:
    """Sampson distance (not squared) in normalised camera coordinates, (N,)."""
    h0 = np.c_[n0, np.ones(len(n0))]
    h1 = np.c_[n1, np.ones(len(n1))]
    Ex0 = h0 @ E.T
    Etx1 = h1 @ E
    num = np.sum(h1 * Ex0, axis=1)
    den = np.sqrt(Ex0[:, 0] ** 2 + Ex0[:, 1] ** 2 + Etx1[:, 0] ** 2 + Etx1[:, 1] ** 2)
    return num / np.maximum(den, 1e-300)


# --------------------------------------------------------------------------- classical backend


@dataclass(frozen=True)
class _RotationFit:
    R: np.ndarray  # X1 = R X0 (camera-1 from camera-0 coordinates)
    focal_scale: float
    residual: np.ndarray  # (N,) pixel transfer error of every match (rotation-compensated parallax)
    inliers: np.ndarray  # (N,) bool


@dataclass(frozen=True)
class _EssentialFit:
    R: np.ndarray  # X1 = R X0 + t
    t: np.ndarray  # (3,) unit
    focal_scale: float
    inliers: np.ndarray  # (N,) bool
    front: np.ndarray  # (N,) bool, inliers triangulated in front of both cameras
    n0: np.ndarray  # (N, 2) normalised coordinates (focal scale applied), first frame
    n1: np.ndarray  # (N, 2) normalised coordinates (focal scale applied), last frame


class ClassicalPose:
    """Two-view pose from matches with known or assumed intrinsics; needs no weights.

    The method and the decision rule are described in the module docstring. Tunables (pixels
    are pixels of the images the matches come from):

    min_matches: fewer finite matches -> ``too_few_matches``.
    min_inliers, min_inlier_share: a model needs ``max(min_inliers, min_inlier_share * n)``
        inliers, else ``too_few_inliers``; the essential path also needs ``min_inliers``
        points triangulated in front of both cameras, else ``no_cheirality``.
    essential_px: inlier threshold of the essential-matrix RANSAC (Sampson distance, px).
    rot_ransac_px: inlier threshold of the rotation-only RANSAC (transfer error, px).
    rot_median_px, rot_share_px, rot_share: the rotation-only model explains the matches when
        their median parallax is <= rot_median_px and a share >= rot_share lies within
        rot_share_px.
    fit_focal: self-calibrate a common focal scale s (principal point fixed): always in the
        rotation-only model, and in the essential model when the evidence for it is at least
        focal_min_gain (see the module docstring). Set False when K is known exactly.
    focal_sigma: prior ``log s ~ N(0, focal_sigma^2)``; max_focal_ratio bounds s.
    trim: share of the sorted triangulated distances dropped at each end before the mean.
    ransac_iters, rot_hypotheses, confidence: RANSAC budgets.
    """

    name = "classical"

    def __init__(
        self,
        *,
        min_matches: int = 30,
        min_inliers: int = 15,
        min_inlier_share: float = 0.25,
        essential_px: float = 1.0,
        rot_ransac_px: float = 2.0,
        rot_median_px: float = 1.0,
        rot_share_px: float = 2.0,
        rot_share: float = 0.8,
        fit_focal: bool = True,
        focal_sigma: float = 0.2,
        focal_min_gain: float = 100.0,
        max_focal_ratio: float = 1.6,
        trim: float = 0.05,
        ransac_iters: int = 5000,
        rot_hypotheses: int = 300,
        confidence: float = 0.9999,
    ) -> None:
        if min_matches < 8:
            raise ValueError(f"min_matches must be at least 8, got {min_matches}")
        if min_inliers < 6:
            raise ValueError(f"min_inliers must be at least 6, got {min_inliers}")
        if not 0 <= trim < 0.5:
            raise ValueError(f"trim must be in [0, 0.5), got {trim}")
        if not min(essential_px, rot_ransac_px, rot_median_px, rot_share_px) > 0:
            raise ValueError("pixel thresholds must be positive")
        if not (0 < rot_share <= 1 and 0 <= min_inlier_share <= 1):
            raise ValueError("rot_share must be in (0, 1] and min_inlier_share in [0, 1]")
        if not (focal_sigma > 0 and max_focal_ratio >= 1 and focal_min_gain >= 0):
            raise ValueError("focal_sigma must be positive, max_focal_ratio >= 1, focal_min_gain >= 0")
        if ransac_iters < 1 or rot_hypotheses < 1 or not 0 < confidence < 1:
            raise ValueError("ransac_iters and rot_hypotheses must be positive, confidence in (0, 1)")
        self.min_matches = int(min_matches)
        self.min_inliers = int(min_inliers)
        self.min_inlier_share = float(min_inlier_share)
        self.essential_px = float(essential_px)
        self.rot_ransac_px = float(rot_ransac_px)
        self.rot_median_px = float(rot_median_px)
        self.rot_share_px = float(rot_share_px)
        self.rot_share = float(rot_share)
        self.fit_focal = bool(fit_focal)
        self.focal_sigma = float(focal_sigma)
        self.focal_min_gain = float(focal_min_gain)
        self.max_focal_ratio = float(max_focal_ratio)
        self.trim = float(trim)
        self.ransac_iters = int(ransac_iters)
        self.rot_hypotheses = int(rot_hypotheses)
        self.confidence = float(confidence)

    def __repr__(self) -> str:
        return (
            f"ClassicalPose(min_matches={self.min_matches}, essential_px={self.essential_px}, "
            f"rot_median_px={self.rot_median_px}, fit_focal={self.fit_focal}, trim={self.trim})"
        )

    # ---- public

    def estimate(self, x0: np.ndarray, x1: np.ndarray, K: np.ndarray, *, seed: int = 0) -> PoseEstimate:
        """Relative pose first -> last frame from (N, 2) matched pixels; never raises on bad
        geometry (a failure is a :class:`PoseEstimate` with ``pose_present = False``)."""
        x0, x1, K = _check_inputs(x0, x1, K)
        n = len(x0)
        f = _focal(K)
        if n < self.min_matches:
            return _failure("too_few_matches", n, f)
        need = max(self.min_inliers, int(math.ceil(self.min_inlier_share * n)))
        with np.errstate(all="ignore"):
            rot = self._fit_rotation(x0, x1, K, seed)
            ess = self._fit_essential(x0, x1, K, seed)

        consistent = rot.inliers.copy()
        if ess is not None:
            consistent |= ess.inliers
        if consistent.sum() < need:
            return _failure("too_few_inliers", n, f, n_inliers=int(consistent.sum()))
        if float(np.std(x0[consistent], axis=0).max()) < 2.0:
            return _failure("degenerate", n, f, n_inliers=int(consistent.sum()))
        par = rot.residual[consistent]
        parallax = float(np.median(par))
        explained = parallax <= self.rot_median_px and float(np.mean(par <= self.rot_share_px)) >= self.rot_share

        if explained and rot.inliers.sum() >= need:
            return PoseEstimate(
                pose_present=True,
                t_inf=parallax / f,
                T_cam0_camT=make_pose(rot.R.T, np.zeros(3)),
                method="rotation",
                reason=None,
                n_matches=n,
                n_inliers=int(rot.inliers.sum()),
                rotation_deg=rotation_angle_deg(rot.R),
                parallax_px=parallax,
                focal_px=f,
                focal_scale=rot.focal_scale,
            )

        def fail(reason: str, n_inl: int) -> PoseEstimate:
            return _failure(reason, n, f, n_inliers=n_inl, parallax_px=parallax)

        if ess is None:
            return fail("degenerate", 0)
        n_inl = int(ess.inliers.sum())
        if n_inl < need:
            return fail("too_few_inliers", n_inl)
        if ess.front.sum() < self.min_inliers:
            return fail("no_cheirality", n_inl)
        scale = self._mean_distance(ess.n0[ess.front], ess.n1[ess.front], ess.R, ess.t)
        if scale is None:
            return fail("no_cheirality", n_inl)
        c = -ess.R.T @ ess.t / scale  # last camera centre in camera-0 coordinates, unit scale
        T = make_pose(ess.R.T, c)
        t_inf = float(np.max(np.abs(c)))
        if not (math.isfinite(t_inf) and np.isfinite(T).all()):
            return fail("degenerate", n_inl)
        return PoseEstimate(
            pose_present=True,
            t_inf=t_inf,
            T_cam0_camT=T,
            method="essential",
            reason=None,
            n_matches=n,
            n_inliers=n_inl,
            rotation_deg=rotation_angle_deg(ess.R),
            parallax_px=parallax,
            focal_px=f,
            focal_scale=ess.focal_scale,
        )

    # ---- rotation-only model

    def _fit_rotation(self, x0: np.ndarray, x1: np.ndarray, K: np.ndarray, seed: int) -> _RotationFit:
        n = len(x0)
        Kinv = np.linalg.inv(K)
        r0 = np.c_[x0, np.ones(n)] @ Kinv.T
        r1 = np.c_[x1, np.ones(n)] @ Kinv.T
        r0 /= np.linalg.norm(r0, axis=1, keepdims=True)
        r1 /= np.linalg.norm(r1, axis=1, keepdims=True)
        rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, 2])
        m = self.rot_hypotheses
        i = rng.integers(0, n, size=m)
        j = (i + rng.integers(1, n, size=m)) % n  # a second, different match
        Rs = _kabsch_batch(np.stack([r0[i], r0[j]], axis=1), np.stack([r1[i], r1[j]], axis=1))
        # score the hypotheses on at most 1000 matches (memory stays bounded)
        sub = np.sort(rng.choice(n, size=min(n, 1000), replace=False))
        p = np.einsum("mab,nb->mna", Rs, r0[sub]) @ K.T
        proj = p[..., :2] / p[..., 2:3]
        err = np.linalg.norm(proj - x1[sub][None], axis=2)
        err[~np.isfinite(err) | (p[..., 2] <= 0)] = np.inf
        best = int(np.argmax((err <= self.rot_ransac_px).sum(axis=1)))
        R, s = Rs[best], 1.0
        res = np.linalg.norm(_transfer(K, R, s, x0) - x1, axis=1)
        inl = res <= self.rot_ransac_px
        for _ in range(4):
            if inl.sum() < 3:
                break
            R, s = self._refine_rotation(x0[inl], x1[inl], K, R, s)
            res = np.linalg.norm(_transfer(K, R, s, x0) - x1, axis=1)
            new = res <= self.rot_ransac_px
            if np.array_equal(new, inl):
                break
            inl = new
        return _RotationFit(R=R, focal_scale=s, residual=res, inliers=inl)

    def _refine_rotation(
        self, x0: np.ndarray, x1: np.ndarray, K: np.ndarray, R: np.ndarray, s: float
    ) -> tuple[np.ndarray, float]:
        """Levenberg-Marquardt on (rotation increment, log focal scale) minimising the pixel
        transfer error, with the weak prior on the focal scale."""
        fit_s = self.fit_focal
        bound = math.log(self.max_focal_ratio)

        def resid(Rc: np.ndarray, lsc: float) -> np.ndarray:
            r = (_transfer(K, Rc, math.exp(lsc), x0) - x1).ravel()
            if fit_s:  # prior log s ~ N(0, focal_sigma^2), weighted like one match with 0.5 px residual
                r = np.append(r, 0.5 * lsc / self.focal_sigma)
            return r

        def apply(Rc: np.ndarray, lsc: float, step: np.ndarray) -> tuple[np.ndarray, float]:
            lsn = float(np.clip(lsc + step[3], -bound, bound)) if fit_s else lsc
            return _rodrigues(step[:3]) @ Rc, lsn

        R, ls = _levenberg_marquardt(resid, apply, (R, math.log(s)), 4 if fit_s else 3, h=1e-6)
        U, _, Vt = np.linalg.svd(R)
        return U @ Vt, math.exp(ls)

    # ---- essential-matrix model

    def _fit_essential(self, x0: np.ndarray, x1: np.ndarray, K: np.ndarray, seed: int) -> _EssentialFit | None:
        Kinv = np.linalg.inv(K)
        n0 = (np.c_[x0, np.ones(len(x0))] @ Kinv.T)[:, :2]
        n1 = (np.c_[x1, np.ones(len(x1))] @ Kinv.T)[:, :2]
        f = _focal(K)
        thr = self.essential_px / f
        params = usac_params(
            thr,
            seed,
            self.ransac_iters,
            self.confidence,
            lo_method=cv2.LOCAL_OPTIM_INNER_LO,
            polisher=cv2.NONE_POLISHER,
        )
        I3 = np.eye(3)
        try:
            E, _ = cv2.findEssentialMat(np.ascontiguousarray(n0), np.ascontiguousarray(n1), I3, I3, None, None, params)
        except cv2.error:
            return None
        if E is None or E.ndim != 2 or E.shape[0] < 3 or E.shape[1] != 3 or not np.isfinite(E[:3]).all():
            return None
        E = E[:3].astype(float)
        inl = np.abs(_sampson(E, n0, n1)) <= thr
        R, t, _ = _recover(E, n0, n1, inl)
        if R is None:
            return None
        # polish (R, t) on the inliers; then, with fit_focal, try a focal scale as well and keep
        # it only when the evidence is strong (likelihood-ratio statistic >= focal_min_gain)
        R, t, _, cost0 = _polish_essential(R, t, n0[inl], n1[inl])
        sc = 1.0
        m = int(inl.sum())
        if self.fit_focal and m > 12 and math.isfinite(cost0):
            R1, t1, s1, cost1 = _polish_essential(
                R,
                t,
                n0[inl],
                n1[inl],
                focal_sigma=self.focal_sigma,
                noise=0.5 / f,
                max_ratio=self.max_focal_ratio,
            )
            gain = (cost0 - cost1) / max(cost1 / (m - 6), 1e-300)
            if math.isfinite(gain) and gain >= self.focal_min_gain:
                R, t, sc = R1, t1, s1
        n0, n1 = n0 / sc, n1 / sc
        inl = np.abs(_sampson(_skew(t) @ R, n0, n1)) * sc <= thr
        R, t, front = _recover(_skew(t) @ R, n0, n1, inl)
        if R is None:
            return None
        return _EssentialFit(R=R, t=t, focal_scale=sc, inliers=inl, front=front, n0=n0, n1=n1)

    def _mean_distance(self, n0: np.ndarray, n1: np.ndarray, R: np.ndarray, t: np.ndarray) -> float | None:
        """Trimmed mean distance from camera 0 of the triangulated points (baseline |t| = 1):
        points behind either camera are dropped, then the ``trim`` share at each end of the
        sorted distances."""
        X = _triangulate(n0, n1, R, t)
        z1 = X @ R.T + t
        ok = np.isfinite(X).all(axis=1) & (X[:, 2] > 0) & (z1[:, 2] > 0)
        if ok.sum() < self.min_inliers:
            return None
        d = np.sort(np.linalg.norm(X[ok], axis=1))
        k = int(math.floor(self.trim * len(d)))
        d = d[k : len(d) - k]
        m = float(d.mean())
        return m if math.isfinite(m) and m > 0 else None


def _recover(E: np.ndarray, n0: np.ndarray, n1: np.ndarray, inl: np.ndarray):
    """The decomposition (R, t) of E that puts most inliers in front of both cameras. Unlike
    ``cv2.recoverPose`` there is no distance cut-off: the far points with little parallax are
    exactly the ones that set the mean scene distance. Returns (R, unit t, front mask) or
    (None, None, None)."""
    if inl.sum() < 5:
        return None, None, None
    idx = np.flatnonzero(inl)
    try:
        R1, R2, tt = cv2.decomposeEssentialMat(E)
    except cv2.error:
        return None, None, None
    tt = tt.ravel().astype(float)
    best = None
    for R, t in ((R1, tt), (R1, -tt), (R2, tt), (R2, -tt)):
        X = _triangulate(n0[idx], n1[idx], R, t)
        z1 = X @ R.T + t
        ok = np.isfinite(X).all(axis=1) & (X[:, 2] > 0) & (z1[:, 2] > 0)
        if best is None or ok.sum() > best[2].sum():
            best = (np.asarray(R, dtype=float), t, ok)
    R, t, ok = best
    norm = float(np.linalg.norm(t))
    if not (np.isfinite(R).all() and np.isfinite(t).all() and norm > 0):
        return None, None, None
    front = np.zeros(len(n0), bool)
    front[idx] = ok
    return R, t / norm, front


def _triangulate(n0: np.ndarray, n1: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Linear (DLT) triangulation in normalised coordinates; X in camera-0 coordinates, (N, 3)."""
    P0 = np.hstack([np.eye(3), np.zeros((3, 1))])
    P1 = np.hstack([R, np.asarray(t, dtype=float).reshape(3, 1)])
    Xh = cv2.triangulatePoints(P0, P1, np.ascontiguousarray(n0.T, dtype=float), np.ascontiguousarray(n1.T, dtype=float))
    with np.errstate(divide="ignore", invalid="ignore"):
        return (Xh[:3] / Xh[3]).T


def _levenberg_marquardt(resid, apply, x, npar: int, *, h: float, iters: int = 40):
    """Minimise ``|resid(*x)|^2`` over increments applied by ``apply(*x, step)``, with a
    forward-difference Jacobian; deterministic."""
    r = resid(*x)
    cost = float(r @ r)
    lam = 1e-3
    for _ in range(iters):
        J = np.empty((len(r), npar))
        for k in range(npar):
            e = np.zeros(npar)
            e[k] = h
            J[:, k] = (resid(*apply(*x, e)) - r) / h
        A = J.T @ J
        g = J.T @ r
        try:
            step = np.linalg.solve(A + lam * np.diag(np.diag(A) + 1e-18), -g)
        except np.linalg.LinAlgError:
            break
        xn = apply(*x, step)
        rn = resid(*xn)
        cn = float(rn @ rn)
        if math.isfinite(cn) and cn < cost:
            done = cost - cn <= 1e-10 * cost
            x, r, cost = xn, rn, cn
            lam = max(lam / 10, 1e-12)
            if done:
                break
        else:
            lam *= 10
            if lam > 1e8:
                break
    return x


def _polish_essential(
    R: np.ndarray,
    t: np.ndarray,
    n0: np.ndarray,
    n1: np.ndarray,
    *,
    focal_sigma: float | None = None,
    noise: float = 1e-3,
    max_ratio: float = 1.6,
) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Levenberg-Marquardt on (rotation increment, translation direction on the sphere and,
    with ``focal_sigma``, the log of a focal scale s) minimising the Sampson distance of the
    inliers, measured in units of f (pixels / f). The scale carries the prior
    ``log s ~ N(0, focal_sigma^2)``, weighted like one match with residual ``noise``.
    Returns (R, t, s, data cost)."""
    if len(n0) < 6:
        return R, t, 1.0, float("nan")
    fit_s = focal_sigma is not None
    bound = math.log(max_ratio)

    def basis(tv: np.ndarray) -> np.ndarray:
        a = np.array([1.0, 0.0, 0.0]) if abs(tv[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        b1 = np.cross(tv, a)
        b1 /= np.linalg.norm(b1)
        return np.stack([b1, np.cross(tv, b1)], axis=1)

    def data(Rc: np.ndarray, tc: np.ndarray, ls: float) -> np.ndarray:
        sc = math.exp(ls)
        return _sampson(_skew(tc) @ Rc, n0 / sc, n1 / sc) * sc

    def resid(Rc: np.ndarray, tc: np.ndarray, ls: float) -> np.ndarray:
        r = data(Rc, tc, ls)
        return np.append(r, noise * ls / focal_sigma) if fit_s else r

    def apply(Rc: np.ndarray, tc: np.ndarray, ls: float, step: np.ndarray):
        tn = tc + basis(tc) @ step[3:5]
        lsn = float(np.clip(ls + step[5], -bound, bound)) if fit_s else ls
        return _rodrigues(step[:3]) @ Rc, tn / np.linalg.norm(tn), lsn

    R, t, ls = _levenberg_marquardt(resid, apply, (R, t, 0.0), 6 if fit_s else 5, h=1e-7)
    U, _, Vt = np.linalg.svd(R)
    R = U @ Vt
    r = data(R, t, ls)
    return R, t, math.exp(ls), float(r @ r)


# --------------------------------------------------------------------------- pose logs


def _as_pose(value: Any, where: str) -> np.ndarray:
    try:
        T = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{where}: T_cam0_camT must be a 4x4 array of numbers") from None
    if T.shape != (4, 4):
        raise ValueError(f"{where}: T_cam0_camT must be 4x4, got shape {T.shape}")
    if not np.isfinite(T).all():
        raise ValueError(f"{where}: T_cam0_camT contains non-finite values")
    if np.abs(T[3] - [0.0, 0.0, 0.0, 1.0]).max() > _ROT_TOL:
        raise ValueError(f"{where}: the last row of T_cam0_camT must be [0, 0, 0, 1], got {T[3].tolist()}")
    R = T[:3, :3]
    ortho = float(np.abs(R.T @ R - np.eye(3)).max())
    det = float(np.linalg.det(R))
    if ortho > _ROT_TOL or abs(det - 1.0) > _ROT_TOL:
        raise ValueError(
            f"{where}: the rotation block of T_cam0_camT is not a rotation "
            f"(max |R^T R - I| = {ortho:.3g}, det = {det:.9g}; both must hold within {_ROT_TOL:g})"
        )
    return T


def _positive(value: Any, name: str, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
        raise ValueError(f"{where}: {name} must be a positive number, got {value!r}")
    return float(value)


class PoseLog:
    """A pose computed elsewhere, read from a JSON pose log (schema in the module docstring)
    or a GeoCon synthetic ground-truth file. :meth:`estimate` ignores the matches."""

    name = "log"

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        where = str(self.path)
        try:
            d = json.loads(self.path.read_text())
        except FileNotFoundError:
            raise ValueError(f"pose log {where} does not exist") from None
        except json.JSONDecodeError as e:
            raise ValueError(f"pose log {where} is not valid JSON: {e}") from None
        if not isinstance(d, dict):
            raise ValueError(f"{where}: a pose log must be a JSON object")
        fmt = d.get("format")
        self.pose_present: bool
        self.T_unit: np.ndarray | None  # translation already divided by the scene scale
        if fmt == POSE_LOG_FORMAT:
            present = d.get("pose_present", True)
            if not isinstance(present, bool):
                raise ValueError(f"{where}: pose_present must be true or false, got {present!r}")
            source = d.get("source", "")
            if not isinstance(source, str):
                raise ValueError(f"{where}: source must be a string, got {source!r}")
            self.source = source
            T_raw = d.get("T_cam0_camT")
            if T_raw is None:
                if present:
                    raise ValueError(f"{where}: T_cam0_camT is required when pose_present is true")
                self.pose_present, self.T_unit, self.scale = False, None, d.get("scale")
                return
            T = _as_pose(T_raw, where)
            scale = d.get("scale")
            if scale == "unit_mean_distance":
                dist = 1.0
            elif scale == "metric":
                if "mean_scene_distance" not in d:
                    raise ValueError(f"{where}: mean_scene_distance is required when scale is 'metric'")
                dist = _positive(d["mean_scene_distance"], "mean_scene_distance", where)
            else:
                raise ValueError(f"{where}: scale must be 'unit_mean_distance' or 'metric', got {scale!r}")
            self.scale = scale
        elif fmt == _SYNTH_GT_FORMAT:
            present = True
            T = _as_pose(d.get("T_cam0_camT"), where)
            if "mean_scene_distance" not in d:
                raise ValueError(f"{where}: synthetic ground truth without mean_scene_distance")
            dist = _positive(d["mean_scene_distance"], "mean_scene_distance", where)
            self.scale = "metric"
            self.source = f"geocon synthetic ground truth {d.get('clip_id', '')}".strip()
        else:
            raise ValueError(
                f"{where}: unknown pose log format {fmt!r}; expected {POSE_LOG_FORMAT!r} "
                f"(or a GeoCon synthetic ground truth, {_SYNTH_GT_FORMAT!r})"
            )
        T = T.copy()
        T[:3, 3] = T[:3, 3] / dist
        self.pose_present = bool(present)
        self.T_unit = T

    def __repr__(self) -> str:
        return f"PoseLog({str(self.path)!r})"

    @property
    def t_inf(self) -> float | None:
        if not self.pose_present or self.T_unit is None:
            return None
        return float(np.max(np.abs(self.T_unit[:3, 3])))

    def estimate(self, x0: np.ndarray, x1: np.ndarray, K: np.ndarray, *, seed: int = 0) -> PoseEstimate:
        """The logged pose (``method = "log"``); the matches are only counted."""
        x0, x1, K = _check_inputs(x0, x1, K)
        n, f = len(x0), _focal(K)
        if not self.pose_present or self.T_unit is None:
            return _failure("log_no_pose", n, f, method="log")
        return PoseEstimate(
            pose_present=True,
            t_inf=self.t_inf,
            T_cam0_camT=self.T_unit.copy(),
            method="log",
            reason=None,
            n_matches=n,
            n_inliers=0,
            rotation_deg=rotation_angle_deg(self.T_unit[:3, :3]),
            parallax_px=None,
            focal_px=f,
        )


def load_pose_log(path: str | Path) -> PoseLog:
    """Read and validate a pose log (``ValueError`` with a clear sentence when invalid)."""
    return PoseLog(path)


# --------------------------------------------------------------------------- registry


POSE_BACKENDS: dict[str, Callable[..., PoseBackend]] = {"classical": ClassicalPose}
"""Backends built from settings alone; ``"log"`` is built from a path by
:func:`make_pose_backend` (``make_pose_backend("log", path=...)``) or :func:`load_pose_log`."""


def make_pose_backend(name: str, **kwargs: Any) -> PoseBackend:
    """Build a pose backend by name: ``"classical"`` (keyword tunables of
    :class:`ClassicalPose`) or ``"log"`` (``path=`` the pose log). An unknown name raises
    ``ValueError`` listing the valid ones."""
    key = str(name).strip().lower()
    if key == "log":
        if "path" not in kwargs or len(kwargs) != 1:
            raise ValueError("the 'log' pose backend takes exactly one argument, path= (the pose log JSON)")
        return PoseLog(kwargs["path"])
    if key not in POSE_BACKENDS:
        valid = ", ".join([*POSE_BACKENDS, "log"])
        raise ValueError(f"unknown pose backend {name!r}; valid: {valid}")
    return POSE_BACKENDS[key](**kwargs)
