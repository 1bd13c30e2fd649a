"""Points in 3D: dense clouds and the multi-view check.

:mod:`.dense` triangulates dense clouds of the first/last pair and of each gate window while a
clip is scored. The multi-view check, one stage a module: :mod:`.tracks` follows long tracks
through the clip, :mod:`.solve` poses the keyframes and adjusts them with pycolmap,
:mod:`.multiview` builds the clip's one reconstruction and finds the background layers that drift
against it, :mod:`.result` is what it reports.
"""

from __future__ import annotations

from .dense import (
    KIND_INLIER,
    KIND_OBJECT,
    KIND_OUTLIER,
    DenseCloud,
    DenseCloudBuilder,
    DenseCloudConfig,
    WindowCloud,
    dense_cloud,
    triangulate_flow,
)
from .multiview import reconstruct
from .result import ARRAY_NAMES, DriftLayer, MultiViewResult
from .tracks import LongTracks, TrackObservations, keyframes

__all__ = [
    "DenseCloud",
    "DenseCloudBuilder",
    "DenseCloudConfig",
    "KIND_INLIER",
    "KIND_OBJECT",
    "KIND_OUTLIER",
    "WindowCloud",
    "dense_cloud",
    "triangulate_flow",
    "ARRAY_NAMES",
    "DriftLayer",
    "LongTracks",
    "MultiViewResult",
    "TrackObservations",
    "keyframes",
    "reconstruct",
]
