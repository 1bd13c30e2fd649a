"""Points in 3D: dense clouds and the multi-view check.

:mod:`.dense` triangulates dense clouds of the first/last pair and of each gate window while a
clip is scored; :mod:`.multiview` builds long tracks, one reconstruction per clip adjusted by
pycolmap, and finds background layers that drift against it.
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
from .multiview import (
    ARRAY_NAMES,
    DriftLayer,
    LongTracks,
    MultiViewResult,
    TrackObservations,
    keyframes,
    reconstruct,
)

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
