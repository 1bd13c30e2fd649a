"""Relative camera pose first -> last frame, the evidence of the translation gate (SPEC section 1).

The gate needs ``t_inf = max(|tx|, |ty|, |tz|)`` of the relative pose between the first and the
last frame, on the DUSt3R scale: the scene is scaled so that the mean distance of the visible
scene points from the first camera is 1. A pose backend turns matched pixels of the two frames
into a :class:`PoseEstimate` that carries ``t_inf``, the pose ``T_cam0_camT`` (the last camera in
first-camera coordinates; its translation column is the last camera centre on that unit scale,
see :mod:`geocon_core.geometry`) and the diagnostics needed to audit the decision.

Backends
--------
``classical`` (:class:`ClassicalPose`, default, no weights; :mod:`geocon_core.pose.classical`)
    Rotation-only and essential-matrix models fitted to the matches, with a decision rule
    between them; settings in :class:`~geocon_core.config.stages.PoseConfig`.
``log`` (:class:`PoseLog`, :mod:`geocon_core.pose.log`)
    A pose computed elsewhere, read from a JSON pose log.
``dust3r`` (:class:`~geocon_core.pose.dust3r.Dust3rPose`, :mod:`geocon_core.pose.dust3r`)
    DUSt3R's point maps of the first and last frame, aligned; the user's own DUSt3R install and
    checkpoint (torch and DUSt3R are imported only when it is built).

Modules: :mod:`.base` (the result record, the protocol, default intrinsics),
:mod:`.classical`, :mod:`.lsq` (least-squares helpers), :mod:`.log`.
"""

from __future__ import annotations

from typing import Any, Callable

from ..config import Dust3rConfig, PoseConfig
from .base import POSE_METHODS, PoseBackend, PoseEstimate, default_intrinsics, failure, focal_of
from .chain import chain_hops, chain_lengths, compose_chain, select_hops
from .classical import ClassicalPose
from .convert import from_colmap, from_dust3r, write_pose_log
from .dust3r import DUST3R_INSTALL, Dust3rPose, import_model_class
from .log import POSE_LOG_FORMAT, PoseLog, load_pose_log
from .pointmaps import PointMaps
from .still import still_pose, still_share

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
    "failure",
    "focal_of",
    "chain_hops",
    "chain_lengths",
    "compose_chain",
    "select_hops",
    "from_colmap",
    "from_dust3r",
    "write_pose_log",
    "PointMaps",
    "still_pose",
    "still_share",
    "DUST3R_INSTALL",
    "Dust3rPose",
    "import_model_class",
]


POSE_BACKENDS: dict[str, Callable[..., PoseBackend]] = {"classical": ClassicalPose}
"""Backends built from settings alone; ``"log"`` is built from a path by
:func:`make_pose_backend` (``make_pose_backend("log", path=...)``) or :func:`load_pose_log`."""


def make_pose_backend(name: str, config: PoseConfig | Dust3rConfig | None = None, **kwargs: Any) -> PoseBackend:
    """Build a pose backend by name: ``"classical"`` (settings ``config``, defaults when None,
    and single-field overrides as keywords), ``"log"`` (``path=`` the pose log) or ``"dust3r"``
    (``checkpoint=``, optional ``clone=`` and ``config=`` a
    :class:`~geocon_core.config.stages.Dust3rConfig`). An unknown name raises ``ValueError``
    listing the valid ones."""
    key = str(name).strip().lower()
    if key == "dust3r":
        from .dust3r import Dust3rPose

        if config is not None and not isinstance(config, Dust3rConfig):
            raise ValueError(f"the 'dust3r' pose backend takes a Dust3rConfig, got {type(config).__name__}")
        return Dust3rPose(config, **kwargs)
    if key == "log":
        if "path" not in kwargs or len(kwargs) != 1 or config is not None:
            raise ValueError("the 'log' pose backend takes exactly one argument, path= (the pose log JSON)")
        return PoseLog(kwargs["path"])
    if key not in POSE_BACKENDS:
        valid = ", ".join([*POSE_BACKENDS, "log", "dust3r"])
        raise ValueError(f"unknown pose backend {name!r}; valid: {valid}")
    return POSE_BACKENDS[key](config, **kwargs)
