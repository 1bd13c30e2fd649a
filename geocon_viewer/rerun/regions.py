"""The region readings (:mod:`geocon_core.regions`) in a Rerun recording, read from the record.

``frame/regions/<reading>``: the region where each reading is largest, outlined on the frame
where its baseline starts (red when it fires, grey when it does not), and on its last frame an
arrow along the drift (its length the drift, exaggerated ``ARROW_GAIN`` times) with the finding in
words. ``series/regions/<reading>``: the drift region's course over the clip, and each reading's
size at the frame its baseline ends. A clip whose regions cannot be judged gets a note saying why.
"""

from __future__ import annotations

import rerun as rr

from geocon_core.record import ClipRecord

__all__ = ["log_regions", "FIRES_RGBA", "QUIET_RGBA"]

FIRES_RGBA = (230, 40, 40, 255)
QUIET_RGBA = (170, 170, 170, 200)
ARROW_GAIN = 4.0
"""Drift arrows are drawn this many times their length (as the object cells' arrows)."""


def log_regions(rec: rr.RecordingStream, record: ClipRecord, set_time) -> bool:
    """Log the record's region readings; ``set_time(t)`` sets the time to frame t. Returns False
    (logging only a note) when the record has none."""
    part = record.regions
    if part is None:
        why = (
            f"The region readings are off in the {record.config.preset!r} preset (they run in 'audit')."
            if not record.config.regions.enabled
            else "No region readings: the record predates them."
        )
        rec.log("frame/regions/note", rr.TextDocument(why), static=True)
        return False
    readings = part.readings
    if not readings.findings:
        reasons = "; ".join(f"{k}: {v}" for k, v in readings.reasons.items()) or "no long tracks"
        rec.log("frame/regions/note", rr.TextDocument(f"The regions cannot be judged ({reasons})."), static=True)
        return False
    for f in readings.findings:
        color = FIRES_RGBA if f.fires else QUIET_RGBA
        path = f"frame/regions/{f.reading}"
        outline = [list(p) for p in f.outline]
        if len(outline) >= 3:
            outline.append(outline[0])
        set_time(f.first)
        rec.log(path, rr.LineStrips2D([outline], colors=[color], labels=[f.describe()], radii=1.5, draw_order=3.0))
        if f.direction is not None:
            set_time(f.last)
            dx, dy = f.direction
            vector = [dx * f.value * ARROW_GAIN, dy * f.value * ARROW_GAIN]
            rec.log(
                f"{path}/arrow",
                rr.Arrows2D(origins=[list(f.centre)], vectors=[vector], colors=[color], labels=[f.describe()]),
            )
        for frame, value in f.course or ((f.last, f.value),):
            set_time(frame)
            rec.log(f"series/regions/{f.reading}", rr.Scalars(float(value)))
    return True
