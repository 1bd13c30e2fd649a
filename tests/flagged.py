"""A record the clip model flags on one pictured reading, with a known picture: the readings of a
real (synthetic) clip's record replaced by ones whose appearance changes along the flow only in a
known patch, strongest at a known frame. For the viewers' and the report's tests of what a flagged
clip is shown with (the readings' own maths is tested on real clips in test_signals)."""

from __future__ import annotations

import shutil
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from geocon_core.config import preset
from geocon_core.record import ClipRecord, read_record, write_record
from geocon_core.signals import ClipReadings, PairReading, ReadingMaps, summarize

STRONGEST_FRAME = 9


@dataclass(frozen=True)
class Patch:
    """The patch where the map fires, in working pixels: centre (x, y), and a point far from it."""

    centre: tuple[int, int]
    far: tuple[int, int]


def flagged_on_appearance(source: Path, folder: Path) -> tuple[ClipRecord, Patch]:
    """Copy the record folder ``source`` to ``folder`` and give it such readings (default preset)."""
    shutil.copytree(source, folder)
    rec = read_record(folder)
    x0, y0, x1, y1 = rec.video.content_box
    h, w = (y1 - y0) // 2, (x1 - x0) // 2  # any canvas size: the map is laid over the content box
    hot = np.zeros((h, w), np.uint8)
    hot[h // 4 : h // 2, w // 4 : w // 2] = 255
    zero = np.zeros((h, w), np.uint8)
    pairs = [PairReading(t, t + 1, census=0.9 if t == STRONGEST_FRAME else 0.5) for t in range(0, 15, 3)]
    pairs += [PairReading(t, t + 4, failure=0.01, interior=0.0, movers=0.0) for t in range(0, 12, 3)]
    readings = ClipReadings(summarize(pairs, ReadingMaps(zero, zero, hot)), 0.0)
    rec = replace(rec, config=preset("audit").with_(working_size=rec.config.working_size), readings=readings)
    write_record(rec, folder)
    patch = Patch((x0 + 3 * w // 4, y0 + 3 * h // 4), (x0 + 3 * w // 2, y0 + 3 * h // 2))
    return read_record(folder), patch
