"""Pictures for the Rerun audit recording: the inferno colour scale, object colours, PNG encoding
and the low-resolution residual map of a frame pair's matches."""

from __future__ import annotations

import math

import cv2
import numpy as np

from ..shared import object_color

__all__ = ["colormap", "object_rgba", "png_bytes", "residual_map"]


def colormap(values: np.ndarray, vmax: float) -> np.ndarray:
    """Inferno colours (N, 4) uint8 of values in [0, vmax] (none for none: a pair without matches)."""
    v = np.clip(np.asarray(values, np.float64).ravel() / max(vmax, 1e-9), 0.0, 1.0)
    if not v.size:
        return np.zeros((0, 4), np.uint8)
    idx = np.round(v * 255).astype(np.uint8).reshape(-1, 1)
    bgr = cv2.applyColorMap(idx, cv2.COLORMAP_INFERNO).reshape(-1, 3)
    out = np.full((len(v), 4), 255, np.uint8)
    out[:, :3] = bgr[:, ::-1]
    return out


def object_rgba(object_id: int) -> tuple[int, int, int, int]:
    """An object's colour with full opacity."""
    return (*object_color(object_id), 255)


def png_bytes(image: np.ndarray, level: int = 6) -> bytes:
    if image.ndim == 3 and image.shape[2] == 4:
        image = cv2.cvtColor(image, cv2.COLOR_RGBA2BGRA)
    elif image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
    ok, buf = cv2.imencode(".png", image, [cv2.IMWRITE_PNG_COMPRESSION, level])
    assert ok
    return buf.tobytes()


def residual_map(
    xy: np.ndarray, residuals: np.ndarray, size: tuple[int, int], vmax: float, *, cell: int = 8, sigma_px: float = 24.0
) -> np.ndarray:
    """A low-resolution RGBA picture (h/cell, w/cell, 4) of per-match residuals spread over an
    image of ``size`` (w, h): a Gaussian-weighted mean of the residuals around each point,
    inferno-coloured over [0, vmax], opaque where matches are dense and transparent where there
    are none. ``xy`` are the matches' working pixels."""
    w, h = size
    gw, gh = max(1, math.ceil(w / cell)), max(1, math.ceil(h / cell))
    num = np.zeros((gh, gw), np.float64)
    den = np.zeros((gh, gw), np.float64)
    finite = np.isfinite(residuals)
    r = np.clip(residuals[finite], 0, 4 * vmax)
    gx = np.clip((xy[finite, 0] / cell).astype(int), 0, gw - 1)
    gy = np.clip((xy[finite, 1] / cell).astype(int), 0, gh - 1)
    np.add.at(num, (gy, gx), r)
    np.add.at(den, (gy, gx), 1.0)
    s = sigma_px / cell
    num_b = np.asarray(cv2.GaussianBlur(num, (0, 0), s))
    den_b = np.asarray(cv2.GaussianBlur(den, (0, 0), s))
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(den_b > 1e-9, num_b / den_b, 0.0)
    # one match within ~sigma gives about 1 / (2 pi s^2) density: call 3 matches full evidence
    alpha = np.clip(den_b * (2 * math.pi * s * s) / 3.0, 0.0, 1.0)
    rgba = colormap(mean.ravel(), vmax).reshape(gh, gw, 4)
    rgba[..., 3] = np.round(alpha * 220).astype(np.uint8)
    return rgba
