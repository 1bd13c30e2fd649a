"""Injectable generator failures, each with a severity knob in documented units.

A failure changes how surfaces are seen (``adjust_view``) or edits the finished frame
(``post_process``); the scene's camera and ground truth stay those of the intended geometry,
so a scorer that sees the failure is right to flag the clip.

========================  ======================================================  ===========
kind                      what it does                                            severity
========================  ======================================================  ===========
``breathing``             smooth non-rigid (rubber-sheet) warp of the whole        peak px
                          background, oscillating with a 24-frame period
``slide``                 one background depth layer drifts in the image,          px at the
                          inconsistently with the camera, linearly in time         last frame
``slide_along``           ``slide`` along the direction the camera's motion        px at the
                          carries the layer (``slide_across``: across it)          last frame
``missing_parallax``      the background is rendered as if it were flatter:        fraction
                          each plane is blended towards one fronto-parallel        0..1
                          plane at the mean scene depth (1 = perfectly flat)
``elastic``               non-affine warp inside the first moving object,          peak px
                          oscillating with a 16-frame period
``boiling``               a background region re-synthesises its texture every     blend 0..1
                          frame (blend weight of the fresh texture)
``letterbox``             black bars burned into the top and bottom                fraction of
                                                                                   height/bar
========================  ======================================================  ===========
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from ..geometry import apply_homography, invert_pose, project
from .render import RenderedFrame, render_frame
from .scene import Scene, SurfaceView, plane_view
from .textures import procedural_texture

__all__ = ["Failure", "FailureSpec", "FAILURES", "make_failure", "plane_waves", "plane_wave_field"]


class Failure:
    """Base class: a failure that changes nothing. Subclasses override the hooks."""

    kind: str = "none"

    def __init__(self, scene: Scene, severity: float) -> None:
        self.severity = float(severity)
        self.num_frames = scene.num_frames

    def adjust_view(self, scene: Scene, t: int, view: SurfaceView) -> SurfaceView:
        return view

    def post_process(self, scene: Scene, t: int, frame: RenderedFrame) -> RenderedFrame:
        return frame

    def params(self) -> dict:
        """JSON-able parameters that, with the scene, define the failure exactly."""
        return {}

    def content_box(self, scene: Scene) -> tuple[int, int, int, int]:
        """(x0, y0, x1, y1), end-exclusive: the pixels that carry image content."""
        return (0, 0, scene.width, scene.height)

    def non_rigid_object_ids(self) -> frozenset[int]:
        return frozenset()


def _with_offset(view: SurfaceView, displacement: np.ndarray) -> SurfaceView:
    """Shift what a surface shows by ``displacement`` d: pixel x of the damaged frame shows
    the content that pixel x - d(x) shows in the intact one (the renderer casts that ray), so
    a point at p moves to the x with x - d(x) = p, i.e. by exactly d(x) at its new place."""
    offset = -displacement if view.query_offset is None else view.query_offset - displacement
    return replace(view, query_offset=offset)


def plane_waves(
    rng: np.random.Generator, cycles: tuple[float, float] = (0.6, 2.0)
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The random parameters of a smooth 2-component field of three plane waves per component:
    ``freqs`` (2, 3, 2) in cycles per unit of each coordinate (``cycles`` apart, either sign),
    ``phases`` (2, 3) and ``amps`` (2, 3) in 0.5..1 (:func:`plane_wave_field` evaluates it)."""
    freqs = rng.uniform(*cycles, (2, 3, 2)) * rng.choice([-1, 1], (2, 3, 2))
    phases = rng.uniform(0, 2 * math.pi, (2, 3))
    amps = rng.uniform(0.5, 1.0, (2, 3))
    return freqs, phases, amps


def plane_wave_field(
    freqs: np.ndarray, phases: np.ndarray, amps: np.ndarray, u: np.ndarray, v: np.ndarray
) -> np.ndarray:
    """``phi_c(u, v) = sum_k amps[c][k] * sin(2 pi (fx u + fy v) + phases[c][k])`` (c = 0: x, 1: y)
    at the points (u, v) (arrays of one shape), stacked on a last axis of 2; not normalised."""
    field = np.zeros((*np.shape(u), 2))
    for c in range(2):
        for k in range(3):
            fx, fy = freqs[c][k]
            field[..., c] += amps[c][k] * np.sin(2 * math.pi * (fx * u + fy * v) + phases[c][k])
    return field


