"""Synthetic scenes with exact geometry for validating every GeoCon metric.

>>> from geocon_core.synth import ClipPlan, write_clip
>>> gt = write_clip(ClipPlan("C3"), "out/")          # doctest: +SKIP
>>> gt.t_inf, gt.expected_gate                        # doctest: +SKIP
"""

from .benchmark import check_benchmark_targets, plan_benchmark, write_benchmark
from .failures import FAILURES, Failure, FailureSpec, make_failure, plane_wave_field, plane_waves
from .families import FAMILIES, Family, build_scene, family_info
from .render import RenderedFrame, render_frame
from .scene import ObjectTrack, Scene, SurfaceView, TexturedPlane, pose_from_center
from .truth import FailureTruth, GroundTruth, ObjectTruth, load_ground_truth
from .writer import (
    DEFAULT_FAILURE_VARIANTS,
    MAX_NOISE,
    ClipPlan,
    check_clip_targets,
    clip_targets,
    mean_scene_distance,
    plan_clips,
    write_clip,
)

__all__ = [
    "FAILURES",
    "Failure",
    "FailureSpec",
    "make_failure",
    "plane_waves",
    "plane_wave_field",
    "FAMILIES",
    "Family",
    "build_scene",
    "family_info",
    "RenderedFrame",
    "render_frame",
    "ObjectTrack",
    "Scene",
    "SurfaceView",
    "TexturedPlane",
    "FailureTruth",
    "GroundTruth",
    "ObjectTruth",
    "load_ground_truth",
    "DEFAULT_FAILURE_VARIANTS",
    "MAX_NOISE",
    "ClipPlan",
    "mean_scene_distance",
    "plan_clips",
    "write_clip",
    "clip_targets",
    "check_clip_targets",
    "pose_from_center",
    "plan_benchmark",
    "write_benchmark",
    "check_benchmark_targets",
]
