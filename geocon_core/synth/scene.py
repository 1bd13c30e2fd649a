"""Scene description for the synthetic renderer: textured planes, moving planar objects and a
pinhole camera following a trajectory. All geometry is exact; the renderer only samples it.

A :class:`SurfaceView` is one surface as seen from one camera: a homography from camera rays
to texture coordinates plus the plane's depth function, which is all the renderer needs.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np

from ..geometry import make_pose

__all__ = ["Role", "TexturedPlane", "ObjectTrack", "Scene", "SurfaceView", "plane_view"]

Role = Literal["background", "object"]


def _vec3(name: str, v: np.ndarray) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    if v.shape != (3,):
        raise ValueError(f"{name} must have shape (3,), got {v.shape}")
    return v


@dataclass(frozen=True, eq=False)
class TexturedPlane:
    """A finite textured rectangle. Texel ``(a, b)`` (texel centres at integers) sits at
    ``origin + a * axis_u + b * axis_v``; the surface spans ``a in [-0.5, w - 0.5]``,
    ``b in [-0.5, h - 0.5]``.

    origin, axis_u, axis_v: (3,) in the plane's parent frame (world, or object coordinates);
        the axes are one texel long and orthogonal.
    texture: (h, w, 3) uint8 RGB.
    alpha: (h, w) uint8 opacity (255 opaque) or None for a fully opaque rectangle.
    """

    name: str
    origin: np.ndarray
    axis_u: np.ndarray
    axis_v: np.ndarray
    texture: np.ndarray
    alpha: np.ndarray | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "origin", _vec3("origin", self.origin))
        object.__setattr__(self, "axis_u", _vec3("axis_u", self.axis_u))
        object.__setattr__(self, "axis_v", _vec3("axis_v", self.axis_v))
        if self.texture.ndim != 3 or self.texture.shape[2] != 3 or self.texture.dtype != np.uint8:
            raise ValueError(f"texture must be (h, w, 3) uint8, got {self.texture.shape} {self.texture.dtype}")
        if self.alpha is not None and self.alpha.shape != self.texture.shape[:2]:
            raise ValueError(f"alpha shape {self.alpha.shape} != texture shape {self.texture.shape[:2]}")
        nu, nv = np.linalg.norm(self.axis_u), np.linalg.norm(self.axis_v)
        if nu <= 0 or nv <= 0 or abs(self.axis_u @ self.axis_v) > 1e-9 * nu * nv:
            raise ValueError(f"plane {self.name!r}: axes must be non-zero and orthogonal")

    @property
    def texture_size(self) -> tuple[int, int]:
        """(width, height) in texels."""
        return self.texture.shape[1], self.texture.shape[0]

    @property
    def normal(self) -> np.ndarray:
        n = np.cross(self.axis_u, self.axis_v)
        return n / np.linalg.norm(n)

    def corners(self) -> np.ndarray:
        """The four corners, (4, 3), in the parent frame."""
        w, h = self.texture_size
        ab = np.array([[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5], [-0.5, h - 0.5]])
        return self.origin + ab[:, :1] * self.axis_u + ab[:, 1:] * self.axis_v

    def transformed(self, T_parent_self: np.ndarray) -> "TexturedPlane":
        """The same plane with its geometry mapped by a 4x4 rigid transform."""
        R, t = T_parent_self[:3, :3], T_parent_self[:3, 3]
        return replace(self, origin=R @ self.origin + t, axis_u=R @ self.axis_u, axis_v=R @ self.axis_v)


@dataclass(frozen=True, eq=False)
class ObjectTrack:
    """A moving planar object. ``plane`` is given in object coordinates; ``T_world_obj``
    (T, 4, 4) places it in the world at each frame. ``object_id`` >= 1 is its label in masks."""

    object_id: int
    name: str
    plane: TexturedPlane
    T_world_obj: np.ndarray

    def __post_init__(self) -> None:
        if not 1 <= self.object_id <= 255:
            raise ValueError(f"object_id must be in 1..255, got {self.object_id}")
        if self.T_world_obj.ndim != 3 or self.T_world_obj.shape[1:] != (4, 4):
            raise ValueError(f"T_world_obj must be (T, 4, 4), got {self.T_world_obj.shape}")

    def plane_at(self, t: int) -> TexturedPlane:
        return self.plane.transformed(self.T_world_obj[t])


@dataclass(frozen=True, eq=False)
class Scene:
    """A complete synthetic scene: camera intrinsics ``K`` (3x3), per-frame world-to-camera
    poses ``T_cam_world`` (T, 4, 4), static background planes and moving objects."""

    family: str
    seed: int
    width: int
    height: int
    fps: float
    K: np.ndarray
    T_cam_world: np.ndarray
    background: tuple[TexturedPlane, ...]
    objects: tuple[ObjectTrack, ...] = ()
    sky_rgb: tuple[int, int, int] = (128, 128, 128)
    fov_x_deg: float = 60.0
    notes: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.K.shape != (3, 3):
            raise ValueError(f"K must be 3x3, got {self.K.shape}")
        if self.T_cam_world.ndim != 3 or self.T_cam_world.shape[1:] != (4, 4):
            raise ValueError(f"T_cam_world must be (T, 4, 4), got {self.T_cam_world.shape}")
        for obj in self.objects:
            if obj.T_world_obj.shape[0] != self.num_frames:
                raise ValueError(
                    f"object {obj.name!r} has {obj.T_world_obj.shape[0]} poses, expected {self.num_frames}"
                )
        ids = [o.object_id for o in self.objects]
        if len(set(ids)) != len(ids):
            raise ValueError(f"object ids must be unique, got {ids}")

    @property
    def num_frames(self) -> int:
        return int(self.T_cam_world.shape[0])


@dataclass(frozen=True, eq=False)
class SurfaceView:
    """One surface seen from one camera, as functions of the camera ray ``r = K^-1 [x, y, 1]``
    through (possibly displaced) query pixel ``x``:

    - texel coordinates: ``H_tex_ray @ r`` dehomogenised (3x3);
    - z-buffer key: ``(depth_num . r) / (depth_den . r)``; for an ordinary plane this is the
      depth ``z`` of the hit point (``depth_num = e_z``, ``depth_den = m``);
    - in front of the camera where ``front . r > 0`` (``front`` is the plane vector ``m``,
      the plane being ``{X : m . X = 1}`` in camera coordinates);
    - ``query_offset``: (H, W, 2) added to each pixel before it is cast (image-space warps of
      injected failures), or None.
    """

    name: str
    role: Role
    object_id: int
    H_tex_ray: np.ndarray
    depth_num: np.ndarray
    depth_den: np.ndarray
    front: np.ndarray
    texture: np.ndarray
    alpha: np.ndarray | None
    query_offset: np.ndarray | None = None


def plane_view(plane: TexturedPlane, T_cam_world: np.ndarray, *, role: Role, object_id: int = 0) -> SurfaceView | None:
    """The :class:`SurfaceView` of a world plane from a camera; None when the plane passes
    through the camera centre (it is then seen edge-on and covers no pixel)."""
    R, t = T_cam_world[:3, :3], T_cam_world[:3, 3]
    n_c = R @ plane.normal
    d_c = n_c @ (R @ plane.origin + t)
    if abs(d_c) < 1e-12:
        return None
    m = n_c / d_c
    P = np.stack([plane.axis_u / (plane.axis_u @ plane.axis_u), plane.axis_v / (plane.axis_v @ plane.axis_v)])
    A = P @ R.T
    b = -P @ (R.T @ t + plane.origin)
    H = np.vstack([A + np.outer(b, m), m])
    return SurfaceView(
        name=plane.name,
        role=role,
        object_id=object_id,
        H_tex_ray=H,
        depth_num=np.array([0.0, 0.0, 1.0]),
        depth_den=m,
        front=m,
        texture=plane.texture,
        alpha=plane.alpha,
    )


def pose_from_center(R_world_cam: np.ndarray, center: np.ndarray) -> np.ndarray:
    """World-to-camera 4x4 from a camera-to-world rotation and the camera centre."""
    return make_pose(R_world_cam.T, -R_world_cam.T @ np.asarray(center, dtype=float))
