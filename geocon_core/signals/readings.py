"""The clip's readings as a record part, and the values a clip model reads."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, Mapping

import numpy as np

from .appearance import MAP_NAMES, AppearanceReading, PairReading, ReadingMaps

__all__ = ["MAP_ARRAYS", "READING_LABELS", "ClipReadings"]

MAP_ARRAYS: tuple[str, ...] = tuple(f"readings_{name}" for name in MAP_NAMES)
"""The arrays of ``matches.npz`` that hold the readings' maps (:class:`~.appearance.ReadingMaps`)."""

READING_LABELS: dict[str, str] = {
    "shortfall": "background fit",
    "unkept": "matches one F does not keep",
    "flow_failure": "flow failures",
    "interior_failure": "flow failures inside surfaces",
    "unexplained_appearance": "appearance the flow does not explain",
    "mover_share": "share moving on its own",
    "mv_residual": "multi-view residual",
    "object_rigidity": "object rigidity (AdaDFRC-W2)",
}
"""Every reading a clip model can use (name -> what a person reads), larger = more broken:
``shortfall`` is minus the report gate's headroom (:func:`~geocon_core.record.finding.report_margin`),
``unkept`` the keep reading (:mod:`.keep`), the next four :mod:`.appearance`, ``mv_residual`` the
multi-view check's median track residual (source px) and ``object_rigidity`` the largest
AdaDFRC-W2 of the clip's objects (px^2)."""


@dataclass(frozen=True)
class ClipReadings:
    """The readings made beside the background fit: ``appearance`` (:mod:`.appearance`, None when
    the clip is too short to read) and ``unkept`` (:mod:`.keep`)."""

    appearance: AppearanceReading | None
    unkept: float | None

    def values(self) -> dict[str, float | None]:
        """These readings by name (:data:`READING_LABELS`)."""
        a = self.appearance
        return {
            "unkept": self.unkept,
            "flow_failure": None if a is None else a.flow_failure,
            "interior_failure": None if a is None else a.interior_failure,
            "unexplained_appearance": None if a is None else a.unexplained_appearance,
            "mover_share": None if a is None else a.mover_share,
        }

    def to_json_dict(self) -> dict[str, Any]:
        return {
            "unkept": self.unkept,
            "appearance": None
            if self.appearance is None
            else {**self.appearance.to_dict(), "pairs": [asdict(p) for p in self.appearance.pairs]},
        }

    def arrays(self) -> dict[str, np.ndarray]:
        """The maps kept in ``matches.npz`` (:data:`MAP_ARRAYS`), empty when there are none."""
        maps = None if self.appearance is None else self.appearance.maps
        if maps is None:
            return {}
        return {key: getattr(maps, name) for key, name in zip(MAP_ARRAYS, MAP_NAMES, strict=True)}

    @classmethod
    def from_json_dict(cls, d: Mapping[str, Any], arrays: Mapping[str, np.ndarray] | None = None) -> "ClipReadings":
        """The readings of ``record.json``'s ``readings``, with their maps where ``arrays`` (of
        ``matches.npz``) hold them."""
        a = d.get("appearance")
        maps = None
        if arrays is not None and all(key in arrays for key in MAP_ARRAYS):
            maps = ReadingMaps(*(np.asarray(arrays[key], np.uint8) for key in MAP_ARRAYS))
        appearance = None
        if a is not None:
            appearance = AppearanceReading(
                flow_failure=a["flow_failure"],
                interior_failure=a["interior_failure"],
                unexplained_appearance=a["unexplained_appearance"],
                mover_share=a["mover_share"],
                pairs=tuple(PairReading(**p) for p in a.get("pairs", [])),
                maps=maps,
            )
        return cls(appearance, d.get("unkept"))
