"""Poses computed elsewhere, read from a JSON pose log.

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
    the last row ``[0, 0, 0, 1]``; the translation, divided by the scene scale, must be at most
    :data:`MAX_T_UNIT` mean scene distances (a camera that moved further than that between the
    first and the last frame is a unit mistake, not a clip); the file must be UTF-8 JSON of at
    most :data:`MAX_POSE_LOG_BYTES`. Anything else raises ``ValueError`` naming the file. A GeoCon synthetic
    ground-truth file (``"format": "geocon-synth-gt/1"``, written as ``<clip>.gt.json`` by
    ``geocon synth``) is accepted too: its ``T_cam0_camT`` is metric and its
    ``mean_scene_distance`` gives the scale, so clips can be gated with their true pose.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from ..files import POSE_LOG, ReadRefused, read_bytes, strict_json
from ..geometry import rotation_angle_deg
from .base import PoseEstimate, check_inputs, failure, focal_of

__all__ = ["POSE_LOG_FORMAT", "MAX_T_UNIT", "MAX_POSE_LOG_BYTES", "PoseLog", "load_pose_log"]

POSE_LOG_FORMAT = "geocon-pose/1"
"""The ``format`` field of a pose log (``geocon pose`` writes it, ``--pose log`` reads it)."""
MAX_T_UNIT = 1000.0
"""Largest translation (in mean scene distances) a pose log may give; the gate's band is at
0.03-0.05, so a larger value can only come from a wrong scale or unit."""
MAX_POSE_LOG_BYTES = POSE_LOG.limit
"""A pose log is a few hundred bytes; a larger file is refused before it is parsed."""
_SYNTH_GT_FORMAT = "geocon-synth-gt/1"
_ROT_TOL = 1e-6


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


def _read_json(path: Path) -> Any:
    """The parsed JSON of a pose log, or ``ValueError`` naming the file."""
    where = str(path)
    if not path.exists():
        raise ValueError(f"pose log {where} does not exist")
    if not path.is_file():
        raise ValueError(f"pose log {where} is not a file (a geocon-pose/1 JSON file is expected)")
    try:
        try:
            raw = read_bytes(path, POSE_LOG)  # a regular file within its bound, or refused unread
        except ReadRefused as exc:
            if exc.reason == "size":
                raise ValueError(
                    f"pose log {where} is larger than {MAX_POSE_LOG_BYTES} bytes; a pose log is a small JSON file"
                ) from None
            raise ValueError(f"pose log {where} is {exc.why} (a geocon-pose/1 JSON file is expected)") from None
        return strict_json(raw.decode("utf-8"), f"pose log {where}")
    except UnicodeDecodeError:
        raise ValueError(f"pose log {where} is not UTF-8 text (a geocon-pose/1 JSON file is expected)") from None
    except json.JSONDecodeError as e:
        raise ValueError(f"pose log {where} is not valid JSON: {e}") from None
    except ValueError as e:  # a repeated key, an absurd number: the sentence names the file
        raise ValueError(str(e)) from None
    except RecursionError:
        raise ValueError(f"pose log {where} is not a pose log (JSON nested too deeply)") from None
    except OSError as e:
        raise ValueError(f"pose log {where} cannot be read: {e.strerror or e}") from None


class PoseLog:
    """A pose computed elsewhere, read from a JSON pose log (schema in the module docstring)
    or a GeoCon synthetic ground-truth file. :meth:`estimate` ignores the matches."""

    name = "log"

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        where = str(self.path)
        d = _read_json(self.path)
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
        with np.errstate(over="ignore"):
            T[:3, 3] = T[:3, 3] / dist
        t = float(np.max(np.abs(T[:3, 3])))
        if not t <= MAX_T_UNIT:
            raise ValueError(
                f"{where}: the translation is {t:.3g} mean scene distances (at most {MAX_T_UNIT:g} is plausible); "
                "check the scale and mean_scene_distance"
            )
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
        x0, x1, K = check_inputs(x0, x1, K)
        n, f = len(x0), focal_of(K)
        if not self.pose_present or self.T_unit is None:
            return failure("log_no_pose", n, f, method="log")
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
