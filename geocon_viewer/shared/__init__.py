"""What every viewer shares, so that a number and an object look the same everywhere: formatting
and colours (:mod:`.style`) and point clouds as the viewers draw them (:mod:`.clouds`)."""

from __future__ import annotations

from .clouds import clean_cloud, dense_points
from .style import EMPTY, OUTLIER_SPAN, dense_legend, fmt, object_color, track_colors

__all__ = [
    "EMPTY",
    "OUTLIER_SPAN",
    "clean_cloud",
    "dense_legend",
    "dense_points",
    "fmt",
    "object_color",
    "track_colors",
]
