"""Writing synthetic clips: video, object masks, ground truth and benchmark sidecar.

For a clip ``ID`` in ``OUT`` this writes

- ``OUT/ID.mp4``: H.264 video (``codec="h264"``, quality ``crf``), or ``OUT/ID.frames/NNNNN.png``:
  lossless PNG frames (``codec="png"``, read by the scorer as an image folder);
- ``OUT/ID.masks/NNNNN.png``: one 8-bit label image per frame (0 = background, k = object
  id k), the external-mask layout the scorer reads;
- ``OUT/ID.gt.json``: :class:`~geocon_core.synth.truth.GroundTruth`;
- ``OUT/ID.meta.json``: benchmark sidecar with the fields of SPEC section 6.

Files are written under temporary names and renamed when complete, so an interrupted run
never leaves a clip that looks finished.
"""

from __future__ import annotations

import json
import os
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Literal, Mapping

import cv2
import numpy as np

from .._version import __version__
from ..files import commit_together, part_path
from ..geometry import relative_pose, rotation_angle_deg, t_inf_from_pose
from ..media import imwrite_any
from ..scoring import binary_gate, hysteresis_gate
from .failures import FAILURES, failure_spec, make_failure
from .families import FAMILIES, build_scene, family_info
from .render import render_frame
from .scene import Scene
from .truth import GT_FORMAT, FailureTruth, GroundTruth, ObjectTruth

__all__ = [
    "ClipPlan",
    "Codec",
    "DEFAULT_FAILURE_VARIANTS",
    "MAX_NOISE",
    "plan_clips",
    "write_clip",
    "clip_targets",
    "check_clip_targets",
    "mean_scene_distance",
]

MAX_NOISE = 255.0
"""The largest sensor noise (standard deviation, grey levels) a clip takes: beyond it every pixel saturates."""

Codec = Literal["h264", "png"]
"""How :func:`write_clip` stores the frames: H.264 MP4, or a folder of lossless PNG frames."""

DEFAULT_FAILURE_VARIANTS: tuple[tuple[str, str], ...] = (
    ("C1", "boiling"),
    ("C2", "breathing"),
    ("C3", "slide"),
    ("C2", "slide_across"),
    ("C3", "slide_along"),
    ("C3", "missing_parallax"),
    ("C4", "elastic"),
    ("C5", "letterbox"),
)
"""(family, failure) pairs that ``geocon synth all`` renders at default severity."""

_NEEDS = {"missing_parallax": ("C3", "C5", "C6"), "elastic": ("C4", "C6")}


@dataclass(frozen=True)
class ClipPlan:
    """One clip to render: a family and an optional failure with its severity."""

    family: str
    failure: str | None = None
    severity: float | None = None

    @property
    def clip_id(self) -> str:
        slug = FAMILIES[self.family].slug
        if self.failure is None:
            return slug
        return f"{slug}__{self.failure}-s{self.severity:g}"


def plan_clips(family: str, failure: str | None = None, severity: float | None = None) -> list[ClipPlan]:
    """The clips for ``geocon synth FAMILY|all [--failure KIND --severity X]``.

    ``all`` without a failure gives every clean family plus :data:`DEFAULT_FAILURE_VARIANTS`;
    ``all`` with a failure gives that failure on every family that can carry it."""
    if severity is not None and failure is None:
        raise ValueError("--severity needs --failure")
    if failure is not None:
        spec = failure_spec(failure)
        severity = spec.check(spec.default if severity is None else severity)
    if family.strip().lower() == "all":
        if failure is None:
            clean = [ClipPlan(code) for code in FAMILIES]
            variants = [ClipPlan(code, kind, FAILURES[kind].default) for code, kind in DEFAULT_FAILURE_VARIANTS]
            return clean + variants
        codes = _NEEDS.get(failure, tuple(FAMILIES))
        return [ClipPlan(code, failure, severity) for code in codes]
    code = family_info(family).code
    if failure is not None and code not in _NEEDS.get(failure, (code,)):
        raise ValueError(f"failure {failure!r} needs one of the families {', '.join(_NEEDS[failure])}, not {code}")
    return [ClipPlan(code, failure, severity)]


def mean_scene_distance(depth: np.ndarray, K: np.ndarray) -> float:
    """Mean Euclidean distance from the camera of the points seen in a depth map (H, W)."""
    H, W = depth.shape
    gy, gx = np.mgrid[0:H, 0:W].astype(np.float64)
    Kinv = np.linalg.inv(K)
    rx = Kinv[0, 0] * gx + Kinv[0, 1] * gy + Kinv[0, 2]
    ry = Kinv[1, 1] * gy + Kinv[1, 2]
    dist = depth * np.sqrt(rx**2 + ry**2 + 1.0)
    finite = np.isfinite(dist)
    if not finite.any():
        raise ValueError("the first frame shows no scene point")
    return float(dist[finite].mean())


