"""Moving-object masks behind one small streaming interface (SPEC section 2, "mask-first").

A :class:`MaskSource` turns the frames of a clip into label images at WORKING resolution:
``(H, W)`` uint8, 0 = background, ``k`` = object ``k`` (1..255), zero outside the content box.
The background mask of frame t is ``content & (labels(t) == 0)``.

>>> src = make_mask_source("motion", info)                  # doctest: +SKIP
>>> for frame in iter_frames(info):                          # doctest: +SKIP
...     src.push(frame)
...     t = frame.index - src.lookahead
...     if t >= 0:
...         labels = src.labels(t); src.release(t)
>>> src.finish()                                             # then the last frames  # doctest: +SKIP

Streaming contract: frames are pushed in order ``0 .. T-1``; ``labels(t)`` is final (the same
array whenever it is asked) once frame ``t + lookahead`` was pushed or after ``finish()``;
``release(t)`` promises that labels of frames ``< t`` are not asked again, so their memory is
freed. ``warnings`` lists problems found so far, e.g. masks covering more than
:data:`IMPLAUSIBLE_SHARE` of the content (one entry per clip, with the frame range).
``coverage`` maps each frame whose labels were produced to its masked share of the content.

Sources
-------
``external`` (:class:`ExternalMasks`, lookahead 0)
    Masks shipped with a data set, at SOURCE resolution (the size of the clip's decoded frames,
    ``info.source_size``). Three layouts, detected automatically:

    (a) a folder of label images ``00000.png, 00001.png, ...``: one PNG per frame, 8- or 16-bit
        single channel, or indexed (palette) PNGs as DAVIS and YouTube-VOS ship them, whose
        palette indices are the ids; 0 = background, k = object id (1..255); file names end in the frame
        number (any zero-padding, any common prefix), taken in natural order, numbered
        consecutively from 0 (or 1). This is what ``geocon synth`` writes as ``<clip>.masks/``.
    (b) a folder of per-object folders ``<id>/NNNNN.png`` or ``obj_<id>/NNNNN.png`` (id 1..255),
        each holding one binary mask per frame (nonzero = object), numbered like (a); where
        objects overlap, the higher id wins.
    (c) an ``.npz`` file with an integer array ``labels`` of shape (T, h, w), values 0..255
        (read without pickle: an object array is refused, naming the file).

    Every mask is mapped into the working canvas exactly like the reader maps frames (scale
    ``info.scale``, offset ``info.offset``, nearest-neighbour resize with centred pixels), then
    zeroed outside ``info.content_box``. A wrong frame count, a wrong size, missing frame files,
    colour images or ids above 255 raise ValueError with one sentence naming the problem.
    Layouts (a) and (b) read one frame at a time; (c) holds the array in memory.

``motion`` (:class:`MotionSegmenter`, lookahead 7 by default, built in, no weights)
    Dense flow at half resolution, a robust background model per pair (homography, or a
    fundamental matrix with a cheirality check when a moving camera shows parallax), compact,
    sharply bounded residual regions (and, with a still camera, a longer frame gap for slow
    movers), parts of one mover merged, tracked into stable ids that survive gaps. Background failures
    (breathing, sliding layers, boiling texture) stay background. See the class docstring.

``sam2``
    Not available in this build: SAM-2 needs torch, the ``sam2`` package and a checkpoint, and
    :func:`make_mask_source` says so instead of pretending.

Modules: :mod:`.base` (the protocol, coverage, canvas mapping), :mod:`.external`,
:mod:`.motion` (the segmenter), :mod:`.evidence` (flow and background residuals),
:mod:`.regions` (object regions of a score map), :mod:`.identity` (colour, merged parts),
:mod:`.tracking` (object ids).
"""

from __future__ import annotations

import importlib.util
from typing import Any

from ..reader import ClipInfo
from ..stage_configs import MotionConfig
from .base import IMPLAUSIBLE_SHARE, MaskSource, labels_to_canvas, masked_share
from .external import ExternalMasks
from .motion import MotionSegmenter

__all__ = [
    "MaskSource",
    "ExternalMasks",
    "MotionSegmenter",
    "MASK_SOURCES",
    "IMPLAUSIBLE_SHARE",
    "make_mask_source",
    "masked_share",
    "labels_to_canvas",
]

MASK_SOURCES: dict[str, type] = {"external": ExternalMasks, "motion": MotionSegmenter}
"""Available mask sources by name."""


def _sam2_missing() -> str:
    have = [m for m in ("torch", "sam2") if importlib.util.find_spec(m) is not None]
    state = f"{' and '.join(have)} installed but " if have else ""
    return (
        "SAM-2 needs torch, the sam2 package and a checkpoint, which are not available in this build "
        f"({state}no checkpoint or loader is shipped); use one of: {', '.join(MASK_SOURCES)}"
    )


def make_mask_source(name: str, info: ClipInfo, config: MotionConfig | None = None, **kwargs: Any) -> MaskSource:
    """The mask source called ``name`` for the clip of ``info``: ``external`` (``path=...``,
    see :class:`ExternalMasks`) or ``motion`` (settings ``config``, defaults when None, plus
    ``flow=``, ``seed=`` and single-field overrides of :class:`MotionSegmenter`). Raises
    ValueError for ``sam2`` (not in this build) and for unknown names, listing the valid ones."""
    key = str(name).strip().lower()
    if key in ("sam2", "sam-2"):
        raise ValueError(_sam2_missing())
    if key not in MASK_SOURCES:
        raise ValueError(
            f"unknown mask source {name!r}; valid: {', '.join(MASK_SOURCES)} "
            "(sam2 needs torch, the sam2 package and a checkpoint)"
        )
    if key == "external":
        if "path" not in kwargs:
            raise ValueError("external masks need path=... (a folder of label PNGs, per-object folders or an .npz)")
        extra = set(kwargs) - {"path"}
        if extra:
            raise ValueError(f"external masks take only path=..., got also {', '.join(sorted(extra))}")
        if config is not None:
            raise ValueError("external masks take no motion segmentation settings")
        return ExternalMasks(kwargs["path"], info)
    return MotionSegmenter(info, config, **kwargs)
