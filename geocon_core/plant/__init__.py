"""Failures planted into real footage, with their exact ground truth: ``geocon plant``.

>>> from geocon_core.plant import plant_clip, planted_displacement
>>> result = plant_clip("clip.mp4", "morph", "middle", 0, "out/")   # doctest: +SKIP
>>> d = planted_displacement(result.truth, 5)                       # doctest: +SKIP

A planted failure is a smooth, seeded, time-varying change of a real clip: ``morph`` (a non-rigid
warp inside one textured region, growing), ``redraw`` (a region's texture cross-fading towards
other content), ``breathing`` (a rubber-sheet warp of the whole frame) or ``slide`` (a region
translating against the rest). The clip and its clean twin are encoded the same way, matched to
the source's codec and quality, so the planted damage is the only difference between them.

Modules: :mod:`.kinds` (the kinds, their severity levels and every number that shapes them),
:mod:`.fields` (the region, the displacement fields, the warp), :mod:`.encode` (the source's planes,
matched re-encoding), :mod:`.writer` (the files and the ground truth).
"""

from .encode import ENCODERS, FALLBACK_CODEC, MATCH_FRAMES, PLANAR_FORMATS, Encoder, SourceVideo, probe_source
from .fields import Planting, Region, plan_planting
from .kinds import LEVELS, PLANT_KINDS, SHAPE, PlantKind, PlantShape, amplitude_of
from .writer import (
    PLANT_FORMAT,
    PlantResult,
    plant_clip,
    plant_names,
    planted_displacement,
    read_plant_truth,
    write_clean_clip,
)

__all__ = [
    "ENCODERS",
    "FALLBACK_CODEC",
    "MATCH_FRAMES",
    "PLANAR_FORMATS",
    "Encoder",
    "SourceVideo",
    "probe_source",
    "Planting",
    "Region",
    "plan_planting",
    "LEVELS",
    "PLANT_KINDS",
    "SHAPE",
    "PlantKind",
    "PlantShape",
    "amplitude_of",
    "PLANT_FORMAT",
    "PlantResult",
    "plant_clip",
    "plant_names",
    "planted_displacement",
    "read_plant_truth",
    "write_clean_clip",
]
