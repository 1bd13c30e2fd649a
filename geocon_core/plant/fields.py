"""Where and how a planted failure changes a clip: its region, its displacement field, and the warp
that applies it to the planes of a decoded frame.

Convention (what optical flow measures): ``d_t(x)`` is the forward displacement at frame ``t``:
the content at pixel ``x`` of the clean frame ``t`` lies at ``x + d_t(x)`` in the planted frame
``t``, so the flow from the clean frame to the planted one is ``d_t`` (the clip's own pixels,
pixel centres at integer coordinates, ``(dx, dy)`` with y down). The planted frame is drawn by
inverting it: pixel ``y`` shows the clean content at the ``x`` with ``x + d_t(x) = y``, found by
the fixed-point iteration ``x <- y - d_t(x)`` (it converges because no partial derivative of
``d_t`` exceeds :attr:`~.kinds.PlantShape.max_stretch`, below 1) and sampled bicubically. A pixel
whose content does not move keeps its decoded value exactly.

Fields, with ``A`` the amplitude, ``g(t)`` the ramp of the kind (:mod:`.kinds`), ``w_t`` the
region's weight (1 in its core, a half cosine to 0 at its rim; the region's centre follows the
clip's content, :func:`track_centres`) and ``(u, v) = ((x - c_t) / a, (y - c_t) / b)`` the point
in the region's normalised frame:

- ``breathing``: ``d_t(x) = A g(t) phi(x / W, y / H) / N``, ``phi`` three plane waves per
  component (:func:`~geocon_core.synth.plane_wave_field`), ``N`` its largest length over the frame;
- ``slide``: ``d_t(x) = A g(t) w_t(x) e``, ``e`` a unit direction within 30 degrees of the
  horizontal;
- ``morph``: ``d_t(x) = A g(t) w_t(x) (phi(u, v) + (0, droop (1 + v) / 2)) / N``, ``N`` the largest
  length of ``w phi`` over the region;
- ``redraw``: no displacement; plane value ``p' = p + A g(t) w_t(x) (q - p)`` with ``q`` the clean
  frame at ``x + o`` (``o``: the offset of another textured region of the frame).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Iterable, Iterator, Mapping, Sequence

import cv2
import numpy as np

from ..flow import DisFlow
from ..synth import plane_wave_field, plane_waves
from .kinds import PLANT_KINDS, RNG_STREAM, SHAPE, PlantKind, PlantShape, amplitude_of, plant_kind

__all__ = [
    "Planting",
    "Region",
    "choose_donor",
    "choose_region",
    "in_view",
    "plan_planting",
    "region_axes",
    "region_candidates",
    "ramp",
    "taper_weight",
    "texture_map",
    "track_centres",
]

CONVENTION = (
    "forward: the content at pixel x of the clean frame t lies at x + d_t(x) in the planted frame t (the "
    "optical flow clean -> planted); the clip's pixels, pixel centres at integer coordinates, (dx, dy), y down"
)

FORMULAS = {
    "breathing": "d_t(x, y) = A g(t) phi(x / W, y / H) / N; phi_c(u, v) = sum_k amps[c][k] sin(2 pi (freqs[c][k][0] u "
    "+ freqs[c][k][1] v) + phases[c][k])",
    "slide": "d_t(x) = A g(t) w_t(x) direction",
    "morph": "d_t(x) = A g(t) w_t(x) (phi(u, v) + (0, droop (1 + v) / 2)) / N; (u, v) = ((x - cx_t) / a, (y - cy_t) / "
    "b); phi as for breathing",
    "redraw": "no displacement; p'(x) = p(x) + A g(t) w_t(x) (p(x + donor_offset) - p(x)) per plane",
}
"""The formula of each kind, as the ground truth states it (symbols: :mod:`.fields`)."""

WEIGHT_FORMULA = (
    "w_t(x) = 1 for r <= taper_start, 0.5 (1 + cos(pi (r - taper_start) / (1 - taper_start))) below 1, else 0; "
    "r = |((x - cx_t) / a, (y - cy_t) / b)|"
)


def ramp(kind: str, t: int, num_frames: int, period: int = SHAPE.breathing_period) -> float:
    """``g(t)``: how much of the amplitude frame ``t`` of ``num_frames`` carries (0 at frame 0;
    ``period``: of the ``sine`` ramp, frames)."""
    how = plant_kind(kind).ramp
    if how == "sine":
        return math.sin(2 * math.pi * t / period)
    s = t / max(1, num_frames - 1)
    return s if how == "linear" else s * s * (3.0 - 2.0 * s)


def taper_weight(r: np.ndarray, taper_start: float) -> np.ndarray:
    """The region's weight at normalised radius ``r``: 1 up to ``taper_start``, a half cosine down
    to 0 at 1, and 0 beyond."""
    r = np.asarray(r, dtype=np.float64)
    fall = 0.5 * (1.0 + np.cos(math.pi * np.clip((r - taper_start) / (1.0 - taper_start), 0.0, 1.0)))
    return np.where(r >= 1.0, 0.0, fall)


@dataclass(frozen=True)
class Region:
    """An ellipse of ``semi_axes`` (a, b) px whose centre is ``centres[t]`` at frame ``t`` (it
    follows the content), weighted by :func:`taper_weight`."""

    semi_axes: tuple[float, float]
    centres: tuple[tuple[float, float], ...]
    taper_start: float = SHAPE.taper_start

    def normalised(self, t: int, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(u, v)``: points in the region's frame at frame ``t`` (the rim is ``u^2 + v^2 = 1``)."""
        cx, cy = self.centres[t]
        a, b = self.semi_axes
        return (np.asarray(x, np.float64) - cx) / a, (np.asarray(y, np.float64) - cy) / b

    def weight(self, t: int, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """``w_t`` at the points (x, y)."""
        u, v = self.normalised(t, x, y)
        return taper_weight(np.hypot(u, v), self.taper_start)

    def box(self, t: int, width: int, height: int) -> tuple[int, int, int, int]:
        """(x0, y0, x1, y1), end-exclusive, clipped to the frame: the pixels the region may touch
        at frame ``t`` (empty when it lies outside)."""
        cx, cy = self.centres[t]
        a, b = self.semi_axes
        x0, x1 = max(0, math.floor(cx - a) - 1), min(width, math.ceil(cx + a) + 2)
        y0, y1 = max(0, math.floor(cy - b) - 1), min(height, math.ceil(cy + b) + 2)
        return x0, y0, max(x0, x1), max(y0, y1)

    def polygon(self, t: int, vertices: int = SHAPE.polygon_vertices) -> list[list[float]]:
        """The rim at frame ``t`` as ``vertices`` (x, y) points, px."""
        cx, cy = self.centres[t]
        a, b = self.semi_axes
        angles = np.linspace(0.0, 2 * math.pi, vertices, endpoint=False)
        return [[round(cx + a * math.cos(q), 3), round(cy + b * math.sin(q), 3)] for q in angles]

    def to_dict(self) -> dict[str, Any]:
        return {
            "shape": "ellipse",
            "semi_axes": [float(v) for v in self.semi_axes],
            "taper_start": float(self.taper_start),
            "weight": WEIGHT_FORMULA,
            "centres": [[float(x), float(y)] for x, y in self.centres],
            "polygons": [self.polygon(t) for t in range(len(self.centres))],
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> Region:
        a, b = d["semi_axes"]
        return cls((float(a), float(b)), tuple((float(x), float(y)) for x, y in d["centres"]), float(d["taper_start"]))


def texture_map(luma: np.ndarray) -> np.ndarray:
    """(h, w) float32: the smallest eigenvalue of the structure tensor (5 px windows): high where
    the image has texture in every direction, as optical flow needs."""
    return np.asarray(cv2.cornerMinEigenVal(np.ascontiguousarray(luma), blockSize=5, ksize=3))


def _candidates(width: int, height: int, semi_axes: tuple[float, float], margin: float, step: float) -> np.ndarray:
    """(n, 2) centres at which an ellipse of ``semi_axes`` lies ``margin`` (share of the frame)
    inside the frame, on a grid ``step`` (share of the frame) apart; the frame's centre at least."""
    a, b = semi_axes
    lo_x, hi_x = a + margin * width, width - 1 - a - margin * width
    lo_y, hi_y = b + margin * height, height - 1 - b - margin * height
    xs = np.arange(lo_x, hi_x + 1e-9, step * width) if hi_x >= lo_x else np.array([(width - 1) / 2])
    ys = np.arange(lo_y, hi_y + 1e-9, step * height) if hi_y >= lo_y else np.array([(height - 1) / 2])
    gx, gy = np.meshgrid(xs, ys)
    return np.stack([gx.ravel(), gy.ravel()], axis=1)


def _core_texture(texture: np.ndarray, centres: np.ndarray, half: tuple[float, float]) -> np.ndarray:
    """Mean of ``texture`` over the box of half-sides ``half`` around each centre."""
    h, w = texture.shape
    integral = cv2.integral(texture.astype(np.float64))
    x0 = np.clip(np.round(centres[:, 0] - half[0]).astype(int), 0, w - 1)
    x1 = np.clip(np.round(centres[:, 0] + half[0]).astype(int) + 1, x0 + 1, w)
    y0 = np.clip(np.round(centres[:, 1] - half[1]).astype(int), 0, h - 1)
    y1 = np.clip(np.round(centres[:, 1] + half[1]).astype(int) + 1, y0 + 1, h)
    total = integral[y1, x1] - integral[y0, x1] - integral[y1, x0] + integral[y0, x0]
    return total / ((x1 - x0) * (y1 - y0))


def _draw_textured(scores: np.ndarray, rng: np.random.Generator, share: float) -> int:
    """Index of a candidate drawn uniformly (``rng``) from the ``share`` of ``scores`` that is highest."""
    order = np.lexsort((np.arange(len(scores)), -scores))  # highest first, ties by index
    top = order[: max(1, math.ceil(share * len(order)))]
    return int(top[int(rng.integers(len(top)))])


def region_axes(width: int, height: int, shape: PlantShape = SHAPE) -> tuple[float, float]:
    """The semi-axes (px) of a region in a ``width`` x ``height`` frame."""
    return shape.region_semi_axes[0] * width, shape.region_semi_axes[1] * height


def region_candidates(width: int, height: int, shape: PlantShape = SHAPE) -> np.ndarray:
    """(n, 2): the centres a region may start at in the first frame (:attr:`PlantShape.candidate_step`
    apart, the ellipse :attr:`PlantShape.region_margin` inside the frame)."""
    return _candidates(width, height, region_axes(width, height, shape), shape.region_margin, shape.candidate_step)


def in_view(tracks: np.ndarray, axes: tuple[float, float], width: int, height: int) -> np.ndarray:
    """(n,): for each track ((T, n, 2) centres), the smallest share over its frames of the region's
    bounding box that lies inside the frame."""
    a, b = axes
    x0, x1 = np.clip(tracks[..., 0] - a, 0, width), np.clip(tracks[..., 0] + a, 0, width)
    y0, y1 = np.clip(tracks[..., 1] - b, 0, height), np.clip(tracks[..., 1] + b, 0, height)
    return (((x1 - x0) * (y1 - y0)) / (4 * a * b)).min(axis=0)


def choose_region(luma: np.ndarray, tracks: np.ndarray, rng: np.random.Generator, shape: PlantShape = SHAPE) -> int:
    """Which candidate (:func:`region_candidates`, followed through the clip: ``tracks``, (T, n, 2))
    carries the failure: among those that stay most in view (:func:`in_view`; all of them in most
    clips), drawn (``rng``) uniformly from the :attr:`PlantShape.textured_share` whose core has the
    most texture in the first frame ``luma`` (:func:`texture_map`)."""
    h, w = luma.shape
    axes = region_axes(w, h, shape)
    seen = in_view(tracks, axes, w, h)
    keep = np.flatnonzero(seen >= seen.max() - 1e-9)
    core = (axes[0] * shape.taper_start, axes[1] * shape.taper_start)
    scores = _core_texture(texture_map(luma), tracks[0, keep], core)
    return int(keep[_draw_textured(scores, rng, shape.textured_share)])


def choose_donor(
    luma: np.ndarray,
    centre: tuple[float, float],
    axes: tuple[float, float],
    rng: np.random.Generator,
    shape: PlantShape = SHAPE,
) -> tuple[float, float]:
    """``redraw``: the offset (px) from the region's centre to another region of the same size,
    inside the frame and apart from it (the farthest when none is apart), drawn (``rng``) from the
    :attr:`PlantShape.textured_share` of them whose core looks least like the region's (mean
    absolute grey difference), so the region visibly turns into other content."""
    h, w = luma.shape
    centres = _candidates(w, h, axes, 0.0, shape.candidate_step)
    apart = np.hypot((centres[:, 0] - centre[0]) / axes[0], (centres[:, 1] - centre[1]) / axes[1])
    if not (apart >= 2.0).any():
        i = int(np.argmax(apart))
        return float(centres[i, 0] - centre[0]), float(centres[i, 1] - centre[1])
    centres = centres[apart >= 2.0]
    hx, hy = (int(round(v * shape.taper_start)) for v in axes)
    grey = luma.astype(np.float64)

    def core(cx: float, cy: float) -> np.ndarray:
        x, y = int(round(cx)), int(round(cy))
        return cv2.getRectSubPix(grey.astype(np.float32), (2 * hx + 1, 2 * hy + 1), (float(x), float(y)))

    mine = core(*centre)
    unlike = np.array([float(np.abs(core(cx, cy) - mine).mean()) for cx, cy in centres])
    i = _draw_textured(unlike, rng, shape.textured_share)
    return float(centres[i, 0] - centre[0]), float(centres[i, 1] - centre[1])


MEDIAN_SAMPLES = 4096
"""At most about this many pixels of a region (on a regular grid) give the median of its flow."""


def track_centres(
    lumas: Iterable[np.ndarray], starts: np.ndarray, axes: tuple[float, float], shape: PlantShape = SHAPE
) -> np.ndarray:
    """(T, n, 2): the centres of regions of semi-axes ``axes`` that start at ``starts`` ((n, 2)) in
    the first frame of ``lumas`` ((h, w) uint8 each) and follow the content: each moves by the
    median of the forward-backward-consistent DIS flow (default settings) between consecutive frames
    over its ellipse (sampled on a grid of at most about :data:`MEDIAN_SAMPLES` pixels), and stays
    where none of that flow is reliable (it left the frame)."""
    backend = DisFlow()
    a, b = axes
    stride = max(1, math.ceil(math.sqrt(math.pi * a * b / MEDIAN_SAMPLES)))
    oy, ox = np.mgrid[-math.ceil(b) : math.ceil(b) + 1 : stride, -math.ceil(a) : math.ceil(a) + 1 : stride]
    centres = [np.asarray(starts, np.float64).copy()]
    previous: np.ndarray | None = None
    for luma in lumas:
        if previous is not None:
            h, w = luma.shape
            field = backend.compute(previous, luma)
            now = centres[-1].copy()
            for i, (cx, cy) in enumerate(centres[-1]):
                px, py = np.round(cx + ox).astype(int), np.round(cy + oy).astype(int)
                use = ((px - cx) / a) ** 2 + ((py - cy) / b) ** 2 < 1.0
                use &= (px >= 0) & (px < w) & (py >= 0) & (py < h)
                px, py = px[use], py[use]
                ok = field.reliable[py, px]
                if ok.any():
                    now[i] += np.median(field.flow[py[ok], px[ok]], axis=0)
            centres.append(now)
        previous = luma
    return np.stack(centres)


@dataclass(frozen=True)
class Planting:
    """One planted failure, exactly: ``kind`` at ``level`` (amplitude ``amplitude`` in the kind's
    unit), drawn from ``seed``, on frames of ``size`` (w, h) px, ``num_frames`` long; ``region``
    (None: the whole frame) and the kind's ``params`` (the random draws, normalisers). From these
    alone :meth:`displacement` gives the displacement of any frame (:mod:`.fields` for the formulas)."""

    kind: str
    level: str
    amplitude: float
    seed: int
    size: tuple[int, int]
    num_frames: int
    region: Region | None
    params: dict[str, Any] = field(default_factory=dict)
    shape: PlantShape = SHAPE

    # --- the field -------------------------------------------------------------------------------

    def gain(self, t: int) -> float:
        """``g(t)`` of the kind (:func:`ramp`)."""
        return ramp(self.kind, t, self.num_frames, int(self.params.get("period", self.shape.breathing_period)))

    def frames_affected(self) -> list[int]:
        """The frames the failure changes (those where ``A g(t)`` is not 0)."""
        return [t for t in range(self.num_frames) if self.amplitude * self.gain(t) != 0.0]

    def _unit(self, t: int, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """The displacement at ``A g(t) = 1``, (..., 2), at the points (x, y)."""
        p = self.params
        x = np.asarray(x, np.float64)
        y = np.asarray(y, np.float64)
        if self.kind == "breathing":
            w, h = self.size
            phi = plane_wave_field(np.array(p["freqs"]), np.array(p["phases"]), np.array(p["amps"]), x / w, y / h)
            return phi / p["norm"]
        if self.kind == "redraw":
            return np.zeros((*x.shape, 2))
        assert self.region is not None
        weight = self.region.weight(t, x, y)[..., None]
        if self.kind == "slide":
            return weight * np.asarray(p["direction"], np.float64)
        u, v = self.region.normalised(t, x, y)
        return weight * _morph_phi(p, u, v) / p["norm"]

    def displacement_at(self, t: int, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """``d_t`` at the points (x, y) (arrays of one shape), (..., 2) px."""
        scale = self.amplitude * self.gain(t) if self.plant.displaces else 0.0
        return scale * self._unit(t, x, y)

    def displacement(self, t: int) -> np.ndarray:
        """``d_t`` on the frame's pixel grid: (h, w, 2) float64 px, ``(dx, dy)``."""
        w, h = self.size
        gy, gx = np.mgrid[0:h, 0:w].astype(np.float64)
        return self.displacement_at(t, gx, gy)

    def blend_at(self, t: int, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """``redraw``: the weight of the donor content at the points (x, y) (0 for other kinds)."""
        if self.kind != "redraw" or self.region is None:
            return np.zeros(np.shape(x))
        return self.amplitude * self.gain(t) * self.region.weight(t, x, y)

    def mask(self, t: int) -> np.ndarray:
        """(h, w) bool: the pixels the failure may change at frame ``t`` (the region; the whole
        frame for breathing)."""
        w, h = self.size
        if self.region is None:
            return np.ones((h, w), bool)
        gy, gx = np.mgrid[0:h, 0:w].astype(np.float64)
        return self.region.weight(t, gx, gy) > 0

    @property
    def plant(self) -> PlantKind:
        """The kind's entry of :data:`~.kinds.PLANT_KINDS`."""
        return PLANT_KINDS[self.kind]

    def source_points(self, t: int, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The clean points whose content lands on (x, y) in the planted frame ``t``: the solution
        ``p`` of ``p + d_t(p) = (x, y)`` by fixed-point iteration."""
        px, py = np.asarray(x, np.float64), np.asarray(y, np.float64)
        for _ in range(self.shape.inverse_max_iterations):
            d = self.displacement_at(t, px, py)
            nx, ny = x - d[..., 0], y - d[..., 1]
            moved = max(float(np.abs(nx - px).max(initial=0.0)), float(np.abs(ny - py).max(initial=0.0)))
            px, py = nx, ny
            if moved < self.shape.inverse_tolerance_px:
                break
        return px, py

    def max_stretch(self) -> float:
        """The largest partial derivative of ``d_t`` over the frame and the clip, at the full amplitude
        (central differences, 0.25 px, on the pixel grid of the region's first frame)."""
        if not self.plant.displaces:
            return 0.0
        w, h = self.size
        x0, y0, x1, y1 = (0, 0, w, h) if self.region is None else self.region.box(0, w, h)
        gy, gx = np.mgrid[y0:y1, x0:x1].astype(np.float64)
        e = 0.25
        ddx = (self._unit(0, gx + e, gy) - self._unit(0, gx - e, gy)) / (2 * e)
        ddy = (self._unit(0, gx, gy + e) - self._unit(0, gx, gy - e)) / (2 * e)
        peak = max(abs(self.gain(t)) for t in range(self.num_frames))
        return self.amplitude * peak * float(max(np.abs(ddx).max(initial=0.0), np.abs(ddy).max(initial=0.0)))

    # --- applying it ----------------------------------------------------------------------------

    def apply(self, t: int, planes: Sequence[np.ndarray], subsampling: Sequence[tuple[int, int]]) -> list[np.ndarray]:
        """The planes of planted frame ``t`` from those of the clean one (uint8 each; plane ``i``
        covers the frame at ``subsampling[i]`` = (sx, sy) frame pixels per sample, centres aligned).
        Pixels the failure leaves alone keep their values exactly."""
        if t not in self.frames_affected():
            return [p.copy() for p in planes]
        return [self._apply_plane(t, plane, sx, sy) for plane, (sx, sy) in zip(planes, subsampling, strict=True)]

    def _apply_plane(self, t: int, plane: np.ndarray, sx: int, sy: int) -> np.ndarray:
        h, w = plane.shape
        W, H = self.size
        if self.region is None:
            x0, y0, x1, y1 = 0, 0, w, h
        else:
            bx0, by0, bx1, by1 = self.region.box(t, W, H)
            x0, y0 = max(0, bx0 // sx - 1), max(0, by0 // sy - 1)
            x1, y1 = min(w, -(-bx1 // sx) + 1), min(h, -(-by1 // sy) + 1)
        out = plane.copy()
        if x1 <= x0 or y1 <= y0:
            return out
        j, i = np.meshgrid(np.arange(x0, x1, dtype=np.float64), np.arange(y0, y1, dtype=np.float64))
        fx, fy = (j + 0.5) * sx - 0.5, (i + 0.5) * sy - 0.5  # sample centres in frame pixels
        if self.plant.displaces:
            px, py = self.source_points(t, fx, fy)
            out[y0:y1, x0:x1] = _sample(plane, (px + 0.5) / sx - 0.5, (py + 0.5) / sy - 0.5)
            return out
        dx, dy = self.params["donor_offset"]
        donor = _sample(plane, (fx + dx + 0.5) / sx - 0.5, (fy + dy + 0.5) / sy - 0.5).astype(np.float64)
        clean = plane[y0:y1, x0:x1].astype(np.float64)
        blended = clean + self.blend_at(t, fx, fy) * (donor - clean)
        out[y0:y1, x0:x1] = np.clip(np.rint(blended), 0, 255).astype(np.uint8)
        return out

    # --- the ground truth -----------------------------------------------------------------------

    def to_dict(self) -> dict[str, Any]:
        """JSON-able: everything :meth:`from_dict` needs to give the same fields (the planting part of
        a planted clip's ``.gt.json``)."""
        spec = self.plant
        w, h = self.size
        peaks = []
        for t in range(self.num_frames):
            x0, y0, x1, y1 = (0, 0, w, h) if self.region is None else self.region.box(t, w, h)
            gy, gx = np.mgrid[y0:y1, x0:x1].astype(np.float64)
            d = self.displacement_at(t, gx, gy)
            peaks.append(round(float(np.linalg.norm(d, axis=-1).max(initial=0.0)), 4))
        return {
            "kind": self.kind,
            "severity": self.level,
            "amplitude": float(self.amplitude),
            "unit": spec.unit,
            "seed": int(self.seed),
            "size": [int(w), int(h)],
            "num_frames": int(self.num_frames),
            "frames_affected": self.frames_affected(),
            "region": {"shape": "frame"} if self.region is None else self.region.to_dict(),
            "displacement": {
                "convention": CONVENTION,
                "formula": FORMULAS[self.kind],
                "ramp": spec.ramp,
                "gain": [float(self.gain(t)) for t in range(self.num_frames)],
                "params": _jsonable(self.params),
                "peak_px": peaks,
                "recompute": "geocon_core.plant.planted_displacement(ground_truth, t)",
            },
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> Planting:
        """The planting a ground truth (:meth:`to_dict`; a planted clip's ``.gt.json``) describes."""
        region = None if d["region"].get("shape") == "frame" else Region.from_dict(d["region"])
        w, h = d["size"]
        return cls(
            kind=str(d["kind"]),
            level=str(d["severity"]),
            amplitude=float(d["amplitude"]),
            seed=int(d["seed"]),
            size=(int(w), int(h)),
            num_frames=int(d["num_frames"]),
            region=region,
            params=dict(d["displacement"]["params"]),
        )


def _morph_phi(p: Mapping[str, Any], u: np.ndarray, v: np.ndarray) -> np.ndarray:
    phi = plane_wave_field(np.array(p["freqs"]), np.array(p["phases"]), np.array(p["amps"]), u, v)
    phi[..., 1] += p["droop"] * (1.0 + v) / 2.0
    return phi


def _sample(plane: np.ndarray, mx: np.ndarray, my: np.ndarray) -> np.ndarray:
    """``plane`` sampled bicubically at (mx, my) (plane pixels; mirrored beyond its edges)."""
    return cv2.remap(
        plane, mx.astype(np.float32), my.astype(np.float32), cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT_101
    )


def _jsonable(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def plan_planting(
    kind: str,
    level: str,
    seed: int,
    lumas: Iterator[np.ndarray],
    shape: PlantShape = SHAPE,
) -> Planting:
    """The planting of ``kind`` at ``level`` drawn from ``seed`` for the clip whose luma planes
    ``lumas`` yields ((h, w) uint8, every frame in order: the region is chosen on the first and
    followed through the rest). Raises ValueError for an unknown kind or level, and when the clip
    is too small for the level (the warp would fold: :attr:`PlantShape.max_stretch`)."""
    amplitude = amplitude_of(kind, level)
    first = next(lumas, None)
    if first is None:
        raise ValueError("no frame to plant into")
    h, w = first.shape
    rng = np.random.default_rng([seed, RNG_STREAM, list(PLANT_KINDS).index(kind)])
    params: dict[str, Any] = {}
    region: Region | None = None
    frames = 1
    if kind == "breathing":
        freqs, phases, amps = plane_waves(rng, shape.breathing_cycles)
        gy, gx = np.mgrid[0:h, 0:w].astype(np.float64)
        norm = float(np.linalg.norm(plane_wave_field(freqs, phases, amps, gx / w, gy / h), axis=2).max())
        params = {"freqs": freqs, "phases": phases, "amps": amps, "norm": norm, "period": shape.breathing_period}
        frames += sum(1 for _ in lumas)
    else:
        axes = region_axes(w, h, shape)
        tracks = track_centres(_chain([first], lumas), region_candidates(w, h, shape), axes, shape)
        chosen = choose_region(first, tracks, rng, shape)
        centre = (float(tracks[0, chosen, 0]), float(tracks[0, chosen, 1]))
        if kind == "slide":
            angle = rng.uniform(-1.0, 1.0) * math.radians(shape.slide_max_angle_deg) + rng.choice([0.0, math.pi])
            params = {"direction": [math.cos(angle), math.sin(angle)]}
        elif kind == "morph":
            freqs, phases, amps = plane_waves(rng, shape.morph_cycles)
            params = {"freqs": freqs, "phases": phases, "amps": amps, "droop": shape.morph_droop}
            n = np.linspace(-1.0, 1.0, shape.normalise_grid)
            u, v = np.meshgrid(n, n)
            length = np.linalg.norm(_morph_phi(params, u, v), axis=2) * taper_weight(np.hypot(u, v), shape.taper_start)
            params["norm"] = float(length.max())
        else:  # redraw
            params = {"donor_offset": list(choose_donor(first, centre, axes, rng, shape))}
        frames = len(tracks)
        region = Region(axes, tuple((float(x), float(y)) for x, y in tracks[:, chosen]), shape.taper_start)
    planting = Planting(kind, level, amplitude, int(seed), (w, h), frames, region, _jsonable(params), shape)
    stretch = planting.max_stretch()
    if stretch > shape.max_stretch:
        raise ValueError(
            f"a {level} {kind} ({amplitude:g} {planting.plant.unit}) would fold a {w}x{h} frame "
            f"over itself (stretch {stretch:.2f}, at most {shape.max_stretch:g}); give a lower severity or a "
            "larger clip"
        )
    return planting


def _chain(*parts: Iterable[np.ndarray]) -> Iterator[np.ndarray]:
    for part in parts:
        yield from part
