"""Pictures of the readings: where on the frame each appearance reading fires.

The maps of :class:`~.appearance.ReadingMaps` live on the readings' small canvas of the clip's
content box; :func:`map_on_frame` puts one back on a frame of the working size, and
:func:`heat_rgba` / :func:`blend_heat` colour it (inferno, transparent where nothing fires) on a
fixed scale per map, so that two clips' pictures can be compared by eye. The viewers and the
report's thumbnails draw the same pictures from these functions.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import cv2
import numpy as np

from .appearance import ReadingMaps

__all__ = [
    "MAP_OF_READING",
    "MAP_VIEWS",
    "MapView",
    "blend_heat",
    "heat_rgba",
    "leading_picture",
    "map_on_frame",
    "picture_of",
]


@dataclass(frozen=True)
class MapView:
    """How a map is shown: its ``title``, what one pixel's value means (``unit``) and the value
    drawn at full colour (``vmax``)."""

    title: str
    unit: str
    vmax: float


MAP_VIEWS: dict[str, MapView] = {
    "failure": MapView("where the flow fails inside surfaces", "share of the far pairs", 1.0),
    "movers": MapView("where pixels move on their own", "share of the far pairs", 1.0),
    "unexplained": MapView("where appearance changes along the flow", "census change", 0.4),
}
"""Each map of :data:`~.appearance.MAP_NAMES` as it is shown. The scales were set from the stick's
clips (2026-11-28): on real-camera clips the failure map's 90th percentile is about 0.3 and the
unexplained map's about 0.14, on generated clips with a geometric artifact 1.0 and 0.35, so a real
clip's picture stays dim and a broken one's lights up."""

MAP_OF_READING: dict[str, str] = {
    "flow_failure": "failure",
    "interior_failure": "failure",
    "mover_share": "movers",
    "unexplained_appearance": "unexplained",
}
"""The map that shows where a reading (:data:`~.readings.READING_LABELS`) fires."""


def picture_of(reading: str) -> str | None:
    """The name of the map that pictures ``reading`` (None for a reading shown elsewhere: the
    background fit by its matches and residuals, the multi-view check by its tracks)."""
    return MAP_OF_READING.get(reading)


def leading_picture(parts: Sequence[tuple[str, float]]) -> tuple[str, str] | None:
    """(reading, map) of the reading that adds the most to a clip score's log-odds among those
    with a picture (``parts``: the finding's contributions, largest first), or None when none of
    them adds anything."""
    pictured = [(part, name) for name, part in parts if picture_of(name) is not None and part > 0]
    if not pictured:
        return None
    _, name = max(pictured)
    return name, MAP_OF_READING[name]


def map_on_frame(
    maps: ReadingMaps, name: str, content_box: tuple[int, int, int, int], size: tuple[int, int]
) -> np.ndarray:
    """Map ``name`` as shares (0..1, float32) on a frame of ``size`` (w, h): resized (bilinear)
    onto the ``content_box`` (x0, y0, x1, y1) it was read from, 0 outside it."""
    w, h = size
    x0, y0, x1, y1 = content_box
    out = np.zeros((h, w), np.float32)
    if x1 <= x0 or y1 <= y0:
        return out
    out[y0:y1, x0:x1] = cv2.resize(maps.shares(name), (x1 - x0, y1 - y0), interpolation=cv2.INTER_LINEAR)
    return out


def heat_rgba(shares: np.ndarray, vmax: float) -> np.ndarray:
    """(h, w, 4) uint8: ``shares`` coloured with inferno up to ``vmax``, opacity rising with the
    value (transparent at 0, 80% at ``vmax`` and above)."""
    level = np.clip(shares / max(vmax, 1e-9), 0.0, 1.0)
    idx = np.round(level * 255.0).astype(np.uint8)
    rgb = cv2.cvtColor(cv2.applyColorMap(idx, cv2.COLORMAP_INFERNO), cv2.COLOR_BGR2RGB)
    alpha = np.round(np.sqrt(level) * 204.0).astype(np.uint8)
    return np.dstack([rgb, alpha])


def blend_heat(rgb: np.ndarray, shares: np.ndarray, vmax: float) -> np.ndarray:
    """``rgb`` (h, w, 3 uint8) dimmed to half, with :func:`heat_rgba` of ``shares`` (same h, w)
    laid over it."""
    heat = heat_rgba(shares, vmax).astype(np.float32)
    a = heat[..., 3:] / 255.0
    base = rgb.astype(np.float32) * 0.5
    return np.round(base * (1.0 - a) + heat[..., :3] * a).astype(np.uint8)
