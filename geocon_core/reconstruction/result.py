"""What the multi-view check reports: the clip's one reconstruction (:class:`MultiViewResult`),
the background layers that drift against it (:class:`DriftLayer`) and the arrays a record keeps
of it (:data:`ARRAY_NAMES`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["ARRAY_NAMES", "DriftLayer", "MultiViewResult"]


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
