"""DUSt3R's point maps as a record part (:class:`PointMaps`); a module of its own so that the pose
backend that makes them and the record that stores them import it without importing each other."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["PointMaps"]


@dataclass(frozen=True, eq=False)
class PointMaps:
    """DUSt3R's point maps of the first/last pair (``--pose dust3r``), subsampled on a grid.

    xyz0: (h, w, 3) float16, the first frame's points in first-camera coordinates; xyz1: (h, w, 3)
    float16, the last frame's points in first-camera coordinates as the network predicts them
    (not moved by the fitted pose); both on the gate's scale (unit mean scene distance).
    conf0, conf1: (h, w) float16 DUSt3R confidences (at least 1). rgb0, rgb1: (h, w, 3) uint8
    colours of the network's input. frames: the two frame indices; box: (x0, y0, x1, y1) the
    region of the working frame (px, end-exclusive) the network saw, resized to its input of
    ``input_size`` (width, height) px; the stored point (i, j) is the input's pixel
    ``(u, v) = (j * step + step // 2, i * step + step // 2)``, i.e. working pixel
    ``x = x0 + (u + 0.5) * (x1 - x0) / width - 0.5`` (and alike for y); note: backend,
    checkpoint, input size and the alignment's residual.
    """

    xyz0: np.ndarray
    xyz1: np.ndarray
    conf0: np.ndarray
    conf1: np.ndarray
    rgb0: np.ndarray
    rgb1: np.ndarray
    frames: tuple[int, int]
    box: tuple[int, int, int, int]
    input_size: tuple[int, int]
    step: int
    note: str

    NAMES = ("xyz0", "xyz1", "conf0", "conf1", "rgb0", "rgb1")
    DTYPES = {"xyz0": np.float16, "xyz1": np.float16, "conf0": np.float16, "conf1": np.float16}

    def __post_init__(self) -> None:
        h, w = self.conf0.shape[:2] if self.conf0.ndim == 2 else (-1, -1)
        shapes = {"xyz0": (h, w, 3), "xyz1": (h, w, 3), "conf0": (h, w), "conf1": (h, w)}
        shapes.update(rgb0=(h, w, 3), rgb1=(h, w, 3))
        for name, shape in shapes.items():
            if getattr(self, name).shape != shape:
                raise ValueError(f"PointMaps.{name} must have shape {shape}, got {getattr(self, name).shape}")
        for name in self.NAMES:
            dtype = self.DTYPES.get(name, np.uint8)
            object.__setattr__(self, name, np.asarray(getattr(self, name), dtype=dtype))
        object.__setattr__(self, "frames", tuple(int(v) for v in self.frames))
        object.__setattr__(self, "box", tuple(int(v) for v in self.box))
        object.__setattr__(self, "input_size", tuple(int(v) for v in self.input_size))
        object.__setattr__(self, "step", int(self.step))

    def to_json_dict(self) -> dict[str, Any]:
        """The JSON part stored in ``record.json`` (the arrays go to ``matches.npz``)."""
        return {
            "frames": list(self.frames),
            "box": list(self.box),
            "input_size": list(self.input_size),
            "step": self.step,
            "shape": list(self.conf0.shape),
            "note": self.note,
        }
