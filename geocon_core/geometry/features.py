"""Correspondences between frames: SIFT (default), ORB, KLT and KLT tracks behind one small interface.

Features are extracted once per frame and scale (:meth:`Matcher.extract`) and reused by every
pair that shares the frame (:meth:`Matcher.match`). Coordinates are pixels of the scaled
working frame (pixel centres at integers).
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass
from typing import Any, Callable, Collection, Protocol

import cv2
import numpy as np

__all__ = [
    "FeatureSet",
    "Matcher",
    "SiftMatcher",
    "OrbMatcher",
    "KltMatcher",
    "KltTrackMatcher",
    "MATCHERS",
    "make_matcher",
    "scaled_inputs",
    "mutual_ratio_matches",
    "gross_mismatches",
    "good_corners",
    "tracking_canvas",
    "lk_forward_backward",
]

BORDER_PX = 4
"""Features closer than this to the edge of the usable mask are dropped (their descriptors
would see padding or the masked-out region)."""


@dataclass(frozen=True, eq=False)
class FeatureSet:
    """Features of one frame at one scale.

    xy: (N, 2) float32 pixel coordinates at this scale.
    desc: (N, D) descriptors (float32 for SIFT, uint8 for ORB), None (KLT) or the track ids
    (N,) int64 (KLT tracks kept alive across frames).
    image: (h, w) uint8 grey image at this scale (kept by KLT only, else None).
    mask: (h, w) bool usable pixels at this scale (content minus masked objects, eroded).
    anchor: SIFT features of the same frame, for the pairs tracks cannot serve (KLT tracks'
    first and last frame), else None.
    """

    frame: int
    scale: float
    xy: np.ndarray
    desc: np.ndarray | None
    image: np.ndarray | None
    mask: np.ndarray
    anchor: FeatureSet | None = None

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

    def __init__(self, *, max_features: int = 2000, ratio: float = 0.8, **_: object) -> None:
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


class SiftOctaveMatcher(SiftMatcher):
    """SIFT run once per frame, at the largest scale; the features of a coarser scale ``2**-k``
    are the keypoints the full-size pass found in its octaves ``>= k - 1`` (the octaves a pass on
    the downscaled image would also have, OpenCV doubling its input first), their coordinates
    scaled, kept inside that scale's mask, the ``max_features * scale`` strongest. Descriptors are
    reused as they are (SIFT describes a keypoint in its own octave's image)."""

    name = "sift_octaves"

    def extract_scales(self, inputs: dict[float, tuple[np.ndarray, np.ndarray]], frame: int) -> dict[float, FeatureSet]:
        """Features at every scale of ``inputs`` (scale -> (grey, usable mask) at that scale)."""
        top = max(inputs)
        coarse = {s: math.log2(top / s) for s in inputs if s != top}
        if top != 1.0 or any(abs(k - round(k)) > 1e-9 for k in coarse.values()):
            return {s: self.extract(g, m, frame, s) for s, (g, m) in inputs.items()}
        gray, mask = inputs[top]
        sift = cv2.SIFT_create()  # type: ignore[attr-defined]  # in cv2, missing from its stubs
        kps = sift.detect(gray, mask.astype(np.uint8) * 255)
        if len(kps) == 0:
            return {
                s: FeatureSet(frame, s, np.zeros((0, 2), np.float32), np.zeros((0, 0), np.float32), None, m)
                for s, (_, m) in inputs.items()
            }
        xy = np.array([k.pt for k in kps], np.float32).reshape(-1, 2)
        response = np.array([k.response for k in kps], np.float64)
        octave = np.array([k.octave & 255 for k in kps], np.int64)
        octave[octave > 127] -= 256
        order = np.argsort(-response, kind="stable")
        chosen = {}
        for s, (_, m) in inputs.items():
            k = 0 if s == top else round(coarse[s])
            sel = order[octave[order] >= k - 1] if k else order
            xs = xy[sel] * np.float32(s / top) if k else xy[sel]
            if k:
                ok = _inside(m, xs)
                sel, xs = sel[ok], xs[ok]
            n = max(64, round(self.max_features * s))
            chosen[s] = (sel[:n], xs[:n], m)
        # descriptors of the chosen keypoints only (a frame has tens of thousands of keypoints):
        # SIFT describes a given keypoint exactly as its own detect-and-describe pass would
        used = np.unique(np.concatenate([sel for sel, _, _ in chosen.values()]))
        described, desc = sift.compute(gray, [kps[i] for i in used])
        if desc is None or len(described) != len(used):
            raise RuntimeError("SIFT did not describe every keypoint it was given")
        row = np.full(len(kps), -1, np.int64)
        row[used] = np.arange(len(used))
        return {
            s: FeatureSet(frame=frame, scale=s, xy=np.ascontiguousarray(xs), desc=desc[row[sel]], image=None, mask=m)
            for s, (sel, xs, m) in chosen.items()
        }


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


_LK_WIN_LEVELS = (21, 4)
"""Window side (px) and pyramid levels of the pairwise KLT matcher's Lucas-Kanade."""
_NO_IDS = np.zeros(0, np.int64)
_NO_XY = np.zeros((0, 2), np.float32)


def _pyramid_lk(prev: np.ndarray, nxt: np.ndarray, pts: np.ndarray, win: int, levels: int) -> tuple[Any, Any]:
    """Pyramidal Lucas-Kanade tracks of ``pts`` (N, 1, 2) from ``prev`` to ``nxt``: (points, status)."""
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01)
    # nextPts=None (let OpenCV allocate) is valid, but missing from OpenCV's type stubs
    p, st, _ = cv2.calcOpticalFlowPyrLK(  # type: ignore[call-overload]
        prev, nxt, pts, None, winSize=(win, win), maxLevel=levels, criteria=criteria
    )
    return p, st


