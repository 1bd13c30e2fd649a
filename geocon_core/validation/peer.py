"""The simplest published peer: the GVGC keep rate.

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
]

PEER_NAME = "GVGC keep rate"
"""The published peer measured beside GeoCon."""
PEER_FILE = "peer.json"
"""The peer's score of a validation case (:class:`PeerScore` as JSON), beside its record."""
PEER_VERSION = 1
"""Bumped whenever what the peer measures changes (saved peer scores of another version are recomputed)."""
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
    what the peer sees. Videos, GIFs and folders of PNG / JPEG frames."""
    from ..media import image_frames, open_video, resolve_clip

    name = str(path)
    kind, files = resolve_clip(Path(path), name)
    frames: Iterator[np.ndarray]
    if kind == "images":
        assert files is not None
        frames = image_frames(files, name)
    else:
        frames = open_video(name)[1]
    for n, bgr in enumerate(frames):
        if max_frames is not None and n >= max_frames:
            break
        yield bgr


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
