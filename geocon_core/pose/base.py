"""The pose result record, the backend protocol and default intrinsics."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np

from ..geometry import intrinsics_from_fov

__all__ = [
    "POSE_METHODS",
    "ZOOM_NOTE_LOG",
    "PoseEstimate",
    "PoseBackend",
    "default_intrinsics",
    "failure",
    "focal_of",
    "check_inputs",
]

POSE_METHODS = ("essential", "rotation", "chain", "log", "dust3r", "still", "none")
"""How a :class:`PoseEstimate` was found (its ``method``); ``none`` when no pose was found."""

ZOOM_NOTE_LOG = 0.05
"""A fitted zoom whose log exceeds this (about 5 %) is named in the pose's note."""


@dataclass(frozen=True, eq=False)
class PoseEstimate:
    """Relative pose first -> last frame and the evidence behind it.

    pose_present: False when no pose could be estimated (the gate then applies fail->F).
    t_inf: ``max |t|`` on the unit-mean-distance scale; None when not present.
    T_cam0_camT: (4, 4) pose of the last camera in first-camera coordinates, translation on
        the unit-mean-distance scale; None when not present. For ``method = "rotation"`` the
        translation column is zero (a translation below the noise is not observable) and
        ``t_inf`` is the first-order bound ``parallax_px / focal_px``.
    method: ``"essential"``, ``"rotation"``, ``"chain"`` (composed from short hops when the
        first-last pair failed, :mod:`geocon_core.pose.chain`), ``"log"``, ``"dust3r"`` (aligned
        DUSt3R point maps, :mod:`geocon_core.pose.dust3r`), ``"still"`` (a still camera told by
        dense motion, :mod:`geocon_core.pose.still`) or ``"none"``.
    reason: reason code when not present (``"too_few_matches"``, ``"too_few_inliers"``,
        ``"degenerate"``, ``"no_cheirality"``, ``"log_no_pose"``, ``"too_few_points"``,
        ``"needs_frames"``, ``"single_frame"`` for a shot of one frame), else None.
    n_matches: finite matches given to the backend.
    n_inliers: inliers of the model used (0 for logs and for failures before any fit).
    rotation_deg: rotation angle of the relative pose, degrees (None when unknown).
    parallax_px: median rotation-compensated parallax of the consistent matches, pixels.
    focal_px: focal length ``sqrt(fx fy)`` of the intrinsics given, pixels.
    focal_scale: focal scale adopted by self-calibration (1.0 = K as given); an addition to
        the minimal interface, defaulted so that older records still load.
    note: which evidence decided, in words, when it is not the first-last pair (a chain).
    zoom: focal length of the last frame over the first's fitted by the rotation-only model
        (``PoseConfig.fit_zoom``; for a chain, the product over its hops); 1.0 without zoom.
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
    note: str | None = None
    zoom: float = 1.0

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
            "note": self.note,
            "zoom": float(self.zoom),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "PoseEstimate":
        d = dict(d)
        T = d.get("T_cam0_camT")
        d["T_cam0_camT"] = None if T is None else np.array(T, dtype=float)
        return cls(**d)


def failure(
    reason: str,
    n_matches: int,
    focal_px: float,
    *,
    n_inliers: int = 0,
    method: str = "none",
    parallax_px: float | None = None,
) -> PoseEstimate:
    """A :class:`PoseEstimate` that found no pose, saying why (``reason``) and what it had to work with."""
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


def default_intrinsics(content_box: tuple[int, int, int, int], fov_x_deg: float) -> np.ndarray:
    """K (3x3) for unknown intrinsics: principal point at the centre of the content box
    (x0, y0, x1, y1 end-exclusive, pixel centres at integers -> cx = (x0 + x1 - 1) / 2), square
    pixels, focal from the horizontal field of view over the content width:
    ``f = (x1 - x0) / 2 / tan(fov_x / 2)``."""
    x0, y0, x1, y1 = (float(v) for v in content_box)
    if not (x1 > x0 and y1 > y0):
        raise ValueError(f"content box must have positive size, got {content_box}")
    K = intrinsics_from_fov(x1 - x0, y1 - y0, fov_x_deg)
    K[0, 2] += x0
    K[1, 2] += y0
    return K


def focal_of(K: np.ndarray) -> float:
    """The focal length in pixels of intrinsics ``K``: the geometric mean of fx and fy."""
    return float(math.sqrt(abs(K[0, 0] * K[1, 1])))


@runtime_checkable
class PoseBackend(Protocol):
    name: str

    def estimate(self, x0: np.ndarray, x1: np.ndarray, K: np.ndarray, *, seed: int = 0) -> PoseEstimate:
        """x0, x1: (N, 2) matched pixel coordinates in the first and last frame."""
        ...


def check_inputs(x0: np.ndarray, x1: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
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