_FROM_SCENE = ("seed", "width", "height", "fps", "num_frames", "fov_x_deg", "K", "T_cam_world")
"""The fields of :class:`GroundTruth` copied as they are from the rendered scene."""


def write_clip(
    plan: ClipPlan,
    out_dir: str | Path,
    *,
    seed: int = 0,
    width: int = 640,
    height: int = 360,
    num_frames: int = 48,
    fps: float = 24.0,
    noise: float = 2.0,
    on_frame: Callable[[int], None] | None = None,
    codec: Codec = "h264",
    crf: int = 12,
    sidecar: Mapping[str, Any] | None = None,
) -> GroundTruth:
    """Render ``plan`` into ``out_dir`` and return its ground truth. ``noise`` is the standard
    deviation (grey levels) of seeded Gaussian sensor noise added to every frame, so that no
    two frames are bit-identical (as with any real camera or generator). ``on_frame(t)`` is
    called after each frame (progress reporting). ``codec`` and ``crf`` (H.264 quality, 0-51,
    lower is better) choose how the frames are stored (see the module docstring). ``sidecar``:
    fields that replace those of the clip's sidecar (a benchmark's clip id, platform and scene).

    Nothing is written where a file is not an earlier rendering of the same clip
    (:func:`check_clip_targets`, before any frame is rendered); the clip, its masks, its ground
    truth and its sidecar are committed together."""
    if not 0 <= noise <= MAX_NOISE:  # NaN fails too
        raise ValueError(f"noise must be a standard deviation of 0 to {MAX_NOISE:g} grey levels, got {noise:g}")
    if codec not in ("h264", "png"):
        raise ValueError(f"codec must be h264 or png, got {codec!r}")
    from ..media import Mp4Writer, PngSequenceWriter

    out = Path(out_dir)
    check_clip_targets(plan, out, codec)
    out.mkdir(parents=True, exist_ok=True)
    scene = build_scene(plan.family, seed=seed, width=width, height=height, num_frames=num_frames, fps=fps)
    failure = make_failure(plan.failure, scene, plan.severity) if plan.failure else None
    targets = clip_targets(plan, out, codec)
    video, masks, gt_path, meta_path = targets["video"], targets["masks"], targets["truth"], targets["meta"]
    tmp_video, tmp_masks = out / f".{video.name}.part", out / f".{masks.name}.part"
    for tmp in (tmp_masks, tmp_video):
        _remove(tmp)
    tmp_masks.mkdir()
    frame_writer = (
        Mp4Writer(tmp_video, width, height, fps, crf=crf)
        if codec == "h264"
        else PngSequenceWriter(tmp_video, width, height)
    )

    content = failure.content_box(scene) if failure else (0, 0, width, height)
    x0, y0, x1, y1 = content
    content_area = (x1 - x0) * (y1 - y0)
    masked_share = np.zeros(num_frames)
    visible: dict[int, list[int]] = {o.object_id: [] for o in scene.objects}
    first_depth = None
    try:
        with frame_writer as writer:
            for t in range(num_frames):
                frame = render_frame(scene, t, failure)
                if t == 0:
                    first_depth = frame.depth
                writer.write(_add_noise(frame.rgb, noise, seed, t))
                if not imwrite_any(tmp_masks / f"{t:05d}.png", frame.labels, [cv2.IMWRITE_PNG_COMPRESSION, 3]):
                    raise OSError(f"could not write mask {tmp_masks / f'{t:05d}.png'}")
                masked_share[t] = np.count_nonzero(frame.labels[y0:y1, x0:x1]) / content_area
                for oid in np.unique(frame.labels):
                    if oid:
                        visible[int(oid)].append(t)
                if on_frame is not None:
                    on_frame(t)
    except BaseException:
        _remove(tmp_masks)
        _remove(tmp_video)
        raise

    assert first_depth is not None
    gt = _ground_truth(scene, plan, failure, first_depth, masked_share, visible, content, video.name, masks.name, noise)
    tmp_gt, tmp_meta = part_path(gt_path), part_path(meta_path)
    moves = [(tmp_masks, masks), (tmp_video, video), (tmp_gt, gt_path), (tmp_meta, meta_path)]
    try:
        gt.write(tmp_gt)
        tmp_meta.write_text(json.dumps({**_sidecar(gt, scene), **(sidecar or {})}, indent=1) + "\n")
    except BaseException:
        for tmp, _ in moves:
            _remove(tmp)
        raise
    commit_together(moves)  # the clip, its masks, its truth and its sidecar: all four or none
    return gt


def clip_targets(plan: ClipPlan, out_dir: str | Path, codec: Codec = "h264") -> dict[str, Path]:
    """The paths :func:`write_clip` writes for ``plan`` in ``out_dir``: ``video`` (``.mp4``, or a
    ``.frames`` folder of PNGs), ``masks`` (a folder), ``truth`` (``.gt.json``) and ``meta``
    (``.meta.json``)."""
    out, cid = Path(out_dir), plan.clip_id
    suffix = ".mp4" if codec == "h264" else ".frames"
    return {
        "video": out / f"{cid}{suffix}",
        "masks": out / f"{cid}.masks",
        "truth": out / f"{cid}.gt.json",
        "meta": out / f"{cid}.meta.json",
    }


