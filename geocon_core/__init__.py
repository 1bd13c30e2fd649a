"""GeoCon core: ground-truth-free scoring of geometric consistency in video.

The public API, loaded lazily (``import geocon_core`` imports no OpenCV stage until a name is
used):

>>> from geocon_core import ScoreConfig, score_clip, write_record   # doctest: +SKIP
>>> record = score_clip("clip.mp4", ScoreConfig())                   # doctest: +SKIP
>>> write_record(record, "out/")                                     # doctest: +SKIP

- scoring: :func:`score_clip`, :func:`score_frames` (frames in memory), :class:`ScoreConfig`,
  :func:`preset`, :data:`PRESETS`, :func:`config_hash`; a reward for training loops in
  :mod:`geocon_core.reward`;
- records: :func:`read_record`, :func:`write_record`, :class:`ClipRecord` and its parts
  (:class:`GateRecord`, :class:`BackgroundSummary`, :class:`PairRecord`, ...), :class:`ClipInfo`,
  :class:`PoseEstimate`;
- errors: :class:`ClipError` (unusable input).

Each package has one public ``__init__`` and follows the data: :mod:`geocon_core.config`
(settings), :mod:`geocon_core.files` (safe files on disk), :mod:`geocon_core.media` (reading
clips), :mod:`geocon_core.geometry` (features, two-view formulas, H and F fits),
:mod:`geocon_core.flow`, :mod:`geocon_core.pose`, :mod:`geocon_core.masks`,
:mod:`geocon_core.reconstruction` (dense clouds, the multi-view check),
:mod:`geocon_core.scoring` (the composition and every verdict rule), :mod:`geocon_core.record`
(the audit record); :mod:`geocon_core.bench` and :mod:`geocon_core.report` (many clips),
:mod:`geocon_core.synth` (synthetic scenes), :mod:`geocon_core.plant` (failures planted into
real footage) and :mod:`geocon_core.validation`;
:mod:`geocon_core.intervals` (confidence intervals shared by the report and the validation).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from ._version import __version__

if TYPE_CHECKING:
    from .config import PRESETS, ScoreConfig, config_hash, preset
    from .media import ClipError, ClipInfo
    from .pose import PoseEstimate
    from .record import (
        BackgroundSummary,
        Category,
        ClipRecord,
        FamilySummary,
        FitSummary,
        GateRecord,
        MatchArrays,
        ObjectEntry,
        ObjectSummary,
        PairRecord,
        PointCloud,
        read_record,
        write_record,
    )
    from .scoring import score_clip, score_frames

_LAZY: dict[str, str] = {
    "score_clip": "scoring",
    "score_frames": "scoring",
    "ScoreConfig": "config",
    "PRESETS": "config",
    "preset": "config",
    "config_hash": "config",
    "read_record": "record",
    "write_record": "record",
    "ClipRecord": "record",
    "GateRecord": "record",
    "BackgroundSummary": "record",
    "FamilySummary": "record",
    "PairRecord": "record",
    "FitSummary": "record",
    "MatchArrays": "record",
    "ObjectSummary": "record",
    "ObjectEntry": "record",
    "Category": "record",
    "PointCloud": "record",
    "ClipInfo": "media",
    "ClipError": "media",
    "PoseEstimate": "pose",
}
"""Public name -> the module of this package that defines it."""

__all__ = [
    "__version__",
    "score_clip",
    "score_frames",
    "ScoreConfig",
    "PRESETS",
    "preset",
    "config_hash",
    "read_record",
    "write_record",
    "ClipRecord",
    "GateRecord",
    "BackgroundSummary",
    "FamilySummary",
    "PairRecord",
    "FitSummary",
    "MatchArrays",
    "ObjectSummary",
    "ObjectEntry",
    "Category",
    "PointCloud",
    "ClipInfo",
    "ClipError",
    "PoseEstimate",
]


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'geocon_core' has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
