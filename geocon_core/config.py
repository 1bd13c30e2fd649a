"""Scoring configuration: one frozen dataclass, named presets, and a stable hash.

Every number a record reports names the hash of the full configuration it came from.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass, fields, replace
from typing import Any

__all__ = ["ScoreConfig", "PRESETS", "preset", "config_hash"]


@dataclass(frozen=True)
class ScoreConfig:
    """All settings of a scoring run. Pixel thresholds are in working-resolution pixels of the
    scale being evaluated (SPEC section 0)."""

    preset: str = "paper"
    # reading
    working_size: tuple[int, int] = (1024, 720)
    """Frames are resized to fit inside (width, height), aspect kept, and letterboxed."""
    bar_luma: float = 16.0
    """A border row/column whose mean luma never exceeds this in any frame is a burned-in bar."""
    duplicate_mad: float = 0.05
    """Consecutive frames whose mean absolute grey difference is at most this are duplicates."""
    # correspondences
    matcher: str = "sift"
    scales: tuple[float, ...] = (0.25, 0.5, 1.0)
    gaps: tuple[int, ...] = (1,)
    aggregation: str = "median"
    """How pair scores become the clip's IR/GE. ``median`` (the paper): per gap, the median over
    valid (pair, scale); ``worst``: per gap and scale, the median over pairs, and the clip takes
    the worst cell, so a failure visible only at full resolution or long gaps is not averaged away.
    With several gaps the headline is the worst gap in both modes."""
    ratio: float = 0.8
    max_features: int = 2000
    """Features per frame at scale 1; ``max_features * scale`` at smaller scales."""
    # mask-first separation and object rigidity (SPEC sections 2, 4)
    masks: str = "motion"
    """Where object masks come from: ``motion`` (built-in segmentation, no weights) or ``none``;
    external masks are given as a path (``geocon score --masks DIR``)."""
    flow: str = "dis"
    grid: int = 8
    """AdaDFRC grid: N x N cells on each object's box."""
    min_cells: int = 3
    # background models (SPEC section 3)
    tau_h: float = 2.0
    tau_f: float = 0.1
    min_inliers: int = 30
    ir_gate: float = 0.97
    ge_gate: float = 3.5
    ransac_iters: int = 2000
    ransac_confidence: float = 0.9999
    # translation gate (SPEC section 1)
    pose_backend: str = "classical"
    fov_x_deg: float = 60.0
    """Horizontal field of view assumed when intrinsics are unknown (principal point at the
    centre of the content)."""
    tau_t: float = 0.04
    tau_t_low: float = 0.03
    tau_t_high: float = 0.05
    gate_window: int = 16
    gate_stride: int = 8
    seed: int = 0

    def __post_init__(self) -> None:
        if not self.scales or any(not 0 < s <= 1 for s in self.scales):
            raise ValueError(f"scales must be in (0, 1], got {self.scales}")
        if not self.gaps or any(g < 1 for g in self.gaps):
            raise ValueError(f"gaps must be positive integers, got {self.gaps}")
        if self.masks not in ("motion", "none", "external"):
            raise ValueError(f"masks must be 'motion', 'none' or 'external', got {self.masks!r}")
        if self.grid < 1 or self.min_cells < 1:
            raise ValueError("grid and min_cells must be positive")
        if self.min_inliers < 1:
            raise ValueError(f"min_inliers must be at least 1, got {self.min_inliers}")
        if self.aggregation not in ("median", "worst"):
            raise ValueError(f"aggregation must be 'median' or 'worst', got {self.aggregation!r}")
        if not self.tau_t_low <= self.tau_t_high:
            raise ValueError("tau_t_low must not exceed tau_t_high")
        if min(self.working_size) < 32:
            raise ValueError(f"working_size too small: {self.working_size}")

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        for k, v in d.items():
            if isinstance(v, tuple):
                d[k] = list(v)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "ScoreConfig":
        names = {f.name for f in fields(cls)}
        unknown = set(d) - names
        if unknown:
            raise ValueError(f"unknown config keys: {', '.join(sorted(unknown))}")
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.items()})

    def with_(self, **changes: Any) -> "ScoreConfig":
        return replace(self, **changes)


PRESETS: dict[str, tuple[str, ScoreConfig]] = {
    "paper": ("the paper's protocol: adjacent frames (gap 1), scales 1/4, 1/2, 1, SIFT", ScoreConfig()),
    "strict": (
        "paper plus frame gaps 4 and 8, which expose slow drift (breathing) that adjacent pairs miss; "
        "the clip takes its worst (gap, scale) median",
        ScoreConfig(preset="strict", gaps=(1, 4, 8), aggregation="worst"),
    ),
}


def preset(name: str) -> ScoreConfig:
    """The configuration of a named preset; an unknown name lists the valid ones."""
    try:
        return PRESETS[name][1]
    except KeyError:
        raise ValueError(f"unknown preset {name!r}; valid: {', '.join(PRESETS)}") from None


def config_hash(config: ScoreConfig) -> str:
    """First 16 hex digits of the SHA-256 of the canonical JSON of the full configuration."""
    blob = json.dumps(config.to_dict(), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(blob.encode()).hexdigest()[:16]
