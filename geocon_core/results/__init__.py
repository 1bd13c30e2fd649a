"""A results folder read back: the triage list, its clips and their thumbnails.

:class:`ResultsIndex` (:mod:`.triage`) lists the clips of a results folder as triage rows, most
severe first, re-gated live under other thresholds; :mod:`.clips` reads one clip's folder (its
record, status and tables) as a :class:`ResultClip`; :mod:`.thumbs` draws a clip's thumbnails
(first frame, worst pair with its inliers and outliers, last frame). Needs the core install only:
the audit app reads results folders with it.
"""

from __future__ import annotations

from .clips import (
    ResultClip,
    clip_from_record_json,
    read_bench_clips,
)
from .thumbs import (
    LAYER_RGB,
    THUMB_WIDTH,
    ClipThumbs,
    Thumb,
    WorstPair,
    clip_thumbs,
    draw_matches,
    many_clip_thumbs,
    read_frames,
    thumbs_html,
    worst_pair,
)
from .triage import (
    BROKEN,
    VERDICTS,
    ResultsError,
    ResultsIndex,
    TriageRow,
    severity_key,
)

__all__ = [
    "ResultClip",
    "clip_from_record_json",
    "read_bench_clips",
    "TriageRow",
    "ResultsIndex",
    "ResultsError",
    "VERDICTS",
    "BROKEN",
    "severity_key",
    "THUMB_WIDTH",
    "ClipThumbs",
    "Thumb",
    "WorstPair",
    "clip_thumbs",
    "draw_matches",
    "many_clip_thumbs",
    "read_frames",
    "thumbs_html",
    "worst_pair",
    "LAYER_RGB",
]
