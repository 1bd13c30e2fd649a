"""The clip of ``geocon teach``: what the sliders set (:class:`TeachParams`) and the rendering of
one short synthetic clip from them (:func:`render_teach_clip`).

The scene is family C4's layout (a wall, two panels, a spinning disc and a turning card; see
:mod:`geocon_core.synth.families`) with a camera path of the sliders' choosing (a pan to the left
and a move to the right, linear in time), the failures of :mod:`geocon_core.synth.failures`
injected together (background breathing, a sliding panel, an elastic disc) and the objects sped
up or slowed down. Rendering only: the clip is scored by :func:`geocon_core.scoring.scorer.score_clip`.
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Literal, Sequence

import cv2
import numpy as np

from geocon_core.geometry import relative_pose, t_inf_from_pose
from geocon_core.media import Mp4Writer, PngSequenceWriter
from geocon_core.synth import Failure, RenderedFrame, Scene, SurfaceView, build_scene, make_failure, render_frame
from geocon_core.synth import mean_scene_distance as scene_distance

__all__ = [
    "FAMILY",
    "SIZES",
    "SENSOR_NOISE",
    "Slider",
    "SLIDERS",
    "TeachParams",
    "TeachClip",
    "mean_distance",
    "render_teach_clip",
]

FAMILY = "C4"
"""The scene family whose layout the app teaches on (static background layers and two objects)."""
SIZES = ("320x180", "480x270", "640x360")
"""Render sizes offered (width x height, px)."""
SENSOR_NOISE = 2.0
"""Standard deviation (grey levels) of the seeded sensor noise on every frame, as ``geocon synth``."""


@dataclass(frozen=True)
class Slider:
    """One slider of the app: the :class:`TeachParams` field it sets, its range and its help."""

    name: str
    label: str
    low: float
    high: float
    step: float
    unit: str
    hint: str


_ROTATION = "The camera pans left by this many degrees from the first frame to the last. A pure rotation moves "
_ROTATION += "every background point by one homography, however far it turns."
_TRANSLATION = "The camera moves right by this share of the mean scene distance (the unit of t_inf). Past 0.05 "
_TRANSLATION += "the layers' parallax needs a fundamental matrix; up to 0.03 a homography explains it."
_BREATHING = "Peak displacement (px) of a smooth rubber-sheet warp of the whole background (24-frame period): no "
_BREATHING += "camera motion explains it."
_SLIDE = "How far (px, at the last frame) the middle panel drifts in the image, whatever the camera does."
_ELASTIC = "Peak non-affine displacement (px) inside the disc (16-frame period): a rigid object's flow is one "
_ELASTIC += "affine motion, a deforming one's is not."
_SPEED = "How far the objects get along their C4 paths (1: the family's). Faster motion makes the dense flow "
_SPEED += "less exact, so even a rigid object scores higher."

SLIDERS: tuple[Slider, ...] = (
    Slider("rotation_deg", "camera rotation", 0.0, 6.0, 0.5, "°", _ROTATION),
    Slider("translation", "camera translation", 0.0, 0.12, 0.005, "", _TRANSLATION),
    Slider("breathing_px", "background breathing", 0.0, 20.0, 0.5, " px", _BREATHING),
    Slider("slide_px", "background slide", 0.0, 40.0, 1.0, " px", _SLIDE),
    Slider("elastic_px", "object elasticity", 0.0, 30.0, 1.0, " px", _ELASTIC),
    Slider("object_speed", "object speed", 0.0, 1.5, 0.05, "×", _SPEED),
)
"""The sliders, in the order shown. The rotation is kept within what the C4 wall covers (about
5° past the field of view), so the grey sky past its edge stays out of view."""


@dataclass(frozen=True)
class TeachParams:
    """What the sliders and menus set: one synthetic clip and how its masks reach the scorer."""

    rotation_deg: float = 0.0
    """Pan to the left at the last frame, degrees."""
    translation: float = 0.0
    """Camera travel to the right at the last frame, as a share of the mean scene distance."""
    breathing_px: float = 0.0
    """Peak displacement of the background's rubber-sheet warp, px (0: none)."""
    slide_px: float = 0.0
    """Drift of the middle panel at the last frame, px (0: none)."""
    elastic_px: float = 0.0
    """Peak non-affine displacement inside the disc, px (0: rigid)."""
    object_speed: float = 0.5
    """Progress of the objects along their C4 paths by the last frame (1: the family's)."""
    size: str = SIZES[0]
    """Render size, ``WIDTHxHEIGHT`` px (one of :data:`SIZES`)."""
    codec: Literal["h264", "png"] = "h264"
    """How the clip is stored: H.264 MP4 or lossless PNG frames."""
    masks: Literal["rendered", "motion"] = "rendered"
    """Object masks: the renderer's exact ones, or the scorer's built-in motion segmentation."""
    num_frames: int = 16
    """Frames per clip."""
    seed: int = 0
    """Seed of the scene's layout and textures, and of the sensor noise."""

    def __post_init__(self) -> None:
        for s in SLIDERS:
            v = getattr(self, s.name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and s.low <= v <= s.high):
                raise ValueError(f"{s.label} must be in [{s.low:g}, {s.high:g}]{s.unit}, got {v!r}")
        if self.size not in SIZES:
            raise ValueError(f"size must be one of {', '.join(SIZES)}, got {self.size!r}")
        if self.codec not in ("h264", "png"):
            raise ValueError(f"codec must be h264 or png, got {self.codec!r}")
        if self.masks not in ("rendered", "motion"):
            raise ValueError(f"masks must be rendered or motion, got {self.masks!r}")
        if not 4 <= self.num_frames <= 120:
            raise ValueError(f"--frames must be between 4 and 120 frames per clip, got {self.num_frames}")

    @property
    def width_height(self) -> tuple[int, int]:
        """The render size (width, height), px."""
        w, h = self.size.split("x")
        return int(w), int(h)


