"""Correspondences between frames: SIFT (default), ORB and KLT behind one small interface.

Features are extracted once per frame and scale (:meth:`Matcher.extract`) and reused by every
pair that shares the frame (:meth:`Matcher.match`). Coordinates are pixels of the scaled
working frame (pixel centres at integers).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Protocol

import cv2
import numpy as np

__all__ = [
    "FeatureSet",
    "Matcher",
    "SiftMatcher",
    "OrbMatcher",
    "KltMatcher",
    "MATCHERS",
    "make_matcher",
    "scaled_inputs",
    "mutual_ratio_matches",
    "gross_mismatches",
]

BORDER_PX = 4
"""Features closer than this to the edge of the usable mask are dropped (their descriptors
would see padding or the masked-out region)."""


@dataclass(frozen=True, eq=False)
class FeatureSet:
    """Features of one frame at one scale.

    xy: (N, 2) float32 pixel coordinates at this scale.
    desc: (N, D) descriptors (float32 for SIFT, uint8 for ORB) or None (KLT).
    image: (h, w) uint8 grey image at this scale (kept by KLT only, else None).
    mask: (h, w) bool usable pixels at this scale (content minus masked objects, eroded).
    """

    frame: int
    scale: float
    xy: np.ndarray
    desc: np.ndarray | None
    image: np.ndarray | None
    mask: np.ndarray

    def __len__(self) -> int:
        return int(self.xy.shape[0])


class Matcher(Protocol):
    """A feature extractor with its matching rule."""

    name: str

    def extract(self, gray: np.ndarray, mask: np.ndarray, frame: int, scale: float) -> FeatureSet:
        """Features of a grey image (h, w) uint8 inside ``mask`` (h, w) bool."""
        ...

    def match(self, a: FeatureSet, b: FeatureSet) -> tuple[np.ndarray, np.ndarray]:
        """Correspondences (x_a, x_b), each (M, 2) float64, with x_a in ``a.mask`` and x_b in
        ``b.mask``."""
        ...


def scaled_inputs(gray: np.ndarray, mask: np.ndarray, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """The grey image and usable mask at ``scale`` (area-averaged image, nearest mask eroded by
    :data:`BORDER_PX`)."""
    if scale == 1.0:
        g, m = gray, mask
    else:
        h, w = gray.shape
        size = (max(1, round(w * scale)), max(1, round(h * scale)))
        g = cv2.resize(gray, size, interpolation=cv2.INTER_AREA)
        m = cv2.resize(mask.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST)
    kernel = np.ones((2 * BORDER_PX + 1, 2 * BORDER_PX + 1), np.uint8)
    m = cv2.erode(np.asarray(m, np.uint8), kernel, borderType=cv2.BORDER_CONSTANT, borderValue=0) > 0
    return g, m


def _inside(mask: np.ndarray, xy: np.ndarray) -> np.ndarray:
    h, w = mask.shape
    xi, yi = np.round(xy[:, 0]).astype(int), np.round(xy[:, 1]).astype(int)
    ok = (xi >= 0) & (xi < w) & (yi >= 0) & (yi < h)
    ok[ok] = mask[yi[ok], xi[ok]]
    return ok


def mutual_ratio_matches(dist2: np.ndarray, ratio: float) -> tuple[np.ndarray, np.ndarray]:
    """Indices (i, j) of pairs that are mutual nearest neighbours in a matrix of *squared*
    distances (Na, Nb) and pass Lowe's ratio test in the a -> b direction
    (``d_best < ratio * d_second``, i.e. ``d2_best < ratio^2 * d2_second``). The matrix is
    modified in place."""
    na, nb = dist2.shape
    if na == 0 or nb < 2:
        return np.zeros(0, int), np.zeros(0, int)
    i = np.arange(na)
    back = np.argmin(dist2, axis=0)
    best = np.argmin(dist2, axis=1)
    d_best = dist2[i, best].copy()
    dist2[i, best] = np.inf
    d_second = np.min(dist2, axis=1)
    keep = (back[best] == i) & (d_best < (ratio * ratio) * d_second)
    return i[keep], best[keep]


def gross_mismatches(x1: np.ndarray, x2: np.ndarray, max_px: float, neighbours: int = 8) -> np.ndarray:
    """Mask (N,) of the matches that disagree with their neighbourhood in both frames: the match's
    displacement ``x2 - x1`` differs by more than ``max_px`` from the median displacement of its
    ``neighbours`` nearest matches around ``x1`` in the first frame *and* from that of its
    nearest matches around ``x2`` in the second.

    Such a match is a matcher's error (repeated structure: one window matched to the next), not
    evidence about the scene: a surface that bends, slides or breathes moves its matches
    together, so they keep agreeing with their neighbours. With fewer than ``neighbours + 2``
    matches nothing is flagged."""
    n = len(x1)
    out = np.zeros(n, bool)
    if n < neighbours + 2 or not max_px > 0:
        return out
    from scipy.spatial import cKDTree

    x1 = np.asarray(x1, np.float64)
    x2 = np.asarray(x2, np.float64)
    d = x2 - x1
    out[:] = True
    for pts in (x1, x2):
        _, idx = cKDTree(pts).query(pts, neighbours + 1)
        local = np.median(d[idx[:, 1:]], axis=1)
        out &= np.linalg.norm(d - local, axis=1) > max_px
    return out


class _DescriptorMatcher:
    name = "descriptor"

    def __init__(self, *, max_features: int = 2000, ratio: float = 0.8) -> None:
        self.max_features = max_features
        self.ratio = ratio

    def _detector(self, n: int):  # pragma: no cover - overridden
        raise NotImplementedError

    def extract(self, gray: np.ndarray, mask: np.ndarray, frame: int, scale: float) -> FeatureSet:
        n = max(64, round(self.max_features * scale))
        kps, desc = self._detector(n).detectAndCompute(gray, mask.astype(np.uint8) * 255)
        xy = np.array([k.pt for k in kps], np.float32).reshape(-1, 2)
        if desc is None or len(kps) == 0:
            desc = np.zeros((0, 0), np.float32)
        return FeatureSet(frame=frame, scale=scale, xy=xy, desc=desc, image=None, mask=mask)

    def _squared_distances(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:  # pragma: no cover - overridden
        raise NotImplementedError

    def match(self, a: FeatureSet, b: FeatureSet) -> tuple[np.ndarray, np.ndarray]:
        if len(a) < 2 or len(b) < 2:
            return np.zeros((0, 2)), np.zeros((0, 2))
        assert a.desc is not None and b.desc is not None, "descriptor features carry descriptors"
        i, j = mutual_ratio_matches(self._squared_distances(a.desc, b.desc), self.ratio)
        return a.xy[i].astype(np.float64), b.xy[j].astype(np.float64)


class SiftMatcher(_DescriptorMatcher):
    """SIFT keypoints (the ``max_features * scale`` strongest per frame), L2 distances, Lowe's
    ratio test and a mutual nearest-neighbour check."""

    name = "sift"

    def _detector(self, n: int):
        return cv2.SIFT_create(nfeatures=n)  # type: ignore[attr-defined]  # in cv2, missing from its stubs

    def _squared_distances(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        a, b = a.astype(np.float32), b.astype(np.float32)
        d2 = a @ b.T
        d2 *= -2.0
        d2 += (a * a).sum(1)[:, None]
        d2 += (b * b).sum(1)[None, :]
        return d2


class OrbMatcher(_DescriptorMatcher):
    """ORB keypoints and binary descriptors, Hamming distances, ratio test and mutual check.
    Several times faster than SIFT, less precise."""

    name = "orb"

    def _detector(self, n: int):
        return cv2.ORB_create(nfeatures=n)  # type: ignore[attr-defined]  # in cv2, missing from its stubs

    def _squared_distances(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        bits_a = np.unpackbits(a, axis=1).astype(np.float32)
        bits_b = np.unpackbits(b, axis=1).astype(np.float32)
        # Hamming distance = |a| + |b| - 2 a.b on bit vectors; squared to share the ratio rule
        ham = bits_a.sum(1)[:, None] + bits_b.sum(1)[None, :] - 2.0 * (bits_a @ bits_b.T)
        return ham * ham


def _pyramid_lk(prev: np.ndarray, nxt: np.ndarray, pts: np.ndarray) -> tuple[Any, Any]:
    """Pyramidal Lucas-Kanade tracks of ``pts`` (N, 1, 2) from ``prev`` to ``nxt``: (points, status)."""
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01)
    # nextPts=None (let OpenCV allocate) is valid, but missing from OpenCV's type stubs
    p, st, _ = cv2.calcOpticalFlowPyrLK(  # type: ignore[call-overload]
        prev, nxt, pts, None, winSize=(21, 21), maxLevel=4, criteria=criteria
    )
    return p, st


class KltMatcher:
    """Shi-Tomasi corners tracked with pyramidal Lucas-Kanade; a track is kept when tracking
    back lands within ``fb_px`` of its start (forward-backward check)."""

    name = "klt"

    def __init__(self, *, max_features: int = 2000, fb_px: float = 0.5, **_: object) -> None:
        self.max_features = max_features
        self.fb_px = fb_px

    def extract(self, gray: np.ndarray, mask: np.ndarray, frame: int, scale: float) -> FeatureSet:
        n = max(64, round(self.max_features * scale))
        pts = cv2.goodFeaturesToTrack(gray, n, 0.005, 5, mask=mask.astype(np.uint8) * 255, blockSize=7)
        xy = np.zeros((0, 2), np.float32) if pts is None else pts.reshape(-1, 2).astype(np.float32)
        return FeatureSet(frame=frame, scale=scale, xy=xy, desc=None, image=gray, mask=mask)

    def match(self, a: FeatureSet, b: FeatureSet) -> tuple[np.ndarray, np.ndarray]:
        if len(a) == 0:
            return np.zeros((0, 2)), np.zeros((0, 2))
        assert a.image is not None and b.image is not None, "KLT features keep their image"
        p0 = a.xy.reshape(-1, 1, 2)
        p1, st1 = _pyramid_lk(a.image, b.image, p0)
        p0b, st2 = _pyramid_lk(b.image, a.image, p1)
        p1, p0b = p1.reshape(-1, 2), p0b.reshape(-1, 2)
        ok = (st1.ravel() == 1) & (st2.ravel() == 1) & (np.linalg.norm(p0b - a.xy, axis=1) <= self.fb_px)
        ok &= _inside(b.mask, p1)
        return a.xy[ok].astype(np.float64), p1[ok].astype(np.float64)


MATCHERS: dict[str, Callable[..., Matcher]] = {"sift": SiftMatcher, "orb": OrbMatcher, "klt": KltMatcher}


def make_matcher(name: str, *, max_features: int = 2000, ratio: float = 0.8) -> Matcher:
    """Build a matcher by name; an unknown name lists the valid ones."""
    try:
        factory = MATCHERS[name]
    except KeyError:
        raise ValueError(f"unknown matcher {name!r}; valid: {', '.join(MATCHERS)}") from None
    return factory(max_features=max_features, ratio=ratio)
