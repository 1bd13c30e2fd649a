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

``sam2`` (:class:`~geocon_core.masks.sam2.Sam2Masks`, the motion segmentation's lookahead)
    SAM-2's video predictor prompted with the boxes of the motion segmentation's movers on the
    first frame each appears, then tracking them under the same ids (:mod:`.sam2`). Needs the
    ``neural`` extra, the ``sam2`` package and a checkpoint the user gives; nothing is downloaded.

Modules: :mod:`.base` (the protocol, coverage, canvas mapping), :mod:`.external`,
:mod:`.motion` (the segmenter), :mod:`.evidence` (flow and background residuals),
:mod:`.regions` (object regions of a score map), :mod:`.identity` (colour, merged parts),
:mod:`.tracking` (object ids), :mod:`.sam2` (SAM-2, loaded only when chosen).
"""

from __future__ import annotations

from typing import Any

from ..config import MotionConfig, Sam2Config
from ..media import ClipInfo
from .base import IMPLAUSIBLE_SHARE, MaskSource, labels_to_canvas, masked_share
from .external import ExternalMasks, check_masks_path
from .motion import MotionSegmenter
from .sam2 import SAM2_INSTALL, Sam2Masks, load_sam2, sam2_config_names

__all__ = [
    "MaskSource",
    "ExternalMasks",
    "MotionSegmenter",
    "Sam2Masks",
    "MASK_SOURCES",
    "IMPLAUSIBLE_SHARE",
    "make_mask_source",
    "masked_share",
    "labels_to_canvas",
    "check_masks_path",
    "SAM2_INSTALL",
    "load_sam2",
    "sam2_config_names",
]

MASK_SOURCES: dict[str, type] = {"external": ExternalMasks, "motion": MotionSegmenter, "sam2": Sam2Masks}
"""Available mask sources by name (``sam2`` imports torch and SAM-2 only when a model is loaded)."""


def make_mask_source(name: str, info: ClipInfo, config: MotionConfig | None = None, **kwargs: Any) -> MaskSource:
    """The mask source called ``name`` for the clip of ``info``: ``external`` (``path=...``,
    see :class:`ExternalMasks`), ``motion`` (settings ``config``, defaults when None, plus
    ``flow=``, ``seed=`` and single-field overrides of :class:`MotionSegmenter`) or ``sam2``
    (:class:`~geocon_core.masks.sam2.Sam2Masks`: ``model=`` a :func:`~geocon_core.masks.sam2.load_sam2`
    result or ``checkpoint=PATH``, ``sam2=`` its :class:`~geocon_core.config.stages.Sam2Config`,
    and the motion segmentation's ``config``, ``flow=`` and ``seed=`` for its prompts). Raises
    ValueError for unknown names, listing the valid ones, and for missing settings."""
    key = str(name).strip().lower()
    if key == "sam-2":
        key = "sam2"
    if key not in MASK_SOURCES:
        raise ValueError(f"unknown mask source {name!r}; valid: {', '.join(MASK_SOURCES)}")
    if key == "sam2":
        return _sam2_source(info, config, **kwargs)
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


def _sam2_source(
    info: ClipInfo,
    config: MotionConfig | None,
    *,
    model: Any = None,
    checkpoint: Any = None,
    sam2: Sam2Config | None = None,
    **motion: Any,
) -> MaskSource:
    if model is None:
        model = load_sam2(checkpoint, sam2)
    elif checkpoint is not None:
        raise ValueError("sam2 masks take either model= or checkpoint=, not both")
    return Sam2Masks(info, model, MotionSegmenter(info, config, **motion), sam2)