def lk_forward_backward(
    prev: np.ndarray, nxt: np.ndarray, xy: np.ndarray, mask: np.ndarray, fb_px: float, win: int, levels: int
) -> tuple[np.ndarray, np.ndarray]:
    """Where the points ``xy`` (N, 2) of ``prev`` land in ``nxt`` (N, 2) float32, and which of them
    to keep (N,) bool: tracked both ways, back within ``fb_px`` of the start, inside ``mask`` of ``nxt``."""
    p1, st1 = _pyramid_lk(prev, nxt, xy.reshape(-1, 1, 2), win, levels)
    p0b, st2 = _pyramid_lk(nxt, prev, p1, win, levels)
    p1, p0b = p1.reshape(-1, 2), p0b.reshape(-1, 2)
    ok = (st1.ravel() == 1) & (st2.ravel() == 1) & (np.linalg.norm(p0b - xy, axis=1) <= fb_px)
    return p1, ok & _inside(mask, p1)


def tracking_canvas(working_size: tuple[int, int], side: int) -> tuple[float, tuple[int, int]]:
    """(scale, (W, H)): the image long tracks are followed on, its long side at most ``side`` px
    (a smaller clip at its own size), never below 16 px a side."""
    W, H = working_size
    scale = min(1.0, side / max(W, H))
    return scale, (max(16, round(W * scale)), max(16, round(H * scale)))


def good_corners(gray: np.ndarray, mask: np.ndarray, n: int, min_distance: int) -> np.ndarray:
    """Up to ``n`` Shi-Tomasi corners (n, 2) float32 inside ``mask`` (uint8, 0 = excluded)."""
    if n <= 0:
        return _NO_XY
    pts = cv2.goodFeaturesToTrack(gray, n, 0.005, min_distance, mask=mask, blockSize=7)
    return _NO_XY if pts is None else pts.reshape(-1, 2).astype(np.float32)


