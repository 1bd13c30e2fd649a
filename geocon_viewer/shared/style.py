"""Formatting and colours shared by the command line and the viewers, so that a number and an
object look the same everywhere."""

from __future__ import annotations

import colorsys
import math

import numpy as np

from geocon_core.results import LAYER_RGB

__all__ = ["EMPTY", "fmt", "object_color", "dense_colors", "dense_legend", "OUTLIER_SPAN"]

EMPTY = "n/a"
"""What a missing value (None or NaN) prints as."""
GOLDEN = 0.61803398875
"""Hue step between consecutive object ids (the golden ratio spreads them around the wheel)."""


def fmt(v: float | None, spec: str = ".3f", unit: str = "") -> str:
    """``v`` formatted with ``spec`` and followed by ``unit``, or :data:`EMPTY` for None or NaN."""
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return EMPTY
    return f"{v:{spec}}{unit}"


def object_color(object_id: int) -> tuple[int, int, int]:
    """The (r, g, b) colour (0..255) of an object id in every viewer."""
    r, g, b = colorsys.hsv_to_rgb((object_id * GOLDEN) % 1.0, 0.75, 1.0)
    return int(r * 255), int(g * 255), int(b * 255)


INLIER_LOW, INLIER_HIGH = (40, 170, 80), (170, 220, 60)
OUTLIER_LOW, OUTLIER_HIGH = (255, 190, 40), (225, 30, 40)
DENSE_OBJECT = (70, 130, 255)
OUTLIER_SPAN = 4.0
"""Outlier colours run from the inlier threshold to this many times it (then stay red)."""


def _ramp(lo: tuple[int, int, int], hi: tuple[int, int, int], u: np.ndarray) -> np.ndarray:
    u = np.clip(u, 0.0, 1.0)[:, None]
    return np.asarray(lo, float) * (1.0 - u) + np.asarray(hi, float) * u


def dense_colors(residual: np.ndarray, kind: np.ndarray, tau_px: float) -> np.ndarray:
    """(N, 3) uint8 colours of a dense cloud's points by their epipolar residual (px): inliers
    (kind 0) dark to light green over 0..tau, outliers (kind 1) yellow to red over
    tau..OUTLIER_SPAN*tau, objects (kind 2) blue."""
    r = np.asarray(residual, float)
    inl = _ramp(INLIER_LOW, INLIER_HIGH, r / tau_px)
    out = _ramp(OUTLIER_LOW, OUTLIER_HIGH, (r - tau_px) / ((OUTLIER_SPAN - 1.0) * tau_px))
    rgb = np.where((np.asarray(kind) == 0)[:, None], inl, out)
    rgb[np.asarray(kind) == 2] = DENSE_OBJECT
    return np.round(rgb).astype(np.uint8)


def dense_legend(tau_px: float) -> list[tuple[str, tuple[int, int, int]]]:
    """The legend of :func:`dense_colors`: (label, colour) rows."""
    return [
        ("inlier, residual 0 px", INLIER_LOW),
        (f"inlier, residual {tau_px:g} px", INLIER_HIGH),
        (f"outlier, residual {tau_px:g} px", OUTLIER_LOW),
        (f"outlier, residual >= {OUTLIER_SPAN * tau_px:g} px", OUTLIER_HIGH),
        ("moving object (not background)", DENSE_OBJECT),
    ]


def track_colors(residual: np.ndarray, tau_px: float, layer_of: np.ndarray | None = None) -> np.ndarray:
    """(N, 3) uint8 colours of the multi-view check's tracks by their residual (px), in the dense
    clouds' scheme (:func:`dense_colors`: green within ``tau_px``, yellow to red beyond), the
    tracks of a layer (``layer_of >= 0``) in the report's ``LAYER_RGB``."""
    r = np.asarray(residual, float)
    rgb = dense_colors(r, (r > tau_px).astype(int), tau_px)
    if layer_of is not None:
        rgb[np.asarray(layer_of) >= 0] = LAYER_RGB
    return rgb
