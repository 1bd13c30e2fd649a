"""What the motion does not explain: dense-flow readings of a clip's appearance.

A real scene's pixels can be followed from frame to frame: the forward flow of a pair and the
backward flow agree (forward-backward test) except where a surface is hidden or revealed, which
happens along motion boundaries; and a pixel followed by the flow still looks like itself. In a
generated clip a melting body, a face turning into another face or a pattern re-forming breaks
both: the flow fails inside surfaces, and where it holds the texture it lands on is not the one
it left. Each reading is a number per clip, the larger the more broken:

- ``flow_failure``: over the clip's pairs ``gap`` frames apart, the 90th percentile of the share of
  the pixels whose flow fails the forward-backward test (pixels whose flow leaves the frame are
  not counted);
- ``interior_failure``: the mean share of failing pixels away from motion boundaries (where the
  flow's spatial gradient is steep, and a band around them): failures there are occlusions, not
  damage;
- ``unexplained_appearance``: over pairs of neighbouring frames, the mean census distance (the
  share of the 24 neighbour comparisons of a 5x5 window that change) between a pixel and where
  the consistent flow takes it, over textured pixels away from motion boundaries;
- ``mover_share``: the mean share of the pixels whose consistent flow departs from one homography
  fitted to the whole frame's flow: how much of the frame moves on its own.

Where each reading fires is kept as a map on the readings' canvas (:class:`ReadingMaps`): per
pixel, the share of the pairs in which it fails the flow test inside a surface, moves on its own,
or changes its census, so that a viewer can show the picture beside the number.

The clip is read on a small canvas (``SignalsConfig.long_side``) at up to ``max_pairs`` pairs spread
evenly over it, so the cost does not grow with clip length. Everything is seeded: the same frames
give the same numbers.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import cv2
import numpy as np

from ..config import FlowConfig, SignalsConfig
from ..flow import FlowField, make_flow_backend

__all__ = [
    "MAP_NAMES",
    "AppearanceReading",
    "PairReading",
    "ReadingMaps",
    "appearance_reading",
    "content_gray",
    "plan_pairs",
    "reduce_gray",
    "summarize",
]

MAP_NAMES: tuple[str, ...] = ("failure", "movers", "unexplained")
"""The maps of :class:`ReadingMaps`, in the order kept."""


@dataclass(frozen=True)
class PairReading:
    """One pair's shares: frames ``t0`` and ``t1``; ``failure``: pixels failing the forward-backward
    test (of those whose flow stays in the frame); ``interior``: failing pixels away from motion
    boundaries; ``movers``: pixels moving against the frame's homography (None for a pair of
    neighbouring frames, where ``census`` is read instead)."""

    t0: int
    t1: int
    failure: float | None = None
    interior: float | None = None
    movers: float | None = None
    census: float | None = None


@dataclass(frozen=True, eq=False)
class ReadingMaps:
    """Where the appearance readings fire, on the readings' canvas of the clip's content box
    (uint8 images, 255 = every pair): ``failure``, per pixel, the share of the far pairs in which
    its flow fails the forward-backward test away from motion boundaries (``interior_failure``);
    ``movers``, the share in which it moves against the frame's homography (``mover_share``);
    ``unexplained``, the mean census change where its neighbouring-frame flow was followed
    (``unexplained_appearance``; 0 where it never was). Pixels are those of each pair's first
    frame: on a still camera they stay put, on a moving one the map is the clip's sum."""

    failure: np.ndarray
    movers: np.ndarray
    unexplained: np.ndarray

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, ReadingMaps):
            return NotImplemented
        return all(np.array_equal(getattr(self, n), getattr(other, n)) for n in MAP_NAMES)

    __hash__ = None  # type: ignore[assignment]

    def shares(self, name: str) -> np.ndarray:
        """The map ``name`` (:data:`MAP_NAMES`) as shares 0..1 (float32)."""
        return getattr(self, name).astype(np.float32) / np.float32(255.0)


class _MapSum:
    """Per-pixel sums of a share and of how often it was read."""

    def __init__(self) -> None:
        self.hits: np.ndarray | None = None
        self.seen: np.ndarray | None = None

    def add(self, hits: np.ndarray, seen: np.ndarray) -> None:
        if self.hits is None or self.seen is None:
            self.hits, self.seen = np.zeros(hits.shape, np.float32), np.zeros(hits.shape, np.float32)
        self.hits += hits
        self.seen += seen

    def image(self, shape: tuple[int, int]) -> np.ndarray:
        if self.hits is None or self.seen is None:
            return np.zeros(shape, np.uint8)
        share = np.divide(self.hits, self.seen, out=np.zeros_like(self.hits), where=self.seen > 0)
        return np.round(np.clip(share, 0.0, 1.0) * 255.0).astype(np.uint8)


