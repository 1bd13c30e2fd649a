"""Settings: every number that can change a score, and the presets.

:class:`ScoreConfig` (:mod:`.presets`) holds the top-level settings, one frozen sub-config per
stage (:mod:`.stages`: bars, cuts, flow, motion masks, SAM-2, pose, DUSt3R, category, scans, the
multi-view check). :func:`preset` builds ``paper``, ``audit``, ``strict`` and ``fast``;
:func:`config_hash` is the short hash every record carries.
"""

from __future__ import annotations

from .presets import (
    DEFAULT_PRESET,
    FOV_RANGE_DEG,
    PRESETS,
    UNUSED_BACKENDS,
    ScoreConfig,
    config_hash,
    config_items,
    preset,
)
from .stages import (
    DIS_PRESET_NAMES,
    BarConfig,
    CategoryConfig,
    CutConfig,
    Dust3rConfig,
    FlowConfig,
    IndependentConfig,
    MotionConfig,
    MultiViewConfig,
    PoseConfig,
    RegionsConfig,
    RewardConfig,
    Sam2Config,
    ScanConfig,
    SignalsConfig,
)

__all__ = [
    "BarConfig",
    "CategoryConfig",
    "CutConfig",
    "DIS_PRESET_NAMES",
    "Dust3rConfig",
    "FlowConfig",
    "IndependentConfig",
    "MotionConfig",
    "MultiViewConfig",
    "PoseConfig",
    "Sam2Config",
    "ScanConfig",
    "SignalsConfig",
    "RegionsConfig",
    "RewardConfig",
    "DEFAULT_PRESET",
    "FOV_RANGE_DEG",
    "PRESETS",
    "ScoreConfig",
    "UNUSED_BACKENDS",
    "config_hash",
    "config_items",
    "preset",
]