class Breathing(Failure):
    """Rubber-sheet warp of the background: content near pixel x is displaced by
    ``d_t(x) = severity * sin(2 pi t / period) * phi(x)``, where ``phi`` is a smooth random
    field (three plane waves per component, 0.6-2 cycles per image size; :func:`plane_waves`)
    normalised so that ``max_x |phi(x)| = 1``. Frame 0 is unwarped."""

    kind = "breathing"
    period = 24

    def __init__(self, scene: Scene, severity: float) -> None:
        super().__init__(scene, severity)
        self.freqs, self.phases, self.amps = plane_waves(np.random.default_rng([scene.seed, 7001]))
        gy, gx = np.mgrid[0 : scene.height, 0 : scene.width].astype(np.float64)
        field = plane_wave_field(self.freqs, self.phases, self.amps, gx / scene.width, gy / scene.height)
        self.field = field / np.linalg.norm(field, axis=2).max()

    def amplitude(self, t: int) -> float:
        return math.sin(2 * math.pi * t / self.period)

    def displacement(self, t: int) -> np.ndarray:
        """(H, W, 2) image-space displacement of background content at frame t, in pixels."""
        return self.severity * self.amplitude(t) * self.field

    def adjust_view(self, scene: Scene, t: int, view: SurfaceView) -> SurfaceView:
        if view.role != "background" or self.amplitude(t) == 0:
            return view
        return _with_offset(view, self.displacement(t))

    def params(self) -> dict:
        return {
            "period_frames": self.period,
            "formula": "d_t(x) = severity * sin(2 pi t / period) * phi(x) / max|phi|; "
            "phi_c(x, y) = sum_k amp[c][k] * sin(2 pi (fx x / W + fy y / H) + phase[c][k])",
            "freqs": self.freqs.tolist(),
            "phases": self.phases.tolist(),
            "amps": self.amps.tolist(),
        }


class Slide(Failure):
    """One background layer (the scene's ``slide_layer``) drifts by
    ``severity * t / (T - 1)`` pixels along a fixed direction: within 30 degrees of the image's
    horizontal, either way (seeded by the scene)."""

    kind = "slide"

    def __init__(self, scene: Scene, severity: float) -> None:
        super().__init__(scene, severity)
        self.layer = scene.notes["slide_layer"]
        self.direction = self._direction(scene)
        self._shape = (scene.height, scene.width, 2)

    def _direction(self, scene: Scene) -> np.ndarray:
        rng = np.random.default_rng([scene.seed, 7101])
        ang = rng.uniform(-math.pi / 6, math.pi / 6) + rng.choice([0.0, math.pi])
        return np.array([math.cos(ang), math.sin(ang)])

    def shift(self, t: int) -> np.ndarray:
        """(2,) pixel shift of the sliding layer at frame t."""
        return self.severity * t / max(1, self.num_frames - 1) * self.direction

    def adjust_view(self, scene: Scene, t: int, view: SurfaceView) -> SurfaceView:
        if view.name != self.layer or t == 0:
            return view
        return _with_offset(view, np.broadcast_to(self.shift(t), self._shape))

    def params(self) -> dict:
        return {
            "layer": self.layer,
            "direction": self.direction.tolist(),
            "formula": "shift_t = severity * t / (T-1) * direction",
        }


def travel_direction(scene: Scene, layer: str) -> np.ndarray:
    """Unit image direction (x right, y down) in which the camera's motion carries the centre of
    background plane ``layer`` from the first frame to the last (the way its parallax runs); the
    image's horizontal when the camera does not move it."""
    plane = next(p for p in scene.background if p.name == layer)
    h, w = plane.texture.shape[:2]
    centre = plane.origin + (w - 1) / 2 * plane.axis_u + (h - 1) / 2 * plane.axis_v
    a = project(scene.K, scene.T_cam_world[0], centre[None])[0]
    b = project(scene.K, scene.T_cam_world[-1], centre[None])[0]
    d = b - a
    n = float(np.linalg.norm(d))
    return d / n if n > 1e-6 else np.array([1.0, 0.0])