@dataclass(frozen=True)
class AppearanceReading:
    """The clip's appearance readings (module docstring); None where no pair could be read.
    ``maps``: where they fire (None for readings stored without them)."""

    flow_failure: float | None
    interior_failure: float | None
    unexplained_appearance: float | None
    mover_share: float | None
    pairs: tuple[PairReading, ...] = ()
    maps: ReadingMaps | None = None

    def to_dict(self) -> dict[str, float | None]:
        return {
            "flow_failure": self.flow_failure,
            "interior_failure": self.interior_failure,
            "unexplained_appearance": self.unexplained_appearance,
            "mover_share": self.mover_share,
        }


def plan_pairs(num_frames: int, cfg: SignalsConfig) -> tuple[list[tuple[int, int]], list[tuple[int, int]]]:
    """The pairs read: (pairs ``cfg.gap`` apart, pairs of neighbouring frames), at most
    ``cfg.max_pairs`` each, their first frames spread evenly over the clip."""

    def spread(gap: int) -> list[tuple[int, int]]:
        last = num_frames - 1 - gap
        if last < 0:
            return []
        count = min(cfg.max_pairs, last + 1)
        starts = np.unique(np.round(np.linspace(0, last, count)).astype(int))
        return [(int(t), int(t) + gap) for t in starts]

    gap = min(cfg.gap, max(1, num_frames - 1))
    return spread(gap), spread(1)


def reduce_gray(gray: np.ndarray, cfg: SignalsConfig) -> np.ndarray:
    """A grey frame on the readings' canvas: its long side at most ``cfg.long_side`` (area
    interpolation), sides rounded to even."""
    h, w = gray.shape[:2]
    s = min(1.0, cfg.long_side / max(h, w))
    if s >= 1.0:
        return np.ascontiguousarray(gray)
    size = (max(16, round(w * s) // 2 * 2), max(16, round(h * s) // 2 * 2))
    return cv2.resize(gray, size, interpolation=cv2.INTER_AREA)


def content_gray(gray: np.ndarray, content_box: tuple[int, int, int, int], cfg: SignalsConfig) -> np.ndarray:
    """The clip's content box (x0, y0, x1, y1) of a grey working frame on the readings' canvas
    (:func:`reduce_gray`): what the readings read, while scoring and when read again."""
    x0, y0, x1, y1 = content_box
    return reduce_gray(gray[y0:y1, x0:x1], cfg)


def _boundaries(flow: np.ndarray, cfg: SignalsConfig) -> np.ndarray:
    """Pixels on or near a motion boundary: the flow's spatial gradient (px per px) above
    ``cfg.boundary_gradient``, widened by ``cfg.boundary_px``."""
    grad = np.zeros(flow.shape[:2], np.float32)
    for c in range(2):
        comp = np.ascontiguousarray(flow[..., c])
        gx = cv2.Sobel(comp, cv2.CV_32F, 1, 0, ksize=3).astype(np.float32) / np.float32(8.0)
        gy = cv2.Sobel(comp, cv2.CV_32F, 0, 1, ksize=3).astype(np.float32) / np.float32(8.0)
        grad += gx * gx + gy * gy
    edge = (np.sqrt(grad) > cfg.boundary_gradient).astype(np.uint8)
    k = 2 * cfg.boundary_px + 1
    return cv2.dilate(edge, np.ones((k, k), np.uint8)) > 0


def _textured(gray: np.ndarray, cfg: SignalsConfig) -> np.ndarray:
    """Pixels whose local mean gradient (5x5) is at least ``cfg.texture_gradient`` grey levels per px."""
    g = gray.astype(np.float32)
    gx = (cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3) / 4.0).astype(np.float32)
    gy = (cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3) / 4.0).astype(np.float32)
    return cv2.blur(cv2.magnitude(gx, gy), (5, 5)) >= cfg.texture_gradient


def _census(gray: np.ndarray, radius: int) -> np.ndarray:
    """The census transform: for each pixel, whether each neighbour of its window is brighter
    ((k, h, w) bool, k = (2r+1)^2 - 1)."""
    g = gray.astype(np.int16)
    h, w = g.shape
    p = np.pad(g, radius, mode="edge")
    bits = [
        p[radius + dy : radius + dy + h, radius + dx : radius + dx + w] > g
        for dy in range(-radius, radius + 1)
        for dx in range(-radius, radius + 1)
        if dx or dy
    ]
    return np.stack(bits)


