"""The published peers: the GVGC keep rate and Epipolar-DPO's mean Sampson distance.

The geometric-consistency study of generated video (the "Sora ... geometrical consistency" work,
and VBench-2.0's port of it) scores a clip by how many SIFT matches between two of its frames a
fundamental matrix keeps. Its protocol, as described there and reproduced here:

- frames resized to 854 x 480 (aspect not kept), grey;
- OpenCV SIFT with up to 40,000 features per frame;
- FLANN (KD-tree) 2-nearest-neighbour matching, Lowe ratio 0.85;
- ``cv2.findFundamentalMat`` with RANSAC at 1 px (the study's threshold at 854 x 480);
- keep rate of a pair = F inliers / ratio-test matches; no masks, no gate, no model choice.

A clip's keep rate is the mean over its adjacent frame pairs (:data:`PEER_GAP`) of the frames
:func:`peer_keep_rate` reads. A pair with fewer than 8 matches (no fundamental matrix can be
fitted) keeps nothing (0); a pair with no match at all is left out. GeoCon reports ``1 - keep
rate`` beside its own clip score (higher = more broken) so both read the same way.

Everything is seeded (``cv2.setRNGSeed``): the same clip gives the same keep rate.

The second peer is the reward of Epipolar-DPO (Kupyn et al. 2025), as its paper and public code
describe it: grey frames as decoded, every :data:`EPIPOLAR_STRIDE`-th frame paired with the next
one sampled, OpenCV SIFT (default settings), brute-force two-nearest-neighbour matching with
Lowe's ratio 0.75, a fundamental matrix fitted by the normalised 8-point algorithm to all
matches (least squares, no RANSAC), and the mean squared Sampson distance of the matches; a
clip reads the mean over its pairs (:func:`epipolar_score`). Deterministic: no random choice.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Iterator
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np

from ..files import SMALL_STATE, read_text

__all__ = [
    "PEER_NAME",
    "PEER_FILE",
    "PEER_VERSION",
    "PEER_SIZE",
    "PEER_FEATURES",
    "PEER_RATIO",
    "PEER_RANSAC_PX",
    "PEER_GAP",
    "PeerScore",
    "read_peer",
    "pair_keep",
    "peer_keep_rate",
    "raw_frames",
    "EPIPOLAR_NAME",
    "EPIPOLAR_FILE",
    "EPIPOLAR_STRIDE",
    "EPIPOLAR_RATIO",
    "EpipolarScore",
    "epipolar_pair",
    "epipolar_score",
    "sampson_squared",
]

PEER_NAME = "GVGC keep rate"
"""The published peer measured beside GeoCon."""
PEER_FILE = "peer.json"
"""The peer's score of a validation case (:class:`PeerScore` as JSON), beside its record."""
PEER_VERSION = 2
"""Bumped whenever what the peers measure changes (saved peer scores of another version are recomputed);
2: ``peer.json`` also holds the second peer (``epipolar``: :class:`EpipolarScore`)."""
PEER_SIZE = (854, 480)
PEER_FEATURES = 40000
PEER_RATIO = 0.85
PEER_RANSAC_PX = 1.0
PEER_GAP = 1
_MIN_F_MATCHES = 8


@dataclass(frozen=True)
class PeerScore:
    """The peer on one clip: ``keep_rate`` (mean over pairs, 0..1; None when no pair had a match),
    ``pairs`` scored, total ``matches`` and ``inliers`` over them, and the wall time."""

    keep_rate: float | None
    pairs: int
    matches: int
    inliers: int
    frames: int
    seconds: float
    version: int = PEER_VERSION

    @property
    def score(self) -> float | None:
        """``1 - keep_rate``: 0 = every match kept, 1 = none (reads like GeoCon's clip score)."""
        return None if self.keep_rate is None else 1.0 - self.keep_rate

    def to_dict(self) -> dict:
        return asdict(self)