class SlideAlong(Slide):
    """:class:`Slide` along the layer's travel direction (:func:`travel_direction`), against it
    or with it (seeded by the scene): the drift a two-view model reads as another depth."""

    kind = "slide_along"

    def _direction(self, scene: Scene) -> np.ndarray:
        sign = np.random.default_rng([scene.seed, 7102]).choice([-1.0, 1.0])
        return sign * travel_direction(scene, scene.notes["slide_layer"])


class SlideAcross(Slide):
    """:class:`Slide` across the layer's travel direction (perpendicular, either way, seeded)."""

    kind = "slide_across"

    def _direction(self, scene: Scene) -> np.ndarray:
        sign = np.random.default_rng([scene.seed, 7103]).choice([-1.0, 1.0])
        dx, dy = travel_direction(scene, scene.notes["slide_layer"])
        return sign * np.array([-dy, dx])


class MissingParallax(Failure):
    """The camera still translates, but every background plane ``m_p`` (plane vector in the
    first camera, ``m . X = 1``) is replaced by ``(1 - s) m_p + s m_ref`` with ``m_ref`` the
    fronto-parallel plane at the mean depth of the first frame. Frame 0 is unchanged; at
    ``s = 1`` the background moves by one homography, as if the scene were flat."""

    kind = "missing_parallax"

    def __init__(self, scene: Scene, severity: float) -> None:
        super().__init__(scene, severity)
        c0 = -scene.T_cam_world[0][:3, :3].T @ scene.T_cam_world[0][:3, 3]
        centers = [-T[:3, :3].T @ T[:3, 3] for T in scene.T_cam_world]
        if max(np.linalg.norm(c - c0) for c in centers) < 1e-9:
            raise ValueError("missing_parallax needs a translating camera (families C3, C5, C6)")
        depth = render_frame(scene, 0, with_objects=False).depth
        self.z_ref = float(depth[np.isfinite(depth)].mean())
        self.m_ref = np.array([0.0, 0.0, 1.0 / self.z_ref])
        self._view0 = {p.name: plane_view(p, scene.T_cam_world[0], role="background") for p in scene.background}

    def adjust_view(self, scene: Scene, t: int, view: SurfaceView) -> SurfaceView:
        view0 = self._view0.get(view.name)
        if view.role != "background" or view0 is None:
            return view
        T_t_0 = scene.T_cam_world[t] @ invert_pose(scene.T_cam_world[0])
        R, tr = T_t_0[:3, :3], T_t_0[:3, 3]
        m0 = view0.depth_den
        m_a = (1.0 - self.severity) * m0 + self.severity * self.m_ref
        denom = 1.0 + m_a @ (R.T @ tr)
        if abs(denom) < 1e-12:
            return replace(view, front=np.zeros(3))
        m_t = R @ m_a / denom
        L = R.T @ (np.eye(3) - np.outer(tr, m_t))  # cam-t point on the flattened plane -> cam-0 point
        return replace(
            view, H_tex_ray=view0.H_tex_ray @ L, depth_num=L[2].copy(), depth_den=m0 @ L, front=m_t, query_offset=None
        )

    def params(self) -> dict:
        return {
            "reference_depth": self.z_ref,
            "formula": "m_p <- (1 - severity) m_p + severity [0, 0, 1/reference_depth]",
        }