class KltMatcher:
    """Shi-Tomasi corners tracked with pyramidal Lucas-Kanade; a track is kept when tracking
    back lands within ``fb_px`` of its start (forward-backward check)."""

    name = "klt"

    def __init__(self, *, max_features: int = 2000, fb_px: float = 0.5, **_: object) -> None:
        self.max_features = max_features
        self.fb_px = fb_px

    def extract(self, gray: np.ndarray, mask: np.ndarray, frame: int, scale: float) -> FeatureSet:
        xy = good_corners(gray, mask.astype(np.uint8) * 255, max(64, round(self.max_features * scale)), 5)
        return FeatureSet(frame=frame, scale=scale, xy=xy, desc=None, image=gray, mask=mask)

    def match(self, a: FeatureSet, b: FeatureSet) -> tuple[np.ndarray, np.ndarray]:
        if len(a) == 0:
            return np.zeros((0, 2)), np.zeros((0, 2))
        assert a.image is not None and b.image is not None, "KLT features keep their image"
        p1, ok = lk_forward_backward(a.image, b.image, a.xy, b.mask, self.fb_px, *_LK_WIN_LEVELS)
        return a.xy[ok].astype(np.float64), p1[ok].astype(np.float64)


@dataclass
class _Tracks:
    """The live tracks of one scale: after ``frame``, ids (N,) and positions (N, 2) float32, and
    the frame's grey image (None after a failure)."""

    frame: int
    ids: np.ndarray
    xy: np.ndarray
    image: np.ndarray | None
    next_id: int


