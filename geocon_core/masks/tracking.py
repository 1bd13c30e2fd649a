"""Object ids of the built-in segmentation (step 5 of :class:`~geocon_core.masks.MotionSegmenter`):
tracks matched greedily by the overlap of their shifted last mask, confirmed after
``min_track`` detections, numbered 1, 2, ... in order of confirmation; a newly confirmed track
that continues a lost one (expected position, colour) takes over its id."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..config import MotionConfig
from .base import MAX_ID
from .identity import centroid, histogram_distance

__all__ = ["Track", "Segmentation", "Tracker", "shift_mask"]


@dataclass
class Track:
    tid: int
    mask: np.ndarray  # (rh, rw) bool, at the last detection
    velocity: np.ndarray  # (2,) px per step at the reduced scale
    last_step: int
    hist: np.ndarray  # colour histogram (running mean over the detections)
    count: int = 1
    public: int = 0
    confirmed_at: int | None = None


@dataclass
class _Lost:
    """What a confirmed track left behind for re-identification."""

    public: int
    centre: np.ndarray  # (2,) reduced px at the last detection
    velocity: np.ndarray  # (2,) reduced px per step
    size: float  # sqrt of the last mask's area, reduced px
    last_step: int
    hist: np.ndarray


@dataclass
class Segmentation:
    """Segmentation of one frame: accepted components (reduced map, 1..n) and their tracks."""

    comps: np.ndarray  # (rh, rw) uint8
    tracks: list[int] = field(default_factory=list)  # tid of component k + 1


class Tracker:
    """Tracks over the distinct frames of a clip. ``warnings`` is appended to (a list shared
    with the mask source) when more objects appear than uint8 labels can hold."""

    def __init__(self, config: MotionConfig, warnings: list[str], s: float = 1.0) -> None:
        self.config = config
        self.warnings = warnings
        self._s = s  # reduced px per px of a setting (MotionConfig.px_reference)
        self.tracks: list[Track] = []
        """Every track a kept frame may still refer to."""
        self.alive: list[Track] = []
        """Tracks that may still be matched."""
        self._lost: list[_Lost] = []
        self._step = 0  # tracking steps (distinct frames segmented)
        self._next_tid = 1
        self._next_public = 1

    def cut(self) -> None:
        """A hard cut ends every track; no id carries over it."""
        self.alive = []
        self._lost = []

    def prune(self, keep: set[int]) -> None:
        """Forget tracks that no kept frame refers to (``keep``) and that cannot be matched again."""
        keep = keep | {tr.tid for tr in self.alive}
        self.tracks = [tr for tr in self.tracks if tr.tid in keep]

    def step(self, t: int, masks: list[np.ndarray], vels: list[np.ndarray], hists: list[np.ndarray]) -> list[int]:
        """The track id of each detection of frame t (new tracks for unmatched ones)."""
        self._step += 1
        step = self._step
        alive = []
        for tr in self.alive:
            if step - tr.last_step <= self.config.max_gap + 1:
                alive.append(tr)
            else:
                self._lose(tr)
        self._lost = [lo for lo in self._lost if step - lo.last_step <= self.config.link_gap + 1]
        out = self._match(alive, masks, vels, hists, step)
        for j, m in enumerate(masks):
            if out[j]:
                continue
            tr = Track(
                tid=self._next_tid,
                mask=m,
                velocity=vels[j],
                last_step=step,
                hist=hists[j],
            )
            self._next_tid += 1
            self.tracks.append(tr)
            alive.append(tr)
            out[j] = tr.tid
        self._confirm(alive, t)
        self.alive = alive
        return out

    def _lose(self, tr: Track) -> None:
        if tr.confirmed_at is not None and tr.mask.any() and tr.last_step > 0:
            self._lost.append(self._lost_of(tr))

    def _match(
        self,
        alive: list[Track],
        masks: list[np.ndarray],
        vels: list[np.ndarray],
        hists: list[np.ndarray],
        step: int,
    ) -> list[int]:
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
            tr.hist = (tr.hist * tr.count + hists[j]) / (tr.count + 1)
            tr.count += 1
            out[j] = tid
        return out

    def _confirm(self, alive: list[Track], t: int) -> None:
        for tr in alive:  # confirm, in order of creation
            if tr.confirmed_at is None and tr.count >= self.config.min_track:
                public = self._part_of(tr, alive)
                if public is None:
                    public = self._relink(tr)
                if public is None:
                    if self._next_public > MAX_ID:
                        msg = f"more than {MAX_ID} moving objects: later ones are not labelled"
                        if msg not in self.warnings:
                            self.warnings.append(msg)
                        continue
                    public = self._next_public
                    self._next_public += 1
                tr.confirmed_at, tr.public = t, public

    def _part_of(self, tr: Track, alive: list[Track]) -> int | None:
        """The id of a confirmed track detected at most ``max_gap`` frames before ``tr``'s latest
        detection whose last box, grown by ``merge_px``, holds ``tr``'s centre: a part of that
        mover (the largest such track wins)."""
        c = centroid(tr.mask)
        pad = self.config.merge_px * self._s
        best, best_area = None, 0
        for other in alive:
            if other is tr or other.confirmed_at is None or tr.last_step - other.last_step > self.config.max_gap:
                continue
            ys, xs = np.nonzero(other.mask)
            inside = xs.min() - pad <= c[0] <= xs.max() + pad and ys.min() - pad <= c[1] <= ys.max() + pad
            if inside and xs.size > best_area:
                best, best_area = other.public, xs.size
        return best

    def _relink(self, tr: Track) -> int | None:
        """The id of the track that ``tr`` continues, if any (that track is consumed): a
        confirmed track not detected in ``tr``'s latest frame and last detected at most
        ``link_gap`` frames before it, where its velocity puts it within ``link_radius`` object
        sizes (plus ``link_speed_px`` per frame of the gap) of ``tr``'s latest centre, colours
        within ``link_hist``. The nearest in position wins. (``tr`` may have begun before the
        other was lost: a mover whose detection split for a few frames.)"""
        cfg = self.config
        now = tr.last_step
        cands: list[tuple[_Lost, Track | None]] = [(lo, None) for lo in self._lost]
        for other in self.alive:  # confirmed tracks still waiting out their gap
            if other is not tr and other.confirmed_at is not None and other.last_step < now:
                cands.append((self._lost_of(other), other))
        centre = centroid(tr.mask)
        best, best_d = None, np.inf
        for k, (lo, _) in enumerate(cands):
            gap = now - lo.last_step
            if not 0 < gap <= cfg.link_gap + 1:
                continue
            if histogram_distance(lo.hist, tr.hist) > cfg.link_hist:
                continue
            expected = lo.centre + lo.velocity * min(gap, cfg.max_gap + 1)
            d = float(np.hypot(*(centre - expected)))
            if d <= cfg.link_radius * lo.size + cfg.link_speed_px * self._s * gap and d < best_d:
                best, best_d = k, d
        if best is None:
            return None
        lo, owner = cands[best]
        if owner is None:
            self._lost = [x for x in self._lost if x is not lo]
        else:
            owner.last_step = -(10**9)  # ended: it can no longer be matched
        return lo.public

    @staticmethod
    def _lost_of(tr: Track) -> _Lost:
        size = float(np.sqrt(max(1, int(np.count_nonzero(tr.mask)))))
        return _Lost(tr.public, centroid(tr.mask), tr.velocity, size, tr.last_step, tr.hist)


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
