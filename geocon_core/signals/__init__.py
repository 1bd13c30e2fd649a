"""Clip-level readings beyond the background fit and the clip score made of them: what the
motion does not explain (:mod:`.appearance`), the keep reading of the background matches
(:mod:`.keep`) and the monotone clip model (:mod:`.model`)."""

from __future__ import annotations

from .appearance import AppearanceReading, PairReading, appearance_reading, plan_pairs, reduce_gray, summarize
from .keep import unkept_share
from .model import DEFAULT_MODEL, MODEL_FORMAT, ClipModel, ModelTerm, fit_clip_model, load_clip_model, model_path
from .readings import READING_LABELS, ClipReadings

__all__ = [
    "AppearanceReading",
    "PairReading",
    "appearance_reading",
    "plan_pairs",
    "reduce_gray",
    "summarize",
    "unkept_share",
    "READING_LABELS",
    "ClipReadings",
    "DEFAULT_MODEL",
    "MODEL_FORMAT",
    "ClipModel",
    "ModelTerm",
    "fit_clip_model",
    "load_clip_model",
    "model_path",
]