class KltTrackMatcher:
    """KLT tracks kept alive across frames (``klt_tracks``): each frame's features are the
    tracks that reached it, so a pair ``(t0, t1)`` matches the tracks alive in both (they were
    followed through every frame between) and no pair tracks again.

    For each frame, in frame order: the previous frame's tracks are followed with pyramidal
    Lucas-Kanade and kept when tracking back lands within ``fb_px`` of where they were and they
    land inside the frame's usable mask (content minus objects); Shi-Tomasi corners are detected
    again only when fewer than ``redetect_share`` of ``max_features * scale`` tracks are left,
    and only at least ``min_distance`` px from every live track.

    :meth:`extract` must see the frames 0, 1, 2, ... of a scale once each: a call for frame t > 0
    waits until frame t - 1 is done (so workers cannot reorder them; the scorer submits them in
    order) and raises after ``wait_s`` seconds without it. A frame that is not the next one
    (frame 0 again, or after a frame that failed) starts the tracks afresh.

    The ``anchors`` (the scorer passes the first and the last frame) are also extracted with
    SIFT (``max_features * scale``, Lowe's ``ratio``), and a pair of two anchors is matched by
    SIFT: after a long camera move few tracks live from the first frame to the last, and those
    that do crowd into the part of the view both share, which weakens the gate's pose."""

    name = "klt_tracks"

    def __init__(
        self,
        *,
        max_features: int = 2000,
        fb_px: float = 0.5,
        redetect_share: float = 0.9,
        min_distance: int = 5,
        win: int = 15,
        levels: int = 3,
        ratio: float = 0.8,
        anchors: Collection[int] = (),
        wait_s: float = 120.0,
        **_: object,
    ) -> None:
        self.win, self.levels = win, levels
        self.anchors = frozenset(anchors)
        self._sift = SiftMatcher(max_features=max_features, ratio=ratio)
        self.max_features, self.fb_px = max_features, fb_px
        self.redetect_share, self.min_distance, self.wait_s = redetect_share, min_distance, wait_s
        self._tracks: dict[float, _Tracks] = {}
        self._claimed: set[float] = set()
        self._turn = threading.Condition()

    def extract(self, gray: np.ndarray, mask: np.ndarray, frame: int, scale: float) -> FeatureSet:
        with self._turn:
            if not self._turn.wait_for(lambda: self._ready(frame, scale), timeout=self.wait_s):
                raise RuntimeError(
                    f"klt_tracks: frame {frame} (scale {scale}) waited {self.wait_s:.0f} s for frame {frame - 1}, "
                    "which never came; frames must be extracted as 0, 1, 2, ..."
                )
            self._claimed.add(scale)
            state = self._tracks.get(scale)
        # a failed frame leaves no tracks, so the next frame starts afresh instead of waiting
        new = _Tracks(frame, _NO_IDS, _NO_XY, None, state.next_id if state else 0)
        try:
            new = self._advance(state, gray, mask, frame, scale)
        finally:
            with self._turn:
                self._tracks[scale] = new
                self._claimed.discard(scale)
                self._turn.notify_all()
        anchor = self._sift.extract(gray, mask, frame, scale) if frame in self.anchors else None
        return FeatureSet(frame=frame, scale=scale, xy=new.xy, desc=new.ids, image=None, mask=mask, anchor=anchor)

    def _ready(self, frame: int, scale: float) -> bool:
        """Whether frame ``frame`` may be tracked now: nobody tracks its scale, and it is frame 0
        or the scale's last frame is not before ``frame - 1`` (an earlier frame restarts the tracks)."""
        state = self._tracks.get(scale)
        return scale not in self._claimed and (frame == 0 or (state is not None and state.frame >= frame - 1))

    def _advance(self, state: _Tracks | None, gray: np.ndarray, mask: np.ndarray, frame: int, scale: float) -> _Tracks:
        if gray.ndim != 2 or gray.dtype != np.uint8 or gray.size == 0 or mask.shape != gray.shape:
            raise ValueError(
                f"klt_tracks needs a non-empty (h, w) uint8 image and a mask of its shape, got "
                f"{gray.dtype} {gray.shape} and {mask.shape}"
            )
        ids, xy, next_id = _NO_IDS, _NO_XY, 0 if state is None else state.next_id
        prev = None if state is None or state.frame != frame - 1 or not len(state.ids) else state.image
        if state is not None and prev is not None and prev.shape == gray.shape:
            p1, ok = lk_forward_backward(prev, gray, state.xy, mask, self.fb_px, self.win, self.levels)
            ids, xy = state.ids[ok], p1[ok].astype(np.float32)
        n = max(64, round(self.max_features * scale))
        if len(ids) < self.redetect_share * n:
            free = mask.astype(np.uint8) * 255
            for x, y in np.round(xy).astype(int):
                cv2.circle(free, (int(x), int(y)), self.min_distance, 0, -1)
            new = good_corners(gray, free, n - len(ids), self.min_distance)
            ids = np.concatenate([ids, np.arange(next_id, next_id + len(new), dtype=np.int64)])
            xy = np.concatenate([xy, new])
            next_id += len(new)
        return _Tracks(frame, ids, xy, gray, next_id)

    def match(self, a: FeatureSet, b: FeatureSet) -> tuple[np.ndarray, np.ndarray]:
        if a.anchor is not None and b.anchor is not None:
            return self._sift.match(a.anchor, b.anchor)
        assert a.desc is not None and b.desc is not None, "klt_tracks features carry their track ids"
        _, ia, ib = np.intersect1d(a.desc, b.desc, assume_unique=True, return_indices=True)
        return a.xy[ia].astype(np.float64), b.xy[ib].astype(np.float64)


MATCHERS: dict[str, Callable[..., Matcher]] = {
    "sift": SiftMatcher,
    "sift_octaves": SiftOctaveMatcher,
    "orb": OrbMatcher,
    "klt": KltMatcher,
    "klt_tracks": KltTrackMatcher,
}
"""The feature matchers by name (``ScoreConfig.matcher``)."""


def make_matcher(name: str, *, max_features: int = 2000, ratio: float = 0.8, anchors: Collection[int] = ()) -> Matcher:
    """Build a matcher by name; an unknown name lists the valid ones. ``anchors``: the frames
    whose pair the gate's first-last pose compares (used by ``klt_tracks``)."""
    try:
        factory = MATCHERS[name]
    except KeyError:
        raise ValueError(f"unknown matcher {name!r}; valid: {', '.join(MATCHERS)}") from None
    return factory(max_features=max_features, ratio=ratio, anchors=anchors)
