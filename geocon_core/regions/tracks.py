"""Long tracks over the whole frame, shared by every whole-clip reading (:class:`RegionTracker`).

Corners are followed from frame to frame with pyramidal Lucas-Kanade and kept only when tracking
back lands within ``fb_px`` of the start (forward-backward check). Unlike the multi-view check's
tracks (:mod:`geocon_core.reconstruction.tracks`) they are not stopped at object masks: every
moving thing is tracked too, and the object under a track is kept at each frame, so a reading can
judge the background mask-first and each mover by its own motion. Where tracks die, corners are
found again away from the live ones; births and deaths are kept (:class:`ClipTracks`). At each
keyframe every live track's patch is compared with its patch at birth (normalised
cross-correlation), the evidence of a region that is redrawn.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..config import RegionsConfig
from ..geometry import good_corners, lk_forward_backward, tracking_canvas

__all__ = ["ClipTracks", "RegionTracker", "region_keyframes"]

_WIN, _LEVELS = 21, 3


def region_keyframes(num_frames: int, step: int) -> tuple[int, ...]:
    """Every ``step``-th frame from the first, and the last."""
    if num_frames <= 0:
        return ()
    frames = set(range(0, num_frames, max(1, step)))
    frames.add(num_frames - 1)
    return tuple(sorted(frames))


@dataclass(frozen=True)
class ClipTracks:
    """The tracks of one clip at its keyframes.

    ``frames`` (K,) the keyframes; ``xy`` (N, K, 2) float32 positions in px of the clip's working
    canvas, NaN where the track is not alive; ``label`` (N, K) int16, the object under the track
    there (0: background, -1: not alive); ``ncc`` (N, K) float32, the normalised
    cross-correlation of the track's patch with its patch at birth (NaN where not alive);
    ``birth`` and ``death`` (N,) the first and last frame each track was alive (every frame, not
    only keyframes); ``size`` the working canvas (W, H); ``scale`` tracking px per working px."""

    frames: np.ndarray
    xy: np.ndarray
    label: np.ndarray
    ncc: np.ndarray
    birth: np.ndarray
    death: np.ndarray
    size: tuple[int, int]
    scale: float

    def alive(self) -> np.ndarray:
        """(N, K) bool: where each track is alive."""
        return np.isfinite(self.xy[..., 0])

    def __len__(self) -> int:
        return int(self.xy.shape[0])

    ARRAYS = ("frames", "xy", "label", "ncc", "birth", "death")

    def arrays(self, prefix: str) -> dict[str, np.ndarray]:
        return {f"{prefix}{name}": getattr(self, name) for name in self.ARRAYS}

    @classmethod
    def from_arrays(
        cls, z: dict[str, np.ndarray], prefix: str, size: tuple[int, int], scale: float
    ) -> "ClipTracks | None":
        if not all(f"{prefix}{name}" in z for name in cls.ARRAYS):
            return None
        a = {name: np.asarray(z[f"{prefix}{name}"]) for name in cls.ARRAYS}
        return cls(
            frames=a["frames"].astype(np.int64),
            xy=a["xy"].astype(np.float32),
            label=a["label"].astype(np.int16),
            ncc=a["ncc"].astype(np.float32),
            birth=a["birth"].astype(np.int64),
            death=a["death"].astype(np.int64),
            size=size,
            scale=scale,
        )


class RegionTracker:
    """Follows corners through every frame of a clip, in order (:meth:`observe`), over the
    content box, movers included; :meth:`result` gives the :class:`ClipTracks`."""

    def __init__(self, config: RegionsConfig, num_frames: int, working_size: tuple[int, int]) -> None:
        self.config = config
        self.keyframes = region_keyframes(num_frames, config.keyframe_step)
        self._key_index = {t: k for k, t in enumerate(self.keyframes)}
        self.working_size = (int(working_size[0]), int(working_size[1]))
        self.scale, self._size = tracking_canvas(self.working_size, config.track_side)
        self._prev: np.ndarray | None = None
        self._prev_t = -2
        self._ids = np.zeros(0, np.int64)
        self._xy = np.zeros((0, 2), np.float32)
        self._patches: list[np.ndarray] = []
        self._birth: list[int] = []
        self._death = np.zeros(0, np.int64)
        """The last frame each track was alive."""
        self._rows: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = {}

    def _small(self, image: np.ndarray, nearest: bool = False) -> np.ndarray:
        if self.scale == 1.0:
            return image
        how = cv2.INTER_NEAREST if nearest else cv2.INTER_AREA
        return cv2.resize(image, self._size, interpolation=how)

    def _patch(self, g: np.ndarray, x: float, y: float) -> np.ndarray:
        p = self.config.patch_px
        return cv2.getRectSubPix(g, (p, p), (float(x), float(y))).astype(np.float32)

    def observe(self, t: int, gray: np.ndarray, content: np.ndarray, labels: np.ndarray | None) -> None:
        """Follow the tracks into frame ``t`` (grey, working px); ``content`` (bool) the pixels of
        the picture, ``labels`` the objects' ids (0: background) or None."""
        cfg = self.config
        g = self._small(gray)
        m = self._small(content.astype(np.uint8), nearest=True)
        m = cv2.erode(m, np.ones((5, 5), np.uint8)) > 0
        ids, xy = self._ids[:0], self._xy[:0]
        if self._prev is not None and self._prev_t == t - 1 and len(self._ids):
            p1, ok = lk_forward_backward(self._prev, g, self._xy, m, cfg.fb_px, _WIN, _LEVELS)
            ids, xy = self._ids[ok], p1[ok].astype(np.float32)
        if len(ids) < cfg.reseed_share * cfg.max_tracks:
            free = m.astype(np.uint8) * 255
            for x, y in np.round(xy).astype(int):
                cv2.circle(free, (int(x), int(y)), cfg.min_distance, 0, -1)
            new = good_corners(g, free, cfg.max_tracks - len(ids), cfg.min_distance)
            start = len(self._birth)
            for x, y in new:
                self._patches.append(self._patch(g, x, y))
                self._birth.append(t)
            self._death = np.concatenate([self._death, np.full(len(new), t, np.int64)])
            ids = np.concatenate([ids, np.arange(start, start + len(new), dtype=np.int64)])
            xy = np.concatenate([xy, new]).astype(np.float32)
        self._death[ids] = t
        self._prev, self._prev_t, self._ids, self._xy = g, t, ids, xy
        if t in self._key_index:
            if labels is None:
                lab = np.zeros(len(ids), np.int16)
            else:
                W, H = self.working_size
                px = np.clip(np.round(xy[:, 0] / self.scale).astype(int), 0, W - 1)
                py = np.clip(np.round(xy[:, 1] / self.scale).astype(int), 0, H - 1)
                lab = labels[py, px].astype(np.int16)
            ncc = np.array(
                [_ncc(self._patch(g, x, y), self._patches[int(i)]) for i, (x, y) in zip(ids, xy, strict=True)],
                np.float32,
            )
            self._rows[t] = (ids.copy(), xy.astype(np.float32) / self.scale, lab, ncc)

    def result(self) -> ClipTracks:
        """The tracks at the keyframes seen (:class:`ClipTracks`)."""
        frames = np.array([t for t in self.keyframes if t in self._rows], np.int64)
        n = len(self._birth)
        xy = np.full((n, len(frames), 2), np.nan, np.float32)
        label = np.full((n, len(frames)), -1, np.int16)
        ncc = np.full((n, len(frames)), np.nan, np.float32)
        for k, t in enumerate(frames):
            ids, pts, lab, c = self._rows[int(t)]
            xy[ids, k] = pts
            label[ids, k] = lab
            ncc[ids, k] = c
        seen = np.isfinite(xy[..., 0]).sum(axis=1) >= 2  # a track seen at one keyframe says nothing
        return ClipTracks(
            frames=frames,
            xy=xy[seen],
            label=label[seen],
            ncc=ncc[seen],
            birth=np.asarray(self._birth, np.int64)[seen],
            death=self._death[seen],
            size=self.working_size,
            scale=self.scale,
        )


def _ncc(a: np.ndarray, b: np.ndarray) -> float:
    a = a - a.mean()
    b = b - b.mean()
    den = float(np.sqrt((a * a).sum() * (b * b).sum()))
    return float((a * b).sum() / den) if den > 1e-6 else float("nan")