def read_peer(folder: Path) -> dict | None:
    """The peer's saved score in a case folder (``peer.json``), None when absent, unreadable or
    of another :data:`PEER_VERSION` (then it is computed again)."""
    try:
        saved = json.loads(read_text(folder / PEER_FILE, SMALL_STATE))
    except (OSError, ValueError):
        return None
    return saved if isinstance(saved, dict) and saved.get("version") == PEER_VERSION else None


def raw_frames(path: str | Path, max_frames: int | None = None) -> Iterator[np.ndarray]:
    """The clip's decoded BGR frames as stored (no crop, no working size), at most ``max_frames``:
    what the peers see (:func:`~geocon_core.media.source_frames`)."""
    from ..media import source_frames

    return source_frames(path, max_frames)


def _features(sift: cv2.SIFT, bgr: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    grey = cv2.cvtColor(cv2.resize(bgr, PEER_SIZE, interpolation=cv2.INTER_LINEAR), cv2.COLOR_BGR2GRAY)
    kps, des = sift.detectAndCompute(grey, None)
    pts = np.array([k.pt for k in kps], np.float32).reshape(-1, 2)
    return pts, des


def pair_keep(pts1: np.ndarray, des1: np.ndarray | None, pts2: np.ndarray, des2: np.ndarray | None) -> tuple[int, int]:
    """(ratio-test matches, fundamental-matrix RANSAC inliers) of one pair of frames' features."""
    if des1 is None or des2 is None or len(des1) < 2 or len(des2) < 2:
        return 0, 0
    knn = cv2.FlannBasedMatcher().knnMatch(des1, des2, k=2)
    good = [m for m, n in (p for p in knn if len(p) == 2) if m.distance < PEER_RATIO * n.distance]
    if len(good) < _MIN_F_MATCHES:
        return len(good), 0
    src = pts1[[m.queryIdx for m in good]]
    dst = pts2[[m.trainIdx for m in good]]
    F, mask = cv2.findFundamentalMat(src, dst, cv2.FM_RANSAC, PEER_RANSAC_PX, 0.99)
    inliers = 0 if F is None or mask is None else int(mask.sum())
    return len(good), inliers


def peer_keep_rate(path: str | Path, max_frames: int | None = None, *, gap: int = PEER_GAP) -> PeerScore:
    """The GVGC keep rate of the clip at ``path`` over its first ``max_frames`` frames (all when
    None), on the pairs (t, t + ``gap``)."""
    if gap < 1:
        raise ValueError(f"gap must be at least 1, got {gap}")
    cv2.setRNGSeed(0)
    start = time.perf_counter()
    sift = cv2.SIFT_create(PEER_FEATURES)  # type: ignore[attr-defined]  # in cv2, missing from its stubs
    feats = [_features(sift, bgr) for bgr in raw_frames(path, max_frames)]
    rates: list[float] = []
    matches = inliers = 0
    for t in range(len(feats) - gap):
        m, k = pair_keep(*feats[t], *feats[t + gap])
        if m == 0:
            continue
        rates.append(k / m)
        matches += m
        inliers += k
    keep = float(np.mean(rates)) if rates else None
    if keep is not None and not math.isfinite(keep):
        keep = None
    return PeerScore(keep, len(rates), matches, inliers, len(feats), round(time.perf_counter() - start, 3))


# --- the second peer: Epipolar-DPO's mean Sampson distance ---------------------------------

EPIPOLAR_NAME = "Epipolar-DPO Sampson"
"""The second published peer: the reward of Epipolar-DPO (Kupyn et al. 2025)."""
EPIPOLAR_FILE = "epipolar.json"
"""Its score of a validation case (:class:`EpipolarScore` as JSON), beside the record."""
EPIPOLAR_VERSION = 1
EPIPOLAR_STRIDE = 15
"""Frames between the two frames of a scored pair: (0, 15), (15, 30), ..."""
EPIPOLAR_RATIO = 0.75
"""Lowe's ratio of its SIFT matching (brute force, two nearest neighbours)."""


@dataclass(frozen=True)
class EpipolarScore:
    """Epipolar-DPO's reading of one clip: ``sampson`` is the mean over its pairs of the mean
    squared Sampson distance (px^2, source pixels) of every ratio-test match to a fundamental
    matrix fitted to all of them by the 8-point algorithm (least squares, no RANSAC); None when
    no pair had 8 matches. Higher = more broken, as GeoCon's clip score reads."""

    sampson: float | None
    pairs: int
    matches: int
    frames: int
    seconds: float
    version: int = EPIPOLAR_VERSION

    @property
    def score(self) -> float | None:
        return self.sampson

    def to_dict(self) -> dict:
        return asdict(self)


def sampson_squared(F: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    """(N,) squared Sampson distance (px^2) of the matches ``x1 -> x2`` ((N, 2) each) to ``F``
    (``x2^T F x1 = 0``): ``(x2^T F x1)^2 / ((F x1)_1^2 + (F x1)_2^2 + (F^T x2)_1^2 + (F^T x2)_2^2)``."""
    h1 = np.c_[x1, np.ones(len(x1))]
    h2 = np.c_[x2, np.ones(len(x2))]
    Fx1 = h1 @ F.T
    Ftx2 = h2 @ F
    num = np.einsum("ij,ij->i", h2, Fx1) ** 2
    den = Fx1[:, 0] ** 2 + Fx1[:, 1] ** 2 + Ftx2[:, 0] ** 2 + Ftx2[:, 1] ** 2
    return num / np.maximum(den, 1e-12)


def epipolar_pair(sift: cv2.SIFT, a: np.ndarray, b: np.ndarray) -> tuple[int, float | None]:
    """(ratio-test matches, mean squared Sampson distance) of two grey frames under Epipolar-DPO's
    protocol; the distance is None below 8 matches."""
    ka, da = sift.detectAndCompute(a, None)
    kb, db = sift.detectAndCompute(b, None)
    if da is None or db is None or len(da) < 2 or len(db) < 2:
        return 0, None
    knn = cv2.BFMatcher().knnMatch(da, db, k=2)
    good = [m for m, n in (p for p in knn if len(p) == 2) if m.distance < EPIPOLAR_RATIO * n.distance]
    if len(good) < _MIN_F_MATCHES:
        return len(good), None
    x1 = np.array([ka[m.queryIdx].pt for m in good], np.float64)
    x2 = np.array([kb[m.trainIdx].pt for m in good], np.float64)
    F, _ = cv2.findFundamentalMat(x1, x2, cv2.FM_8POINT)
    if F is None or F.shape != (3, 3):
        return len(good), None
    d = sampson_squared(F, x1, x2)
    return len(good), float(np.mean(d)) if np.isfinite(d).all() else None


def epipolar_score(frames: "Iterator[np.ndarray] | str | Path", max_frames: int | None = None) -> EpipolarScore:
    """Epipolar-DPO's reading (:class:`EpipolarScore`) of a clip at a path, or of its BGR frames
    (an iterable of (h, w, 3) uint8 arrays, e.g. :func:`raw_frames`), over the pairs
    (t, t + :data:`EPIPOLAR_STRIDE`) for t = 0, 15, 30, ... of its first ``max_frames`` frames."""
    start = time.perf_counter()
    source = raw_frames(frames, max_frames) if isinstance(frames, (str, Path)) else frames
    grey = [
        cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
        for t, bgr in enumerate(source)
        if t % EPIPOLAR_STRIDE == 0 and (max_frames is None or t < max_frames)
    ]
    sift = cv2.SIFT_create()  # type: ignore[attr-defined]  # in cv2, missing from its stubs
    values: list[float] = []
    matches = 0
    for a, b in zip(grey, grey[1:], strict=False):
        m, d = epipolar_pair(sift, a, b)
        matches += m
        if d is not None:
            values.append(d)
    mean = float(np.mean(values)) if values else None
    return EpipolarScore(mean, len(values), matches, len(grey), round(time.perf_counter() - start, 3))
