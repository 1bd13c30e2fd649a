"""A synthetic benchmark dataset: the same scenes "generated" by several platforms that differ
only in the failures they inject, with sidecar metadata in the ``geocon bench`` layout.

Platforms (each renders every scene of every family; the same ``scene_id`` across platforms is
the same camera path and layout):

- ``clean``: no failure;
- ``breathing``: the background breathes (rubber-sheet warp, ``breathing_px`` peak);
- ``elastic``: moving objects deform non-rigidly (``elastic_px`` peak) in the families that have
  objects; elsewhere it renders the clean scene.

The truth a benchmark must recover: ``breathing`` ranks worst on background GE/IR, ``elastic``
worst on AdaDFRC, and the t_inf gate separates the H families (C1, C2, C4) from the F families
(C3, C5).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

from .families import FAMILIES, family_info
from .writer import ClipPlan, check_clip_targets, clip_targets, write_clip

__all__ = ["PLATFORMS", "BenchClip", "check_benchmark_targets", "plan_benchmark", "write_benchmark"]

PLATFORMS = ("clean", "breathing", "elastic")
_OBJECT_FAMILIES = ("C4", "C6")


@dataclass(frozen=True)
class BenchClip:
    platform: str
    plan: ClipPlan
    seed: int

    @property
    def clip_id(self) -> str:
        return f"{self.platform}-{FAMILIES[self.plan.family].slug}-s{self.seed}"

    @property
    def scene_id(self) -> str:
        return f"{self.plan.family}-seed{self.seed}"


def plan_benchmark(
    *,
    families: Sequence[str] = ("C1", "C2", "C3", "C4", "C5"),
    scenes: int = 3,
    platforms: Sequence[str] = PLATFORMS,
    breathing_px: float = 3.0,
    elastic_px: float = 8.0,
    first_seed: int = 0,
) -> list[BenchClip]:
    """Every (platform, family, scene) clip of the benchmark."""
    unknown = [p for p in platforms if p not in PLATFORMS]
    if unknown:
        raise ValueError(f"unknown platform(s) {', '.join(unknown)}; valid: {', '.join(PLATFORMS)}")
    if scenes < 1:
        raise ValueError(f"scenes must be at least 1, got {scenes}")
    _refuse_repeats("--families", families, lambda f: family_info(f).code)
    _refuse_repeats("platforms", platforms, str)
    clips = []
    for platform in platforms:
        for family in families:
            code = family_info(family).code
            for k in range(scenes):
                if platform == "breathing":
                    plan = ClipPlan(code, "breathing", breathing_px)
                elif platform == "elastic" and code in _OBJECT_FAMILIES:
                    plan = ClipPlan(code, "elastic", elastic_px)
                else:
                    plan = ClipPlan(code)
                clips.append(BenchClip(platform, plan, first_seed + k))
    return clips


def _refuse_repeats(what: str, names: Sequence[str], key: Callable[[str], str]) -> None:
    """A ``ValueError`` naming the first entry of ``names`` that repeats an earlier one (the same
    ``key``): it would render the same clips into the same files twice, and count them twice."""
    seen: dict[str, str] = {}
    for name in names:
        k = key(name)
        if k in seen:
            same = f" ({seen[k]!r} and {name!r} are the same)" if seen[k] != name else ""
            raise ValueError(f"{what} lists {k} twice{same}; give each once")
        seen[k] = name


def write_benchmark(
    out_dir: str | Path,
    clips: Sequence[BenchClip],
    *,
    width: int = 320,
    height: int = 180,
    num_frames: int = 24,
    fps: float = 24.0,
    on_frame: Callable[[int], None] | None = None,
) -> list[Path]:
    """Render ``clips`` into ``out_dir/<platform>/<scene_id>/`` and rewrite each sidecar with the
    benchmark's clip id, platform (``model``) and scene id. Returns the sidecar paths."""
    root = Path(out_dir)
    check_benchmark_targets(root, clips)
    sidecars = []
    for clip in clips:
        folder = root / clip.platform / clip.scene_id
        write_clip(
            clip.plan,
            folder,
            seed=clip.seed,
            width=width,
            height=height,
            num_frames=num_frames,
            fps=fps,
            on_frame=on_frame,
            sidecar={"clip_id": clip.clip_id, "model": clip.platform, "scene_id": clip.scene_id},
        )
        sidecars.append(clip_targets(clip.plan, folder)["meta"])
    return sidecars


def check_benchmark_targets(out_dir: str | Path, clips: Sequence[BenchClip]) -> None:
    """Every clip's files checked (:func:`~.writer.check_clip_targets`) before the first is rendered."""
    for clip in clips:
        check_clip_targets(clip.plan, Path(out_dir) / clip.platform / clip.scene_id)
