"""Decoded frames held in memory, as a training loop has them.

A video generator's training script holds its samples as arrays, not files: a numpy array or a
torch tensor, on the CPU or a GPU, channels last or first, bytes or floats in [0, 1].
:func:`as_bgr_frames` turns any of those into the one layout the probe and the frame pass read
(:func:`~geocon_core.media.reader.probe_frames`), so the same frames give the same numbers
whether they come from memory or from a folder of PNG files.

>>> import numpy as np
>>> as_bgr_frames(np.zeros((4, 3, 8, 8), np.float32)).shape   # T, C, H, W floats in [0, 1]
(4, 8, 8, 3)
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .decode import DEFAULT_FPS, ClipError

__all__ = ["HeldFrames", "as_bgr_frames", "to_numpy"]


@dataclass(frozen=True, eq=False)
class HeldFrames:
    """A clip held in memory, where :func:`~geocon_core.scoring.score_clip` takes a path:
    ``frames`` (T, h, w, 3) uint8 BGR (:func:`as_bgr_frames`), ``name`` standing in for the path
    in the record, ``fps`` for its rate."""

    frames: np.ndarray
    name: str = "frames"
    fps: float = DEFAULT_FPS


def to_numpy(frames: Any) -> np.ndarray:
    """``frames`` as a numpy array: numpy as it is, a torch tensor copied off its device
    (never imports torch), anything else that numpy can read."""
    if isinstance(frames, np.ndarray):
        return frames
    detach = getattr(frames, "detach", None)
    if callable(detach):  # a torch tensor, on any device
        return np.asarray(detach().to("cpu").numpy())
    try:
        return np.asarray(frames)
    except (TypeError, ValueError) as err:
        raise ClipError(
            f"frames must be an array of shape (T, H, W, 3) or (T, 3, H, W), got {type(frames).__name__}"
        ) from err


def as_bgr_frames(frames: Any, *, channel_order: str = "rgb", name: str = "frames") -> np.ndarray:
    """(T, H, W, 3) contiguous uint8 BGR frames from ``frames``: shape (T, H, W, 3), (T, 3, H, W)
    or (T, H, W) grey; uint8, or floats in [0, 1] (rounded to bytes, as an encoder would);
    ``channel_order`` "rgb" (numpy images, torch, PIL) or "bgr" (OpenCV). Raises
    :class:`~geocon_core.media.decode.ClipError` with one sentence for anything else."""
    order = channel_order.strip().lower()
    if order not in ("rgb", "bgr"):
        raise ClipError(f"channel_order must be 'rgb' or 'bgr', got {channel_order!r}")
    a = to_numpy(frames)
    if a.ndim == 3:
        a = np.repeat(a[..., None], 3, axis=-1)
    if a.ndim != 4:
        raise ClipError(f"{name}: frames must have shape (T, H, W, 3), (T, 3, H, W) or (T, H, W), got {a.shape}")
    if a.shape[-1] != 3 and a.shape[1] == 3:
        a = np.moveaxis(a, 1, -1)
    if a.shape[-1] != 3:
        raise ClipError(f"{name}: frames must have 3 colour channels (last or second axis), got shape {a.shape}")
    if a.shape[0] < 2:
        raise ClipError(f"{name}: has {a.shape[0]} frame{'s' if a.shape[0] != 1 else ''}; at least 2 are needed")
    if min(a.shape[1:3]) < 16:
        raise ClipError(f"{name}: frames of {a.shape[2]}x{a.shape[1]} px are too small to score (16 px at least)")
    if a.dtype == np.uint8:
        out = a
    elif a.dtype == np.bool_ or not (np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.integer)):
        raise ClipError(f"{name}: frames must be uint8 or floats in [0, 1], got {a.dtype}")
    elif np.issubdtype(a.dtype, np.integer):
        if a.min() < 0 or a.max() > 255:
            raise ClipError(f"{name}: integer frames must lie in 0..255, got {a.min()}..{a.max()}")
        out = a.astype(np.uint8)
    else:
        if not np.isfinite(a).all():
            raise ClipError(f"{name}: frames hold NaN or infinite values")
        lo, hi = float(a.min()), float(a.max())
        if lo < -1e-3 or hi > 1 + 1e-3:
            raise ClipError(
                f"{name}: float frames must lie in [0, 1], got {lo:.3g}..{hi:.3g} (divide by 255, or undo the "
                "[-1, 1] normalisation: (x + 1) / 2)"
            )
        out = np.clip(np.rint(a.astype(np.float32) * 255.0), 0, 255).astype(np.uint8)
    if order == "rgb":
        out = out[..., ::-1]
    return np.ascontiguousarray(out)
