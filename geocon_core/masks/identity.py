"""Identity cues of the built-in segmentation (:class:`~geocon_core.masks.MotionSegmenter`):
the colour histogram of a region, the merging of the parts of one mover within a frame, and
the position a lost track is expected at after a gap."""

from __future__ import annotations

import cv2
import numpy as np

from ..config import MotionConfig

__all__ = ["colour_histogram", "histogram_distance", "merge_parts", "centroid"]

_BINS = 8


def colour_histogram(rgb: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Normalised RGB histogram (``8**3`` float32 bins summing to 1) of the pixels of ``rgb``
    ((h, w, 3) uint8) under ``mask`` ((h, w) bool); uniform when the mask is empty."""
    hist = cv2.calcHist([rgb], [0, 1, 2], mask.astype(np.uint8), [_BINS] * 3, [0, 256] * 3).ravel()
    total = float(hist.sum())
    if total <= 0:
        return np.full(_BINS**3, 1.0 / _BINS**3, np.float32)
    return (hist / total).astype(np.float32)


def histogram_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Bhattacharyya distance of two normalised histograms: 0 for equal ones, 1 for disjoint
    (OpenCV's, as the reader's cut detection uses it)."""
    return float(cv2.compareHist(a.astype(np.float32), b.astype(np.float32), cv2.HISTCMP_BHATTACHARYYA))


def centroid(mask: np.ndarray) -> np.ndarray:
    """Centre (x, y) of a non-empty mask, float64 (2,)."""
    ys, xs = np.nonzero(mask)
    return np.array([xs.mean(), ys.mean()], np.float64)


def merge_parts(masks: list[np.ndarray], vels: list[np.ndarray], config: MotionConfig, s: float) -> list[list[int]]:
    """Groups (lists of indices into ``masks``) of regions that belong to one mover: regions
    whose gap is at most ``merge_px`` and whose velocities ((2,) reduced px per frame) differ
    by at most ``merge_speed_px`` plus ``merge_speed_share`` of the faster one. ``s`` is the
    reduced / working scale. Groups are ordered by their first member; members ascending."""
    n = len(masks)
    parent = list(range(n))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    r = max(1, round(config.merge_px * s))
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    grown = [cv2.dilate(m.astype(np.uint8), kernel) > 0 for m in masks]
    for i in range(n):
        for j in range(i + 1, n):
            speed = max(float(np.hypot(*vels[i])), float(np.hypot(*vels[j])))
            tol = config.merge_speed_px * s + config.merge_speed_share * speed
            if float(np.hypot(*(vels[i] - vels[j]))) > tol:
                continue
            if np.any(grown[i] & masks[j]):
                parent[root(j)] = root(i)
    groups: dict[int, list[int]] = {}
    for i in range(n):
        groups.setdefault(root(i), []).append(i)
    return sorted(groups.values(), key=lambda g: g[0])
