"""Formatting and colours shared by the command line and the viewers, so that a number and an
object look the same everywhere."""

from __future__ import annotations

import colorsys
import math

__all__ = ["EMPTY", "fmt", "object_color"]

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
