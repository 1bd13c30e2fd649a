"""The record's part of the region readings (:class:`RegionsPart`): the readings with their
findings in ``record.json``, the tracks they were read from in ``matches.npz``, so that a changed
rule reads them again without the clip (:func:`read_regions_again`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from ..config import RegionsConfig
from .readings import RegionReadings, read_regions
from .tracks import ClipTracks

__all__ = ["ARRAY_PREFIX", "REGION_ARRAYS", "RegionsPart", "read_regions_again"]

ARRAY_PREFIX = "regions_"
REGION_ARRAYS: tuple[str, ...] = tuple(f"{ARRAY_PREFIX}{name}" for name in ClipTracks.ARRAYS)
"""The names of the tracks' arrays in ``matches.npz``."""


@dataclass(frozen=True)
class RegionsPart:
    """The region readings of a clip (``readings``) and the tracks they were read from (``tracks``;
    None in a record read without its arrays)."""

    readings: RegionReadings
    tracks: ClipTracks | None
    size: tuple[int, int]
    scale: float
    camera: str | None = None
    """The model family the clip's gate chose, which every pair's camera is fitted with (None:
    chosen pair by pair)."""

    def values(self) -> dict[str, float | None]:
        """The readings by name, prefixed ``region_`` (the names a clip model would use)."""
        return {f"region_{k}": v for k, v in self.readings.values.items()}

    def to_json_dict(self) -> dict[str, Any]:
        return {**self.readings.to_dict(), "size": list(self.size), "scale": self.scale, "camera": self.camera}

    def arrays(self) -> dict[str, np.ndarray]:
        return {} if self.tracks is None else self.tracks.arrays(ARRAY_PREFIX)

    def summary(self) -> dict[str, Any]:
        """What ``geocon score --json`` prints of it."""
        r = self.readings
        return {
            "values": dict(r.values),
            "fired": [f.describe() for f in r.fired],
            "tracks": r.tracks,
            "coverage": r.coverage,
            **({"cannot_judge": dict(r.reasons)} if r.reasons else {}),
        }

    @classmethod
    def from_json_dict(cls, d: Mapping[str, Any], arrays: Mapping[str, np.ndarray] | None = None) -> "RegionsPart":
        size = (int(d["size"][0]), int(d["size"][1]))
        scale = float(d["scale"])
        tracks = None if arrays is None else ClipTracks.from_arrays(dict(arrays), ARRAY_PREFIX, size, scale)
        camera = d.get("camera")
        return cls(RegionReadings.from_dict(dict(d)), tracks, size, scale, None if camera is None else str(camera))


def read_regions_again(part: RegionsPart, config: RegionsConfig, seed: int = 0) -> RegionsPart:
    """``part`` read again with ``config``'s rules from its stored tracks (no clip needed);
    ValueError when the record kept no tracks."""
    if part.tracks is None:
        raise ValueError("this record keeps no region tracks: score the clip again to read its regions")
    readings = read_regions(part.tracks, config, seed, part.camera)
    return RegionsPart(readings, part.tracks, part.size, part.scale, part.camera)