class Elastic(Failure):
    """Non-affine warp inside the first object: with ``u = (x - c_t) / rho_t`` (object centre
    and half-extent in the image at frame t), content is displaced by
    ``severity * sin(2 pi t / period) * [cos(pi u_y), cos(pi u_x)] / sqrt(2)``."""

    kind = "elastic"
    period = 16

    def __init__(self, scene: Scene, severity: float) -> None:
        super().__init__(scene, severity)
        if not scene.objects:
            raise ValueError("elastic needs a family with moving objects (C4, C6)")
        self.object_id = min(o.object_id for o in scene.objects)
        self._obj = next(o for o in scene.objects if o.object_id == self.object_id)
        gy, gx = np.mgrid[0 : scene.height, 0 : scene.width].astype(np.float64)
        self._grid = (gx, gy)

    def amplitude(self, t: int) -> float:
        return math.sin(2 * math.pi * t / self.period)

    def object_frame(self, scene: Scene, t: int) -> tuple[np.ndarray, float]:
        """Projected centre (2,) and half-extent (px) of the object at frame t."""
        x = project(scene.K, scene.T_cam_world[t], self._obj.plane_at(t).corners())
        return x.mean(axis=0), 0.5 * float(max(np.ptp(x[:, 0]), np.ptp(x[:, 1])))

    def displacement(self, scene: Scene, t: int) -> np.ndarray:
        c, rho = self.object_frame(scene, t)
        ux = (self._grid[0] - c[0]) / rho
        uy = (self._grid[1] - c[1]) / rho
        a = self.severity * self.amplitude(t) / math.sqrt(2.0)
        return np.stack([a * np.cos(math.pi * uy), a * np.cos(math.pi * ux)], axis=-1)

    def adjust_view(self, scene: Scene, t: int, view: SurfaceView) -> SurfaceView:
        if view.object_id != self.object_id or self.amplitude(t) == 0:
            return view
        return _with_offset(view, self.displacement(scene, t))

    def non_rigid_object_ids(self) -> frozenset[int]:
        return frozenset({self.object_id})

    def params(self) -> dict:
        return {"object_id": self.object_id, "period_frames": self.period}


def _box_corners(box: np.ndarray) -> np.ndarray:
    x0, y0, x1, y1 = box
    return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=float)


class Boiling(Failure):
    """A background region (a texel box on the surface seen at a central image point in
    frame 0) has its texture re-synthesised every frame:
    ``(1 - s) * texture + s * fresh_noise_t``. ``image_box0`` bounds the region in frame 0."""

    kind = "boiling"

    def __init__(self, scene: Scene, severity: float) -> None:
        super().__init__(scene, severity)
        self.seed = scene.seed
        rng = np.random.default_rng([scene.seed, 7201])
        frame0 = render_frame(scene, 0, with_objects=False)
        W, H = scene.width, scene.height
        cx, cy = W * rng.uniform(0.35, 0.65), H * rng.uniform(0.35, 0.65)
        idx = int(frame0.surface[int(cy), int(cx)])
        self.plane_name = frame0.surfaces[idx]
        plane = next(p for p in scene.background if p.name == self.plane_name)
        view0 = plane_view(plane, scene.T_cam_world[0], role="background")
        assert view0 is not None
        box = np.array([[cx - 0.15 * W, cy - 0.15 * H], [cx + 0.15 * W, cy + 0.15 * H]])
        H_tex_img = view0.H_tex_ray @ np.linalg.inv(scene.K)
        tex = apply_homography(H_tex_img, _box_corners(box.reshape(-1)))
        tw, th = plane.texture_size
        x0, y0 = np.clip(np.floor(np.nanmin(tex, axis=0)).astype(int), 0, [tw - 1, th - 1])
        x1, y1 = np.clip(np.ceil(np.nanmax(tex, axis=0)).astype(int) + 1, 1, [tw, th])
        self.texel_box = (int(x0), int(y0), int(x1), int(y1))
        # the region actually re-synthesised, as seen in frame 0 (bounding box, pixels)
        img = apply_homography(
            np.linalg.inv(H_tex_img), _box_corners(np.array(self.texel_box, float) - [0.5, 0.5, 0.5, 0.5])
        )
        self.image_box0 = [float(v) for v in (*np.nanmin(img, axis=0), *np.nanmax(img, axis=0))]
        self._texture = plane.texture

    def texture_at(self, t: int) -> np.ndarray:
        x0, y0, x1, y1 = self.texel_box
        out = self._texture.copy()
        noise = procedural_texture(np.random.default_rng([self.seed, 7202, t]), y1 - y0, x1 - x0)
        region = out[y0:y1, x0:x1].astype(np.float32)
        out[y0:y1, x0:x1] = np.clip((1 - self.severity) * region + self.severity * noise + 0.5, 0, 255).astype(np.uint8)
        return out

    def adjust_view(self, scene: Scene, t: int, view: SurfaceView) -> SurfaceView:
        if view.name != self.plane_name:
            return view
        return replace(view, texture=self.texture_at(t))

    def params(self) -> dict:
        return {"plane": self.plane_name, "texel_box": list(self.texel_box), "image_box_frame0": self.image_box0}


