"""Clip-level readings beyond the background fit and the clip score made of them: what the
motion does not explain (:mod:`.appearance`), the keep reading of the background matches
(:mod:`.keep`), the monotone clip model (:mod:`.model`) and the pictures of where the readings
fire (:mod:`.pictures`)."""

from __future__ import annotations

from .appearance import (
    MAP_NAMES,
    AppearanceReading,
    PairReading,
    ReadingMaps,
    appearance_reading,
    content_gray,
    plan_pairs,
    reduce_gray,
    summarize,
)
from .keep import unkept_share
from .model import (
    DEFAULT_MODEL,
    MODEL_FORMAT,
    ClipModel,
    ClipModelError,
    ClipModelMismatch,
    ModelTerm,
    configured_model,
    fit_clip_model,
    load_clip_model,
    model_path,
)
from .pictures import (
    MAP_OF_READING,
    MAP_VIEWS,
    MapView,
    blend_heat,
    heat_rgba,
    leading_picture,
    map_on_frame,
    picture_of,
)
from .readings import MAP_ARRAYS, READING_LABELS, ClipReadings

__all__ = [
    "MAP_ARRAYS",
    "MAP_NAMES",
    "AppearanceReading",
    "PairReading",
    "ReadingMaps",
    "appearance_reading",
    "content_gray",
    "plan_pairs",
    "reduce_gray",
    "summarize",
    "unkept_share",
    "READING_LABELS",
    "ClipReadings",
    "MAP_OF_READING",
    "MAP_VIEWS",
    "MapView",
    "blend_heat",
    "heat_rgba",
    "leading_picture",
    "map_on_frame",
    "picture_of",
    "DEFAULT_MODEL",
    "MODEL_FORMAT",
    "ClipModel",
    "ClipModelError",
    "ClipModelMismatch",
    "configured_model",
    "ModelTerm",
    "fit_clip_model",
    "load_clip_model",
    "model_path",
]
