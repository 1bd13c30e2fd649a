"""The six scene families of the paper (C1-C6), built from textured planes.

World coordinates are those of the first camera (x right, y down, z forward); every layout
and trajectory is jittered by the seed. Camera motion is linear in time (constant velocity
and angular rate) from the first frame to the last.

:func:`build_scene` can replace a family's camera path by another linear one
(``camera_end_center``, ``camera_end_angles``) and speed its objects up or down
(``object_speed``) while keeping the family's layout, textures and object shapes; with the
defaults the scene is exactly the family's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from ..geometry import intrinsics_from_fov, make_pose, rotation_xyz
from .scene import ObjectTrack, Scene, TexturedPlane, pose_from_center
from .textures import object_texture, procedural_texture, shape_alpha

__all__ = ["Family", "FAMILIES", "family_info", "build_scene"]

MAX_TEXELS = 2048


def _panel(
    rng: np.random.Generator,
    name: str,
    K: np.ndarray,
    center: tuple[float, float, float],
    size: tuple[float, float],
    *,
    yaw: float = 0.0,
    pitch: float = 0.0,
    contrast: float = 1.0,
    shape: str | None = None,
    parent_center: bool = False,
) -> TexturedPlane:
    """A textured rectangle of ``size`` (width, height) world units centred at ``center``,
    turned by ``yaw``/``pitch`` degrees, with one texel per pixel at the centre's depth.
    With ``parent_center`` the plane is centred on the origin (object coordinates) and
    ``center[2]`` only sets the texel density."""
    width, height = size
    texel = max(center[2] / K[0, 0], max(width, height) / MAX_TEXELS)
    tw, th = max(2, math.ceil(width / texel)), max(2, math.ceil(height / texel))
    R = rotation_xyz(yaw, pitch)
    u, v = R @ np.array([texel, 0.0, 0.0]), R @ np.array([0.0, texel, 0.0])
    c = np.zeros(3) if parent_center else np.asarray(center, dtype=float)
    origin = c - u * (tw - 1) / 2 - v * (th - 1) / 2
    alpha = shape_alpha(th, tw, shape) if shape else None
    if alpha is not None and parent_center:
        texture = object_texture(rng, alpha)
    else:
        texture = procedural_texture(rng, th, tw, contrast=contrast)
    return TexturedPlane(name=name, origin=origin, axis_u=u, axis_v=v, texture=texture, alpha=alpha)


def _wall(
    rng: np.random.Generator,
    K: np.ndarray,
    W: int,
    H: int,
    z: float,
    extra_deg: float,
    reach: float,
    contrast: float = 1.0,
) -> TexturedPlane:
    """Back wall at depth z wide enough to fill the view for view directions up to
    ``extra_deg`` beyond the field of view and camera shifts up to ``reach``."""
    half_x = math.atan((W / 2) / K[0, 0])
    half_y = math.atan((H / 2) / K[1, 1])
    ext = math.radians(extra_deg)
    w = 2 * (z * math.tan(min(half_x + ext, math.radians(80))) + reach)
    h = 2 * (z * math.tan(min(half_y + ext, math.radians(80))) + reach)
    return _panel(rng, "wall", K, (0.0, 0.0, z), (w, h), contrast=contrast)


def _vec3(name: str, value: Sequence[float]) -> np.ndarray:
    v = np.asarray(value, dtype=float)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ValueError(f"{name} must be three finite numbers, got {value!r}")
    return v


def _jit(rng: np.random.Generator, scale: float) -> float:
    return float(rng.uniform(-scale, scale))


def _static_cams(n: int) -> np.ndarray:
    return np.repeat(np.eye(4)[None], n, axis=0)


def _moving_cams(n: int, end_center: np.ndarray, end_angles: tuple[float, float, float]) -> np.ndarray:
    """Camera from the origin (identity) to ``end_center`` with yaw/pitch/roll ramping
    linearly to ``end_angles`` degrees."""
    poses = []
    for i in range(n):
        u = i / max(1, n - 1)
        R = rotation_xyz(*(a * u for a in end_angles))
        poses.append(pose_from_center(R, u * np.asarray(end_center, dtype=float)))
    return np.stack(poses)


def _jittered_panel(
    rng: np.random.Generator,
    K: np.ndarray,
    name: str,
    center: tuple[float, float, float],
    spread: tuple[float, float, float],
    size: tuple[float, float],
    yaw: float,
) -> TexturedPlane:
    """A panel centred at ``center`` moved by up to ``spread`` on each axis, turned ``yaw``
    degrees give or take 5 (drawn in that order)."""
    x, y, z = (c + _jit(rng, d) for c, d in zip(center, spread, strict=True))
    return _panel(rng, name, K, (x, y, z), size, yaw=yaw + _jit(rng, 5))


def _layers_far(
    rng: np.random.Generator, K: np.ndarray, W: int, H: int, extra_deg: float, reach: float
) -> list[TexturedPlane]:
    """Wall plus a mid and a near panel at moderate depths (C1, C2, C4)."""
    return [
        _wall(rng, K, W, H, 11.0 + _jit(rng, 1.0), extra_deg, reach),
        _jittered_panel(rng, K, "panel_mid", (-1.3, -0.2, 6.0), (0.3, 0.2, 0.5), (3.2, 2.4), 18),
        _jittered_panel(rng, K, "panel_near", (1.1, 0.5, 3.6), (0.2, 0.15, 0.3), (1.5, 1.2), -25),
    ]


def _layers_parallax(
    rng: np.random.Generator, K: np.ndarray, W: int, H: int, extra_deg: float, reach: float
) -> list[TexturedPlane]:
    """Wall plus panels close to the camera, for strong parallax (C3, C5)."""
    return [
        _wall(rng, K, W, H, 10.0 + _jit(rng, 1.0), extra_deg, reach),
        _jittered_panel(rng, K, "panel_mid", (0.9, -0.3, 4.8), (0.2, 0.2, 0.4), (2.4, 2.0), -15),
        _jittered_panel(rng, K, "panel_near", (-0.2, 0.35, 2.3), (0.15, 0.1, 0.2), (1.0, 0.9), 20),
    ]


def _object(
    rng: np.random.Generator,
    K: np.ndarray,
    object_id: int,
    name: str,
    size: tuple[float, float],
    depth: float,
    shape: str,
    poses: list[np.ndarray],
) -> ObjectTrack:
    plane = _panel(rng, name, K, (0.0, 0.0, depth), size, shape=shape, parent_center=True)
    return ObjectTrack(object_id=object_id, name=name, plane=plane, T_world_obj=np.stack(poses))


def _progress(n: int, speed: float) -> list[float]:
    """How far along its path an object is at each of ``n`` frames: 0 at the first frame,
    ``speed`` at the last (1: the family's path, exactly)."""
    return [speed * i / max(1, n - 1) for i in range(n)]


def _objects(rng: np.random.Generator, K: np.ndarray, n: int, speed: float = 1.0) -> tuple[ObjectTrack, ...]:
    """A disc crossing left to right while spinning in its plane, and a card moving
    diagonally, receding and turning (both rigid); ``speed`` scales how far along their paths
    they get (:func:`_progress`)."""
    us = _progress(n, speed)
    y1, z1, spin = 0.25 + _jit(rng, 0.1), 3.0 + _jit(rng, 0.2), 40 + _jit(rng, 10)
    disc = [
        make_pose(rotation_xyz(roll_deg=spin * u), np.array((-1.1 + 2.2 * u, y1 + 0.1 * math.sin(math.pi * u), z1)))
        for u in us
    ]
    x2, y2, turn = 0.9 + _jit(rng, 0.1), -0.55 + _jit(rng, 0.1), 25 + _jit(rng, 8)
    card = [
        make_pose(rotation_xyz(yaw_deg=turn * u), np.array((x2 - 1.3 * u, y2 + 0.7 * u, 4.2 + 0.4 * u))) for u in us
    ]
    return (
        _object(rng, K, 1, "disc", (0.64, 0.64), z1, "disc", disc),
        _object(rng, K, 2, "card", (0.7, 0.45), 4.4, "card", card),
    )


def _c1(rng, K, W, H, n, speed=1.0):
    return _static_cams(n), _layers_far(rng, K, W, H, 5, 0.0), ()


def _c2(rng, K, W, H, n, speed=1.0):
    angles = (rng.choice([-1, 1]) * rng.uniform(8, 14), rng.uniform(3, 6), rng.choice([-1, 1]) * rng.uniform(4, 8))
    return _moving_cams(n, np.zeros(3), angles), _layers_far(rng, K, W, H, 25, 0.0), ()


def _c3(rng, K, W, H, n, speed=1.0):
    end = np.array([0.8 + _jit(rng, 0.1), 0.05 + _jit(rng, 0.05), 0.25 + _jit(rng, 0.1)])
    return _moving_cams(n, end, (0, 0, 0)), _layers_parallax(rng, K, W, H, 5, 1.2), ()


def _c4(rng, K, W, H, n, speed=1.0):
    return _static_cams(n), _layers_far(rng, K, W, H, 5, 0.0), _objects(rng, K, n, speed)


def _c5(rng, K, W, H, n, speed=1.0):
    end = np.array([0.55 + _jit(rng, 0.1), -0.12 + _jit(rng, 0.05), 0.45 + _jit(rng, 0.1)])
    angles = (-9 + _jit(rng, 2), 3 + _jit(rng, 1), 2 + _jit(rng, 1))
    return _moving_cams(n, end, angles), _layers_parallax(rng, K, W, H, 20, 1.0), ()


def _c6(rng, K, W, H, n, speed=1.0):
    """Stress: a low-texture wall, thin poles, a near occluder and an object passing behind it."""
    end = np.array([0.7 + _jit(rng, 0.1), _jit(rng, 0.05), 0.15 + _jit(rng, 0.05)])
    planes = [_wall(rng, K, W, H, 9.0 + _jit(rng, 0.8), 5, 1.0, contrast=0.06)]
    planes.append(
        _panel(
            rng, "panel_mid", K, (-1.6 + _jit(rng, 0.2), 0.2, 5.5 + _jit(rng, 0.3)), (1.6, 1.4), yaw=15, contrast=0.3
        )
    )
    for i, x in enumerate(np.linspace(-1.4, 1.6, 5) + rng.uniform(-0.1, 0.1, 5)):
        planes.append(_panel(rng, f"pole_{i}", K, (float(x), 0.0, 2.4 + 0.4 * i + _jit(rng, 0.1)), (0.05, 3.0)))
    planes.append(_panel(rng, "occluder", K, (0.9 + _jit(rng, 0.1), 0.55, 1.9 + _jit(rng, 0.1)), (0.9, 1.0), yaw=-10))
    us = _progress(n, speed)
    y, z = -0.1 + _jit(rng, 0.1), 3.1 + _jit(rng, 0.2)
    disc = [make_pose(rotation_xyz(roll_deg=30 * u), (-0.9 + 2.4 * u, y, z)) for u in us]
    objects = (_object(rng, K, 1, "disc", (0.6, 0.6), z, "disc", disc),)
    return _moving_cams(n, end, (0, 0, 0)), planes, objects


@dataclass(frozen=True)
class Family:
    code: str
    slug: str
    title: str
    builder: Callable
    """``builder(rng, K, W, H, n, speed)`` -> (camera poses, background planes, objects); ``speed``
    scales the objects' progress along their paths (families without objects ignore it)."""
    slide_layer: str = "panel_mid"


FAMILIES: dict[str, Family] = {
    f.code: f
    for f in (
        Family("C1", "c1_static", "static camera", _c1),
        Family("C2", "c2_rotation", "pure rotation (pan, tilt, roll)", _c2),
        Family("C3", "c3_translation", "translation with strong parallax", _c3),
        Family("C4", "c4_objects", "static camera with moving objects", _c4),
        Family("C5", "c5_complex", "rotation and translation", _c5),
        Family("C6", "c6_stress", "stress: thin structures, low texture, occlusions", _c6),
    )
}
"""The scene families C1-C6 by code (SPEC section 5)."""


def family_info(name: str) -> Family:
    """Look a family up by code (``C3``) or slug (``c3_translation``), case-insensitively."""
    key = name.strip().lower()
    for fam in FAMILIES.values():
        if key in (fam.code.lower(), fam.slug, fam.slug.split("_", 1)[1]):
            return fam
    valid = ", ".join(f"{f.code} ({f.slug})" for f in FAMILIES.values())
    raise ValueError(f"unknown family {name!r}; valid: {valid}")


def build_scene(
    family: str,
    *,
    seed: int = 0,
    width: int = 640,
    height: int = 360,
    num_frames: int = 48,
    fps: float = 24.0,
    fov_x_deg: float = 60.0,
    camera_end_center: Sequence[float] | None = None,
    camera_end_angles: Sequence[float] | None = None,
    object_speed: float = 1.0,
) -> Scene:
    """Build the scene of ``family`` (code or slug), deterministic in ``seed``.

    ``camera_end_center`` (x, y, z world units, first-camera coordinates) and
    ``camera_end_angles`` (yaw, pitch, roll degrees, :func:`~geocon_core.geometry.twoview.rotation_xyz`)
    replace the family's camera path by a linear one from the identity to that pose (a missing
    one of the two is zero); ``object_speed`` (>= 0) scales how far the objects get along their
    paths by the last frame (0: they stay at their first pose). The layout, textures and objects'
    first poses are the family's whatever these are; with the defaults (None, None, 1.0) the
    scene is exactly the family's. A family's walls are sized for its own camera motion: a much
    larger one shows the grey sky past their edges."""
    fam = family_info(family)
    if width < 16 or height < 16:
        raise ValueError(f"size must be at least 16x16, got {width}x{height}")
    if num_frames < 2:
        raise ValueError(f"a clip needs at least 2 frames, got {num_frames}")
    if not fps > 0:
        raise ValueError(f"fps must be positive, got {fps}")
    if not (math.isfinite(object_speed) and object_speed >= 0):
        raise ValueError(f"object_speed must be a finite number >= 0, got {object_speed}")
    rng = np.random.default_rng([seed, int(fam.code[1])])
    K = intrinsics_from_fov(width, height, fov_x_deg)
    cams, planes, objects = fam.builder(rng, K, width, height, num_frames, object_speed)
    if camera_end_center is not None or camera_end_angles is not None:
        center = np.zeros(3) if camera_end_center is None else _vec3("camera_end_center", camera_end_center)
        angles = np.zeros(3) if camera_end_angles is None else _vec3("camera_end_angles", camera_end_angles)
        cams = _moving_cams(num_frames, center, (float(angles[0]), float(angles[1]), float(angles[2])))
    return Scene(
        family=fam.code,
        seed=seed,
        width=width,
        height=height,
        fps=float(fps),
        K=K,
        T_cam_world=cams,
        background=tuple(planes),
        objects=tuple(objects),
        fov_x_deg=fov_x_deg,
        notes={"slide_layer": fam.slide_layer},
    )
