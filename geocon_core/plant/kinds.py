"""The planted failures and every number that shapes them, in one place.

Severity levels per kind (the amplitude ``A`` each level sets, in the clip's own pixels):

=============  ===========================================  =====  ======  ====  ==========================
kind           amplitude                                    low    middle  high  over time ``g(t)``
=============  ===========================================  =====  ======  ====  ==========================
``morph``      peak displacement at the last frame, px      2      5       10    smoothstep ``s^2 (3 - 2s)``
``redraw``     blend weight of the other content, last      0.3    0.6     1.0   smoothstep ``s^2 (3 - 2s)``
               frame (0..1)
``breathing``  peak displacement, px                        2      5       10    ``sin(2 pi t / 24)``
``slide``      shift of the region at the last frame, px    2      5       10    linear ``s``
=============  ===========================================  =====  ======  ====  ==========================

``s = t / (T - 1)`` over the ``T`` frames planted: frame 0 is never changed, and the damage grows
to its amplitude at the last frame (breathing oscillates as the synthetic family's does, with its
24-frame period). The shapes (:data:`SHAPE`): a region is an ellipse of semi-axes
``region_semi_axes`` (shares of the frame's width and height), its weight 1 inside
``taper_start`` of its normalised radius and falling to 0 at its rim along a half cosine.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["LEVELS", "PLANT_KINDS", "PlantKind", "PlantShape", "SHAPE", "plant_kind", "amplitude_of"]

LEVELS: tuple[str, ...] = ("low", "middle", "high")
"""The severity levels of ``geocon plant --severity``."""


@dataclass(frozen=True)
class PlantKind:
    """One kind of planted failure: its name, what it does, the unit of its amplitude, the
    amplitude at each of :data:`LEVELS` and how it grows over the clip (``ramp``: ``smoothstep``,
    ``linear`` or ``sine``)."""

    kind: str
    summary: str
    unit: str
    amplitudes: tuple[float, float, float]
    ramp: str
    displaces: bool
    """Whether the kind moves content (a displacement field optical flow can recover); ``redraw``
    blends content instead."""


PLANT_KINDS: dict[str, PlantKind] = {
    k.kind: k
    for k in (
        PlantKind(
            "morph",
            "a smooth non-rigid warp inside one textured region, growing as a melting object does",
            "px of peak displacement at the last frame",
            (2.0, 5.0, 10.0),
            "smoothstep",
            True,
        ),
        PlantKind(
            "redraw",
            "one region's texture cross-fades towards a patch from elsewhere in the frame",
            "blend weight of the other content at the last frame",
            (0.3, 0.6, 1.0),
            "smoothstep",
            False,
        ),
        PlantKind(
            "breathing",
            "rubber-sheet warp of the whole frame (the synthetic family's breathing)",
            "px of peak displacement",
            (2.0, 5.0, 10.0),
            "sine",
            True,
        ),
        PlantKind(
            "slide",
            "one region translates against the rest, growing over time, with soft edges",
            "px of shift at the last frame",
            (2.0, 5.0, 10.0),
            "linear",
            True,
        ),
    )
}
"""The kinds of ``geocon plant`` by name (:class:`PlantKind`)."""


@dataclass(frozen=True)
class PlantShape:
    """The numbers that shape a planted failure besides its amplitude (:data:`SHAPE`)."""

    region_semi_axes: tuple[float, float] = (0.18, 0.22)
    """Semi-axes of the region's ellipse, shares of the frame's width and height."""
    taper_start: float = 0.5
    """Normalised radius (0 centre, 1 rim) where the region's weight starts to fall from 1 to 0."""
    region_margin: float = 0.04
    """Share of the frame's width and height kept between the region and the frame's edge in frame 0."""
    candidate_step: float = 0.04
    """Spacing of the candidate region centres, share of the frame's width and height."""
    textured_share: float = 0.25
    """The region is drawn (seeded, uniformly) from this share of the candidates with the most
    texture (mean smallest eigenvalue of the structure tensor over the region's core)."""
    breathing_cycles: tuple[float, float] = (0.6, 2.0)
    """Breathing: plane-wave frequencies, cycles per frame width or height (the synthetic family's)."""
    breathing_period: int = 24
    """Breathing: period of ``sin(2 pi t / period)``, frames (the synthetic family's)."""
    morph_cycles: tuple[float, float] = (0.2, 0.45)
    """Morph: plane-wave frequencies, cycles per unit of the region's normalised radius."""
    morph_droop: float = 1.5
    """Morph: weight of the downward droop ``(0, (1 + v) / 2)`` added to the waves (a melting sag)."""
    slide_max_angle_deg: float = 30.0
    """Slide: the direction is within this angle of the image's horizontal, either way."""
    max_stretch: float = 0.8
    """Largest allowed ``|d d / d x|`` (any partial derivative of the displacement, any frame): above
    it the warp folds content over itself; a clip too small for a level is refused."""
    inverse_tolerance_px: float = 1e-4
    """The warp is inverted by fixed-point iteration until points move less than this, px."""
    inverse_max_iterations: int = 200
    """At most this many fixed-point iterations per frame."""
    normalise_grid: int = 201
    """Points per side of the grid on which a region's field is normalised to a peak of 1."""
    polygon_vertices: int = 48
    """Vertices of the region's outline stored per frame in the ground truth."""


SHAPE = PlantShape()
"""The shape settings every planting uses."""

RNG_STREAM = 7301
"""Second word of the random generator's seed (``default_rng([seed, RNG_STREAM, kind index])``)."""


def plant_kind(kind: str) -> PlantKind:
    """The :class:`PlantKind` called ``kind``; ValueError naming the valid ones otherwise."""
    try:
        return PLANT_KINDS[kind]
    except (KeyError, TypeError):
        raise ValueError(f"unknown planted failure {kind!r}; valid: {', '.join(PLANT_KINDS)}") from None


def amplitude_of(kind: str, level: str) -> float:
    """The amplitude of ``kind`` at severity ``level`` (one of :data:`LEVELS`); ValueError otherwise."""
    spec = plant_kind(kind)
    if level not in LEVELS:
        raise ValueError(f"unknown severity {level!r}; give one of {', '.join(LEVELS)}")
    return spec.amplitudes[LEVELS.index(level)]
