"""Region-by-region readings over the whole clip.

What builds up slowly over a clip in one place (a layer that slides, a surface that melts, a
patch that is redrawn) moves a few tenths of a pixel per frame and never crosses a per-pair
threshold, and a frame-wide number drowns it. This stage follows long tracks over the whole frame
once per clip (:mod:`.tracks`, movers included) and reads, region by region and over long
baselines, each region's motion against the clip's one camera and its look against its start
(:mod:`.readings`). Tracks in, typed readings out; the record keeps both, so the viewers draw
them and a changed rule is read again from the record without the clip.

>>> from geocon_core.config import RegionsConfig
>>> RegionsConfig(enabled=True).min_baseline
12
"""

from .part import REGION_ARRAYS, RegionsPart, read_regions_again
from .readings import READING_NAMES, RegionFinding, RegionReadings, read_regions
from .tracks import ClipTracks, RegionTracker, region_keyframes

__all__ = [
    "READING_NAMES",
    "REGION_ARRAYS",
    "RegionsPart",
    "read_regions_again",
    "ClipTracks",
    "RegionFinding",
    "RegionReadings",
    "RegionTracker",
    "read_regions",
    "region_keyframes",
]
