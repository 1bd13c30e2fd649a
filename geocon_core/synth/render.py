"""Ray-cast renderer for textured planes: for every pixel and surface, the camera ray is
intersected with the plane analytically, the texture is sampled bilinearly and the nearest
surface wins (z-buffer). Object masks are exact: a pixel carries an object's id exactly when
that object is the visible surface there."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator, Protocol

import cv2
import numpy as np

from .scene import Scene, SurfaceView, plane_view

__all__ = ["RenderedFrame", "RenderHooks", "render_frame", "surface_views"]


@dataclass(frozen=True, eq=False)
class RenderedFrame:
    """One rendered frame.

    rgb: (H, W, 3) uint8.
    labels: (H, W) uint8 object id per pixel, 0 = background.
    depth: (H, W) float32 depth (camera z) of the visible surface; inf where nothing is hit.
    surface: (H, W) int16 index into ``surfaces`` of the visible surface, -1 where nothing is hit.
    surfaces: names of the surfaces in the order they were rendered.
    """

    rgb: np.ndarray
    labels: np.ndarray
    depth: np.ndarray
    surface: np.ndarray
    surfaces: tuple[str, ...]


class RenderHooks(Protocol):
    """What :func:`render_frame` asks of an injected failure (see :mod:`.failures`): change each
    surface before it is drawn, then the finished frame."""

    def adjust_view(self, scene: Scene, t: int, view: SurfaceView) -> SurfaceView: ...

    def post_process(self, scene: Scene, t: int, frame: RenderedFrame) -> RenderedFrame: ...


def surface_views(scene: Scene, t: int, *, with_objects: bool = True) -> Iterator[SurfaceView]:
    """The scene's surfaces at frame ``t`` (background first, then objects)."""
    T = scene.T_cam_world[t]
    for plane in scene.background:
        view = plane_view(plane, T, role="background")
        if view is not None:
            yield view
    if with_objects:
        for obj in scene.objects:
            view = plane_view(obj.plane_at(t), T, role="object", object_id=obj.object_id)
            if view is not None:
                yield view


def _pixel_rays(K: np.ndarray, qx: np.ndarray, qy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    Kinv = np.linalg.inv(K)
    rx = Kinv[0, 0] * qx + Kinv[0, 1] * qy + Kinv[0, 2]
    ry = Kinv[1, 0] * qx + Kinv[1, 1] * qy + Kinv[1, 2]
    rz = Kinv[2, 0] * qx + Kinv[2, 1] * qy + Kinv[2, 2]
    return rx, ry, rz


def _dot(v: np.ndarray, rays: tuple[np.ndarray, np.ndarray, np.ndarray]) -> np.ndarray:
    """``v . ray`` per pixel for a 3-vector ``v`` and per-pixel ray components."""
    rx, ry, rz = rays
    return v[0] * rx + v[1] * ry + v[2] * rz


def render_frame(
    scene: Scene, t: int, failure: RenderHooks | None = None, *, with_objects: bool = True
) -> RenderedFrame:
    """Render frame ``t`` of ``scene``, with ``failure`` injected if given."""
    if not 0 <= t < scene.num_frames:
        raise IndexError(f"frame {t} out of range 0..{scene.num_frames - 1}")
    H, W = scene.height, scene.width
    gy, gx = np.mgrid[0:H, 0:W].astype(np.float64)
    rgb = np.empty((H, W, 3), np.uint8)
    rgb[:] = scene.sky_rgb
    zbuf = np.full((H, W), np.inf)
    labels = np.zeros((H, W), np.uint8)
    surface = np.full((H, W), -1, np.int16)
    names: list[str] = []

    for view in surface_views(scene, t, with_objects=with_objects):
        if failure is not None:
            view = failure.adjust_view(scene, t, view)
        qx, qy = gx, gy
        if view.query_offset is not None:
            qx = gx + view.query_offset[..., 0]
            qy = gy + view.query_offset[..., 1]
        rays = _pixel_rays(scene.K, qx, qy)
        den = _dot(view.depth_den, rays)
        num = _dot(view.depth_num, rays)
        hw = _dot(view.H_tex_ray[2], rays)
        ok = (_dot(view.front, rays) > 0) & (den > 0) & (num > 0) & (np.abs(hw) > 1e-15)
        with np.errstate(divide="ignore", invalid="ignore"):
            depth = np.where(ok, num / den, np.inf)
            a = np.where(ok, _dot(view.H_tex_ray[0], rays) / hw, -1e9)
            b = np.where(ok, _dot(view.H_tex_ray[1], rays) / hw, -1e9)
        th, tw = view.texture.shape[:2]
        ok &= (a >= -0.5) & (a <= tw - 0.5) & (b >= -0.5) & (b <= th - 0.5)
        ok &= depth < zbuf
        if not ok.any():
            names.append(view.name)
            continue
        map_x, map_y = a.astype(np.float32), b.astype(np.float32)
        if view.alpha is not None:
            alpha = cv2.remap(view.alpha, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
            ok &= alpha >= 128
        colour = cv2.remap(view.texture, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT_101)
        rgb[ok] = colour[ok]
        zbuf[ok] = depth[ok]
        labels[ok] = view.object_id
        surface[ok] = len(names)
        names.append(view.name)

    frame = RenderedFrame(rgb=rgb, labels=labels, depth=zbuf.astype(np.float32), surface=surface, surfaces=tuple(names))
    if failure is not None:
        frame = failure.post_process(scene, t, frame)
    return frame
