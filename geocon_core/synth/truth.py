"""Ground truth of a synthetic clip, written next to the video as ``<clip_id>.gt.json``
and read back exactly (floats are stored with full precision)."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..scoring import GateLabel

__all__ = ["ObjectTruth", "FailureTruth", "GroundTruth", "load_ground_truth", "GT_FORMAT"]

GT_FORMAT = "geocon-synth-gt/1"


@dataclass(frozen=True)
class ObjectTruth:
    """A moving object: its label in the masks, whether it moves rigidly, and the frames in
    which at least one of its pixels is visible."""

    object_id: int
    name: str
    rigid: bool
    visible_frames: tuple[int, ...]


@dataclass(frozen=True)
class FailureTruth:
    """An injected failure: kind, severity (in ``unit``) and the parameters that define it."""

    kind: str
    severity: float
    unit: str
    params: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True, eq=False)
class GroundTruth:
    """Everything known about a synthetic clip.

    K: (3, 3) intrinsics in pixels (pixel centres at integer coordinates).
    T_cam_world: (T, 4, 4) world-to-camera pose per frame (world = first camera).
    T_cam0_camT: (4, 4) pose of the last camera in first-camera coordinates (DUSt3R-style
        cam-to-world with camera 0 as world); its translation, divided by
        ``mean_scene_distance``, gives ``t_inf``.
    mean_scene_distance: mean Euclidean distance of the scene points visible in frame 0 from
        the first camera, in world units.
    t_inf: ``max |t|`` of the first->last translation on that unit scale (SPEC section 1).
    masked_share: (T,) share of content pixels covered by object masks, per frame.
    content_box: (x0, y0, x1, y1) end-exclusive region of real image content.
    sensor_noise_sigma: standard deviation (grey levels) of the Gaussian noise in the video.
    """

    clip_id: str
    family: str
    family_title: str
    seed: int
    width: int
    height: int
    fps: float
    num_frames: int
    fov_x_deg: float
    K: np.ndarray
    T_cam_world: np.ndarray
    T_cam0_camT: np.ndarray
    mean_scene_distance: float
    t_inf: float
    rotation_deg: float
    expected_gate: GateLabel
    expected_gate_binary: GateLabel
    objects: tuple[ObjectTruth, ...]
    masks_path: str
    masked_share: np.ndarray
    content_box: tuple[int, int, int, int]
    failure: FailureTruth | None
    video_path: str
    sensor_noise_sigma: float = 0.0

    def __post_init__(self) -> None:
        T = self.num_frames
        checks = {
            "K": (self.K, (3, 3)),
            "T_cam_world": (self.T_cam_world, (T, 4, 4)),
            "T_cam0_camT": (self.T_cam0_camT, (4, 4)),
            "masked_share": (self.masked_share, (T,)),
        }
        for name, (arr, shape) in checks.items():
            if np.shape(arr) != shape:
                raise ValueError(f"{name} must have shape {shape}, got {np.shape(arr)}")

    @property
    def rigid_objects(self) -> tuple[int, ...]:
        return tuple(o.object_id for o in self.objects if o.rigid)

    def T_camB_camA(self, a: int, b: int) -> np.ndarray:
        """Rigid transform taking camera-``a`` coordinates to camera-``b`` coordinates."""
        from ..geometry import invert_pose

        return self.T_cam_world[b] @ invert_pose(self.T_cam_world[a])

    def to_json_dict(self) -> dict[str, Any]:
        d = asdict(self)
        for key in ("K", "T_cam_world", "T_cam0_camT", "masked_share"):
            d[key] = np.asarray(d[key]).tolist()
        d["content_box"] = list(self.content_box)
        for o in d["objects"]:
            o["visible_frames"] = list(o["visible_frames"])
        return {"format": GT_FORMAT, **d}

    def write(self, path: str | Path) -> None:
        Path(path).write_text(json.dumps(self.to_json_dict(), indent=1) + "\n")

    @classmethod
    def from_json_dict(cls, d: dict[str, Any]) -> "GroundTruth":
        d = dict(d)
        fmt = d.pop("format", None)
        if fmt != GT_FORMAT:
            raise ValueError(f"not a GeoCon synthetic ground truth (format {fmt!r}, expected {GT_FORMAT!r})")
        d["K"] = np.array(d["K"], dtype=float)
        d["T_cam_world"] = np.array(d["T_cam_world"], dtype=float)
        d["T_cam0_camT"] = np.array(d["T_cam0_camT"], dtype=float)
        d["masked_share"] = np.array(d["masked_share"], dtype=float)
        d["content_box"] = tuple(d["content_box"])
        d["objects"] = tuple(ObjectTruth(**{**o, "visible_frames": tuple(o["visible_frames"])}) for o in d["objects"])
        d["failure"] = FailureTruth(**d["failure"]) if d["failure"] else None
        return cls(**d)


def load_ground_truth(path: str | Path) -> GroundTruth:
    """Read a ``<clip_id>.gt.json`` file (a regular file within the bound of
    :data:`~geocon_core.files.bounded.GROUND_TRUTH`, else :class:`~geocon_core.files.ReadRefused`)."""
    from ..files import GROUND_TRUTH, read_text

    return GroundTruth.from_json_dict(json.loads(read_text(path, GROUND_TRUTH)))