@dataclass(frozen=True)
class TeachClip:
    """A rendered teaching clip: the video (``clip.mp4`` or a ``clip.frames/`` PNG folder) and
    its exact object masks (``masks/``: one 8-bit label PNG per frame, 0 = background), with what
    the renderer knows for sure."""

    video: Path
    masks: Path
    t_inf_truth: float
    """``t_inf`` of the rendered camera path (first -> last pose, unit mean scene distance)."""
    T_cam0_camT_truth: np.ndarray
    """(4, 4) the rendered first -> last camera pose, translation in units of the mean scene
    distance (the scale of the gate's pose)."""
    object_names: dict[int, str]
    """Object id (mask label) -> name (``disc``, ``card``)."""
    deforming_id: int
    """The object the elasticity slider deforms."""


class _Failures:
    """Several injected failures at once (a :class:`~geocon_core.synth.render.RenderHooks`): each
    one's change to a surface applies after the previous one's, so displacements add up."""

    def __init__(self, failures: Sequence[Failure]) -> None:
        self.failures = tuple(failures)

    def adjust_view(self, scene: Scene, t: int, view: SurfaceView) -> SurfaceView:
        for f in self.failures:
            view = f.adjust_view(scene, t, view)
        return view

    def post_process(self, scene: Scene, t: int, frame: RenderedFrame) -> RenderedFrame:
        for f in self.failures:
            frame = f.post_process(scene, t, frame)
        return frame


def _noisy(rgb: np.ndarray, sigma: float, seed: int, t: int) -> np.ndarray:
    """``rgb`` plus seeded Gaussian sensor noise (the seed stream ``geocon synth`` uses)."""
    if sigma == 0:
        return rgb
    rng = np.random.default_rng([seed, 9001, t])
    noisy = rgb.astype(np.float32) + rng.normal(0.0, sigma, rgb.shape).astype(np.float32)
    return np.clip(noisy + 0.5, 0, 255).astype(np.uint8)


def mean_distance(seed: int, width: int, height: int) -> float:
    """Mean distance of the scene from the first camera (the unit of ``t_inf`` and of the
    translation slider). The first camera is the identity whatever the sliders say, so this
    depends on the seed and the size only."""
    scene = build_scene(FAMILY, seed=seed, width=width, height=height, num_frames=2)
    return scene_distance(render_frame(scene, 0).depth, scene.K)


def teach_scene(params: TeachParams, distance: float) -> Scene:
    """The scene of ``params``: C4's layout, the camera path of the sliders, the objects' speed."""
    w, h = params.width_height
    return build_scene(
        FAMILY,
        seed=params.seed,
        width=w,
        height=h,
        num_frames=params.num_frames,
        camera_end_center=(params.translation * distance, 0.0, 0.0),
        camera_end_angles=(-params.rotation_deg, 0.0, 0.0),
        object_speed=params.object_speed,
    )


def render_teach_clip(
    params: TeachParams, folder: str | Path, *, distance: float, check: Callable[[], None] | None = None
) -> TeachClip:
    """Render the clip of ``params`` into ``folder`` (``clip.mp4`` or ``clip.frames/``, and
    ``masks/``); ``distance`` is :func:`mean_distance` of its seed and size. Two threads render
    frames while this one encodes them. ``check()`` is called before each frame is written (it
    may raise to stop; the frames still rendering are dropped)."""
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    w, h = params.width_height
    scene = teach_scene(params, distance)
    severities = (("breathing", params.breathing_px), ("slide", params.slide_px), ("elastic", params.elastic_px))
    failures = _Failures([make_failure(kind, scene, s) for kind, s in severities if s > 0])
    video = out / ("clip.mp4" if params.codec == "h264" else "clip.frames")
    masks = out / "masks"
    masks.mkdir(exist_ok=True)
    writer = Mp4Writer(video, w, h, scene.fps) if params.codec == "h264" else PngSequenceWriter(video, w, h)
    pool = ThreadPoolExecutor(max_workers=2, thread_name_prefix="geocon-teach-render")
    try:
        with writer:
            for t, frame in enumerate(pool.map(lambda t: render_frame(scene, t, failures), range(scene.num_frames))):
                if check is not None:
                    check()
                writer.write(_noisy(frame.rgb, SENSOR_NOISE, params.seed, t))
                if not cv2.imwrite(str(masks / f"{t:05d}.png"), frame.labels):
                    raise OSError(f"could not write the mask {masks / f'{t:05d}.png'}")
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
    T_0T = relative_pose(scene.T_cam_world[0], scene.T_cam_world[-1])
    T_unit = T_0T.copy()
    T_unit[:3, 3] /= distance
    return TeachClip(
        video=video,
        masks=masks,
        t_inf_truth=t_inf_from_pose(T_0T, distance),
        T_cam0_camT_truth=T_unit,
        object_names={o.object_id: o.name for o in scene.objects},
        deforming_id=min(o.object_id for o in scene.objects),
    )
