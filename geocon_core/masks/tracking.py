"""Object ids of the built-in segmentation (step 5 of :class:`~geocon_core.masks.MotionSegmenter`):
tracks matched greedily by the overlap of their shifted last mask, confirmed after
``min_track`` detections, numbered 1, 2, ... in order of confirmation."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..stage_configs import MotionConfig
from .base import MAX_ID

__all__ = ["Track", "Segmentation", "Tracker", "shift_mask"]


@dataclass
class Track:
    tid: int
    mask: np.ndarray  # (rh, rw) bool, at the last detection
    velocity: np.ndarray  # (2,) px per step at the reduced scale
    last_step: int
    count: int = 1
    public: int = 0
    confirmed_at: int | None = None


@dataclass
class Segmentation:
    """Segmentation of one frame: accepted components (reduced map, 1..n) and their tracks."""

    comps: np.ndarray  # (rh, rw) uint8
    tracks: list[int] = field(default_factory=list)  # tid of component k + 1


class Tracker:
    """Tracks over the distinct frames of a clip. ``warnings`` is appended to (a list shared
    with the mask source) when more objects appear than uint8 labels can hold."""

    def __init__(self, config: MotionConfig, warnings: list[str]) -> None:
        self.config = config
        self.warnings = warnings
        self.tracks: list[Track] = []
        """Every track a kept frame may still refer to."""
        self.alive: list[Track] = []
        """Tracks that may still be matched."""
        self._step = 0  # tracking steps (distinct frames segmented)
        self._next_tid = 1
        self._next_public = 1

    def cut(self) -> None:
        """A hard cut ends every track."""
        self.alive = []

    def prune(self, keep: set[int]) -> None:
        """Forget tracks that no kept frame refers to (``keep``) and that cannot be matched again."""
        keep = keep | {tr.tid for tr in self.alive}
        self.tracks = [tr for tr in self.tracks if tr.tid in keep]

    def step(self, t: int, masks: list[np.ndarray], vels: list[np.ndarray]) -> list[int]:
        """The track id of each detection of frame t (new tracks for unmatched ones)."""
        self._step += 1
        step = self._step
        alive = [tr for tr in self.alive if step - tr.last_step <= self.config.max_gap + 1]
        out = self._match(alive, masks, vels, step)
        for j, m in enumerate(masks):
            if out[j]:
                continue
            tr = Track(tid=self._next_tid, mask=m, velocity=vels[j], last_step=step)
            self._next_tid += 1
            self.tracks.append(tr)
            alive.append(tr)
            out[j] = tr.tid
        self._confirm(alive, t)
        self.alive = alive
        return out

    def _match(self, alive: list[Track], masks: list[np.ndarray], vels: list[np.ndarray], step: int) -> list[int]:
        """Greedy matching by overlap, best first; updates the matched tracks."""
        cand = []
        for i, tr in enumerate(alive):
            pred = shift_mask(tr.mask, tr.velocity * (step - tr.last_step))
            npred = int(np.count_nonzero(pred))
            for j, m in enumerate(masks):
                inter = int(np.count_nonzero(pred & m))
                if inter == 0 or npred == 0:
                    continue
                ov = inter / min(npred, int(np.count_nonzero(m)))
                if ov >= self.config.match_overlap:
                    cand.append((-ov, tr.tid, j, i))
        cand.sort()
        used_t, used_c = set(), set()
        out: list[int] = [0] * len(masks)
        for _, tid, j, i in cand:
            if tid in used_t or j in used_c:
                continue
            used_t.add(tid)
            used_c.add(j)
            tr = alive[i]
            tr.mask, tr.velocity, tr.last_step = masks[j], vels[j], step
            tr.count += 1
            out[j] = tid
        return out

    def _confirm(self, alive: list[Track], t: int) -> None:
        for tr in alive:  # confirm, in order of creation
            if tr.confirmed_at is None and tr.count >= self.config.min_track:
                if self._next_public > MAX_ID:
                    msg = f"more than {MAX_ID} moving objects: later ones are not labelled"
                    if msg not in self.warnings:
                        self.warnings.append(msg)
                    continue
                tr.confirmed_at, tr.public = t, self._next_public
                self._next_public += 1


def shift_mask(mask: np.ndarray, d: np.ndarray) -> np.ndarray:
    """``mask`` translated by d = (dx, dy) rounded to whole pixels (outside: False)."""
    dx, dy = int(round(float(d[0]))), int(round(float(d[1])))
    h, w = mask.shape
    out = np.zeros_like(mask)
    if abs(dx) >= w or abs(dy) >= h:
        return out
    out[max(0, dy) : h + min(0, dy), max(0, dx) : w + min(0, dx)] = mask[
        max(0, -dy) : h - max(0, dy), max(0, -dx) : w - max(0, dx)
    ]
    return out