def _grid(shape: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates (x, y) of a canvas of ``shape`` (float32)."""
    h, w = shape[:2]
    gx, gy = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    return gx, gy


def _warp(image: np.ndarray, flow: np.ndarray, grid: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """``image`` sampled where ``flow`` takes each pixel (bilinear, 0 outside)."""
    gx, gy = grid
    return cv2.remap(image, gx + flow[..., 0], gy + flow[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)


def _movers(
    field: FlowField, inside: np.ndarray, cfg: SignalsConfig, seed: int, grid: tuple[np.ndarray, np.ndarray]
) -> np.ndarray | None:
    """The in-frame pixels whose flow departs from the homography fitted (RANSAC, seeded) to the
    consistent flow of a grid of pixels by more than ``cfg.mover_px`` (None when no homography
    can be fitted)."""
    flow = field.flow
    h, w = flow.shape[:2]
    ys, xs = np.mgrid[4:h:8, 4:w:8]
    pick = field.reliable[ys, xs]
    if np.count_nonzero(pick) < 12:
        return None
    src = np.stack([xs[pick], ys[pick]], 1).astype(np.float32)
    dst = src + flow[ys[pick], xs[pick]]
    cv2.setRNGSeed(seed)
    H, _ = cv2.findHomography(src, dst, cv2.RANSAC, cfg.mover_px, maxIters=1000, confidence=0.995)
    if H is None:
        return None
    gx, gy = grid
    pts = np.stack([gx, gy, np.ones_like(gx)], -1) @ H.T
    z = pts[..., 2]
    ok = np.abs(z) > 1e-9
    pred = np.where(ok[..., None], pts[..., :2] / np.where(ok, z, 1.0)[..., None], np.inf)
    off = np.linalg.norm(flow + np.stack([gx, gy], -1) - pred, axis=2)
    return (off > cfg.mover_px) & inside


def appearance_reading(frames: dict[int, np.ndarray], num_frames: int, cfg: SignalsConfig) -> AppearanceReading:
    """The readings of a clip of ``num_frames`` frames from ``frames`` (index -> grey frame on the
    readings' canvas, :func:`reduce_gray`), which must hold every frame of :func:`plan_pairs`."""
    flow = make_flow_backend("dis", FlowConfig(preset=cfg.flow_preset, fb_abs=cfg.fb_abs, fb_rel=cfg.fb_rel, margin=0))
    far, near = plan_pairs(num_frames, cfg)
    pairs: list[PairReading] = []
    sums = {name: _MapSum() for name in MAP_NAMES}
    shape = next(iter(frames.values())).shape[:2] if frames else (0, 0)
    grid = _grid(shape)
    for t0, t1 in far:
        field = flow.compute(frames[t0], frames[t1])
        inside = np.isfinite(field.fb_error)
        if np.count_nonzero(inside) < 100:
            continue
        failing = inside & ~field.reliable
        away = inside & ~_boundaries(field.flow, cfg)
        sums["failure"].add(failing & away, away)
        moving = _movers(field, inside, cfg, t0 * 7919 + t1, grid)
        if moving is not None:
            sums["movers"].add(moving, inside)
        pairs.append(
            PairReading(
                t0,
                t1,
                failure=float(np.count_nonzero(failing) / np.count_nonzero(inside)),
                interior=float(np.count_nonzero(failing & away) / max(1, int(np.count_nonzero(away)))),
                movers=None if moving is None else float(np.count_nonzero(moving) / np.count_nonzero(inside)),
            )
        )
    for t0, t1 in near:
        field = flow.compute(frames[t0], frames[t1])
        keep = field.reliable & ~_boundaries(field.flow, cfg) & _textured(frames[t0], cfg)
        if np.count_nonzero(keep) < 50:
            continue
        a = _census(frames[t0], cfg.census_radius)
        b = _census(_warp(frames[t1], field.flow, grid), cfg.census_radius)
        changed = (a != b).mean(axis=0)
        sums["unexplained"].add(np.where(keep, changed, 0.0), keep)
        pairs.append(PairReading(t0, t1, census=float(changed[keep].mean())))
    maps = ReadingMaps(**{name: sums[name].image(shape) for name in MAP_NAMES}) if pairs else None
    return summarize(pairs, maps)


def summarize(pairs: Sequence[PairReading], maps: ReadingMaps | None = None) -> AppearanceReading:
    """The clip's readings from its pairs' (module docstring), with ``maps`` where they fire."""

    def values(name: str) -> list[float]:
        return [v for p in pairs if (v := getattr(p, name)) is not None]

    def mean(xs: list[float]) -> float | None:
        return float(np.mean(xs)) if xs else None

    failure = values("failure")
    return AppearanceReading(
        flow_failure=float(np.percentile(failure, 90)) if failure else None,
        interior_failure=mean(values("interior")),
        unexplained_appearance=mean(values("census")),
        mover_share=mean(values("movers")),
        pairs=tuple(pairs),
        maps=maps,
    )