def check_clip_targets(plan: ClipPlan, out_dir: str | Path, codec: Codec = "h264") -> None:
    """Refuse (:class:`~geocon_core.files.OutPathError`, one sentence), before anything is
    rendered, to write ``plan`` where its files would replace what is not an earlier rendering of
    the same clip by GeoCon: a file of that name beside no ground truth of this clip (a user's
    clip, masks folder or sidecar), a ground truth of another kind or clip, a folder where a file
    goes (or a file where a folder goes), a device. An earlier rendering of the clip (its
    ``.gt.json`` names it) is replaced whole."""
    from ..files import OutPathError, check_targets, held

    targets = clip_targets(plan, out_dir, codec)
    truth = held(targets["truth"])
    data = truth.data or {}
    ours = (truth.format or "").startswith(f"{GT_FORMAT.split('/')[0]}/") and data.get("clip_id") == plan.clip_id
    for path in targets.values():
        if os.path.lexists(path) and not ours:
            what = held(path).describe()
            raise OutPathError(
                f"{path} exists and is {what}, not an earlier rendering of {plan.clip_id} by GeoCon (no ground truth "
                f"of it beside); move it away or choose another --out"
            )
    check_targets([(path, key == "masks" or (key == "video" and codec == "png")) for key, path in targets.items()])


def _remove(path: Path) -> None:
    """Remove a file or a folder, if there."""
    if path.is_dir():
        shutil.rmtree(path, ignore_errors=True)
    else:
        path.unlink(missing_ok=True)


def _add_noise(rgb: np.ndarray, sigma: float, seed: int, t: int) -> np.ndarray:
    if sigma == 0:
        return rgb
    rng = np.random.default_rng([seed, 9001, t])
    noisy = rgb.astype(np.float32) + rng.normal(0.0, sigma, rgb.shape).astype(np.float32)
    return np.clip(noisy + 0.5, 0, 255).astype(np.uint8)


def _ground_truth(
    scene: Scene, plan: ClipPlan, failure, first_depth, masked_share, visible, content, video_name, masks_name, noise
) -> GroundTruth:
    T_0T = relative_pose(scene.T_cam_world[0], scene.T_cam_world[-1])
    dist = mean_scene_distance(first_depth, scene.K)
    t_inf = t_inf_from_pose(T_0T, dist)
    non_rigid = failure.non_rigid_object_ids() if failure else frozenset()
    objects = tuple(
        ObjectTruth(
            object_id=o.object_id,
            name=o.name,
            rigid=o.object_id not in non_rigid,
            visible_frames=tuple(visible[o.object_id]),
        )
        for o in scene.objects
    )
    fail = None
    if failure is not None:
        fail = FailureTruth(
            kind=failure.kind, severity=failure.severity, unit=FAILURES[failure.kind].unit, params=failure.params()
        )
    return GroundTruth(
        clip_id=plan.clip_id,
        family=scene.family,
        family_title=FAMILIES[scene.family].title,
        **{name: getattr(scene, name) for name in _FROM_SCENE},
        T_cam0_camT=T_0T,
        mean_scene_distance=dist,
        t_inf=t_inf,
        rotation_deg=rotation_angle_deg(T_0T[:3, :3]),
        expected_gate=hysteresis_gate(t_inf),
        expected_gate_binary=binary_gate(t_inf),
        objects=objects,
        masks_path=masks_name,
        masked_share=masked_share,
        content_box=(int(content[0]), int(content[1]), int(content[2]), int(content[3])),
        failure=fail,
        video_path=video_name,
        sensor_noise_sigma=float(noise),
    )


def _sidecar(gt: GroundTruth, scene: Scene) -> dict:
    """Benchmark metadata (SPEC section 6). Each failure kind acts as its own "platform";
    clean and damaged renders of one scene share ``scene_id``."""
    prompt = f"synthetic {gt.family}: {gt.family_title}"
    if gt.failure:
        prompt += f" (injected {gt.failure.kind}, severity {gt.failure.severity:g} {gt.failure.unit})"
    return {
        "clip_id": gt.clip_id,
        "prompt": prompt,
        "model": "geocon-synth" if gt.failure is None else f"geocon-synth/{gt.failure.kind}",
        "model_version": __version__,
        "seed": gt.seed,
        "resolution": [gt.width, gt.height],
        "fps": gt.fps,
        "duration": gt.num_frames / gt.fps,
        "masks_path": gt.masks_path,
        "category": gt.family,
        "scene_id": f"synth-{gt.family}-seed{gt.seed}",
        "video": gt.video_path,
        "ground_truth": f"{gt.clip_id}.gt.json",
    }
