"""The multi-view check's long tracks: corners followed through every frame with pyramidal
Lucas-Kanade (:class:`LongTracks`), their positions at up to ``max_views`` keyframes
(:class:`TrackObservations`) and the tracks x keyframes table a reconstruction reads
(:class:`TrackTable`)."""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from ..config import MultiViewConfig
from ..geometry import good_corners, lk_forward_backward, tracking_canvas

__all__ = ["LongTracks", "TrackObservations", "TrackTable", "keyframes"]

_WIN, _LEVELS = 21, 3


def keyframes(num_frames: int, max_views: int) -> tuple[int, ...]:
    """Up to ``max_views`` frames spread evenly from the first to the last (both included)."""
    if num_frames <= 0:
        return ()
    k = max(2, min(num_frames, max_views))
    return tuple(sorted({int(round(i * (num_frames - 1) / (k - 1))) for i in range(k)}))


@dataclass
class TrackObservations:
    """Where each track was at each keyframe: ``frames`` (K,) the keyframes, and per keyframe
    the ids (N_k,) int64 and positions (N_k, 2) float64 in working px of the tracks alive there."""

    frames: list[int] = field(default_factory=list)
    ids: list[np.ndarray] = field(default_factory=list)
    xy: list[np.ndarray] = field(default_factory=list)


class LongTracks:
    """Corners followed through every frame (pyramidal Lucas-Kanade, forward-backward checked)
    on a grey image whose long side is at most ``config.track_side``; a track ends where it
    leaves the usable mask (content minus objects). Corners are detected again, away from the
    live tracks, when fewer than 80% of ``config.max_tracks`` are left. :meth:`observe` must see
    the frames in order; the positions at the keyframes are kept (:attr:`observations`)."""

    def __init__(self, config: MultiViewConfig, num_frames: int, working_size: tuple[int, int]) -> None:
        self.config = config
        self.keyframes = frozenset(keyframes(num_frames, config.max_views))
        self.scale, self._size = tracking_canvas(working_size, config.track_side)
        self._prev: np.ndarray | None = None
        self._prev_t = -2
        self._ids = np.zeros(0, np.int64)
        self._xy = np.zeros((0, 2), np.float32)
        self._next_id = 0
        self.observations = TrackObservations()

    def observe(self, t: int, gray: np.ndarray, usable: np.ndarray) -> None:
        """Follow the tracks into frame ``t`` (grey, working px) whose usable pixels are ``usable`` (bool)."""
        cfg = self.config
        g = gray if self.scale == 1.0 else cv2.resize(gray, self._size, interpolation=cv2.INTER_AREA)
        m = (
            usable
            if self.scale == 1.0
            else cv2.resize(usable.astype(np.uint8), self._size, interpolation=cv2.INTER_NEAREST) > 0
        )
        m = cv2.erode(m.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0  # away from mask edges
        ids, xy = self._ids[:0], self._xy[:0]
        if self._prev is not None and self._prev_t == t - 1 and len(self._ids):
            p1, ok = lk_forward_backward(self._prev, g, self._xy, m, cfg.fb_px, _WIN, _LEVELS)
            ids, xy = self._ids[ok], p1[ok].astype(np.float32)
        if len(ids) < 0.8 * cfg.max_tracks:
            free = m.astype(np.uint8) * 255
            for x, y in np.round(xy).astype(int):
                cv2.circle(free, (int(x), int(y)), cfg.min_distance, 0, -1)
            new = good_corners(g, free, cfg.max_tracks - len(ids), cfg.min_distance)
            ids = np.concatenate([ids, np.arange(self._next_id, self._next_id + len(new), dtype=np.int64)])
            xy = np.concatenate([xy, new]).astype(np.float32)
            self._next_id += len(new)
        self._prev, self._prev_t, self._ids, self._xy = g, t, ids, xy
        if t in self.keyframes:
            obs = self.observations
            obs.frames.append(t)
            obs.ids.append(ids.copy())
            obs.xy.append(xy.astype(np.float64) / self.scale)


@dataclass
class TrackTable:
    """Tracks x keyframes: ``xy`` (T, K, 2) working px (NaN where unseen) and ``ids`` (T,)."""

    frames: tuple[int, ...]
    ids: np.ndarray
    xy: np.ndarray

    @classmethod
    def of(cls, obs: TrackObservations, min_views: int) -> "TrackTable":
        frames = tuple(obs.frames)
        all_ids = np.unique(np.concatenate(obs.ids)) if obs.ids else np.zeros(0, np.int64)
        xy = np.full((len(all_ids), len(frames), 2), np.nan)
        for k, (ids, pts) in enumerate(zip(obs.ids, obs.xy, strict=True)):
            xy[np.searchsorted(all_ids, ids), k] = pts
        seen = np.isfinite(xy[..., 0]).sum(axis=1)
        keep = seen >= min_views
        return cls(frames, all_ids[keep], xy[keep])

    def seen(self) -> np.ndarray:
        return np.isfinite(self.xy[..., 0])