class Letterbox(Failure):
    """Black bars of ``round(severity * H)`` rows burned into the top and bottom."""

    kind = "letterbox"

    def bar_rows(self, scene: Scene) -> int:
        return int(round(self.severity * scene.height))

    def post_process(self, scene: Scene, t: int, frame: RenderedFrame) -> RenderedFrame:
        bar = self.bar_rows(scene)
        rgb, labels = frame.rgb.copy(), frame.labels.copy()
        for sl in (slice(0, bar), slice(scene.height - bar, scene.height)):
            rgb[sl] = 0
            labels[sl] = 0
        return replace(frame, rgb=rgb, labels=labels)

    def content_box(self, scene: Scene) -> tuple[int, int, int, int]:
        bar = self.bar_rows(scene)
        return (0, bar, scene.width, scene.height - bar)

    def params(self) -> dict:
        return {"bar_rows_formula": "round(severity * height) rows at the top and at the bottom"}


@dataclass(frozen=True)
class FailureSpec:
    """One failure kind: its name, the unit of its severity, default, range, a description and its class."""

    kind: str
    unit: str
    default: float
    low: float
    high: float
    summary: str
    factory: Callable[[Scene, float], Failure]

    def check(self, severity: float) -> float:
        if not (self.low < severity <= self.high):
            raise ValueError(
                f"severity for {self.kind!r} must be in ({self.low:g}, {self.high:g}] {self.unit}, got {severity:g}"
            )
        return float(severity)


FAILURES: dict[str, FailureSpec] = {
    s.kind: s
    for s in (
        FailureSpec("breathing", "px (peak displacement)", 3.0, 0.0, 50.0, "background rubber-sheet warp", Breathing),
        FailureSpec("slide", "px (drift at the last frame)", 8.0, 0.0, 200.0, "one depth layer slides", Slide),
        FailureSpec(
            "slide_along",
            "px (drift at the last frame)",
            8.0,
            0.0,
            200.0,
            "a layer slides along its travel",
            SlideAlong,
        ),
        FailureSpec(
            "slide_across",
            "px (drift at the last frame)",
            8.0,
            0.0,
            200.0,
            "a layer slides across its travel",
            SlideAcross,
        ),
        FailureSpec(
            "missing_parallax",
            "fraction of parallax removed",
            1.0,
            0.0,
            1.0,
            "translating camera, flat scene",
            MissingParallax,
        ),
        FailureSpec(
            "elastic", "px (peak non-affine displacement)", 4.0, 0.0, 50.0, "object deforms non-rigidly", Elastic
        ),
        FailureSpec(
            "boiling", "blend weight of fresh texture", 0.8, 0.0, 1.0, "texture re-synthesised per frame", Boiling
        ),
        FailureSpec("letterbox", "fraction of height per bar", 0.12, 0.0, 0.4, "black bars burned in", Letterbox),
    )
}
"""The failure kinds by name (:class:`FailureSpec`)."""


def failure_spec(kind: str) -> FailureSpec:
    try:
        return FAILURES[kind]
    except KeyError:
        raise ValueError(f"unknown failure {kind!r}; valid: {', '.join(FAILURES)}") from None


def make_failure(kind: str, scene: Scene, severity: float | None = None) -> Failure:
    """Instantiate failure ``kind`` for ``scene`` (default severity if None); raises
    ValueError listing the valid kinds for an unknown name, or when the severity is out of
    range or the scene cannot carry the failure."""
    spec = failure_spec(kind)
    return spec.factory(scene, spec.check(spec.default if severity is None else severity))
