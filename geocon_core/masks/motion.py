"""The built-in motion segmentation (``motion``): streaming, per-frame segmentation and labels.
The evidence is computed by :mod:`.evidence`, regions by :mod:`.regions`, ids by :mod:`.tracking`."""

from __future__ import annotations

from collections import deque
from dataclasses import replace
from typing import Any

import cv2
import numpy as np

from ..config import MotionConfig
from ..flow import DisFlow, FlowBackend
from ..media import ClipInfo, Frame
from .base import MAX_ID, Coverage
from .evidence import Evidence, Side
from .identity import colour_histogram, merge_parts
from .regions import RegionFinder
from .tracking import Segmentation, Tracker

__all__ = ["MotionSegmenter"]


class MotionSegmenter(Coverage):
    """Built-in motion segmentation (``name = "motion"``, lookahead ``lookahead`` = 7, no weights).

    Settings: ``config`` (:class:`~geocon_core.config.stages.MotionConfig`, defaults when None;
    keyword arguments override single fields); ``flow`` is the flow backend, ``seed`` seeds the
    background fits. The defaults quoted below are those of :class:`MotionConfig`.

    Lengths below are working pixels unless marked *reduced* (pixels of the analysis scale).
    For every pair of consecutive distinct frames (t, t+1), at the analysis size (the largest
    size inside ``analysis_size``, default 512x360, never above the working size) of the
    content, over the content box only:

    1. **Flow**: forward and backward dense flow (``flow``, default :class:`DisFlow`, medium
       preset) with the forward-backward reliability check.
    2. **Background model**, fitted separately to each direction on a grid of reliable flow
       vectors (every ``fit_step`` = 12 reduced px, about 1000 vectors at 1024x576) with
       OpenCV USAC (MAGSAC++, seeded, via :func:`geocon_core.geometry.models.fit_homography` and
       ``fit_fundamental``), inlier tolerance ``fit_tau_px`` = 1 px. Regimes:

       * ``static``: the homography moves 95 % of the grid vectors by at most ``static_px`` =
         0.5 px. The homography is used and F is never tried: with a still background, a
         single translating object is exactly as consistent with an epipolar geometry as
         parallax is, and F would swallow it.
       * ``F``: the camera moved and a fundamental matrix explains what the homography
         leaves: at least half of its outliers and at least ``f_gain`` = 5 % of all vectors
         (structured parallax of a translating camera).
       * ``H``: otherwise (pan, tilt, roll, zoom, planar scenes).
    3. **Residual** per pixel: ``H``/``static``: the transfer error ``|x + F(x) - H x|``;
       ``F``: the distance of ``x + F(x)`` to the epipolar line of ``x`` (blind to motion along
       epipolar lines, i.e. to parallax), combined (max) with a *cheirality* residual: with
       default intrinsics (``fov_deg`` = 60 over the content width) F gives the camera motion
       (R, t) that puts most vectors in front of both cameras, and a static point can only
       move from its point at infinity ``K R K^-1 x`` towards the epipole side, never against
       it; the component against it is residual (an object moving against the flow of a
       translating camera). From this F residual, ``parallax_share`` = 1/4 of the pixel's
       parallax (its displacement from the homography's prediction) is subtracted: flow
       errors grow with the displacement, and near surfaces of a static scene seen by a
       translating camera move most. Threshold ``max(k_sigma * sigma, min_px)`` with ``sigma = 1.4826 *
       median`` grid residual, ``k_sigma`` = 4, ``min_px`` = 2 px per frame: a breathing or
       drifting background moves less than that per frame (and is, if it moves more, still
       smooth; see 4) and is left to the scorer, which reports it as a failure. Frame t's
       score is residual / threshold from the pair (t, t+1) and from the backward pair
       (t, t-1); where both exist their minimum is taken, which removes the occlusion strips
       ahead of and behind a moving object (only one direction is occluded there).
       **Slow movers**: when the camera is still (``static`` regime both over (t-1, t) and
       over the gap), frame t is also compared with the distinct frame ``slow_gap`` = 4
       frames earlier; that residual counts (max with the above) where its flow is reliable
       and agrees with ``slow_gap`` times the adjacent backward flow within ``min_px`` plus
       half its length (a steady slow mover; the wake of a fast mover disagrees).
    4. **Objects**: a pixel is kept where its score is >= 1 and at least ``refine`` = 1/2 of
       the highest score within ``halo_px`` = 6 reduced px (a local half-maximum boundary:
       flow is smoothed across object edges, and this trims the halo and separates objects
       whose halos touch); opened (3x3), closed (5x5, never into a trimmed halo); connected
       components are kept when they are compact (area between ``min_area`` = 0.1 % and
       ``max_area`` = 35 % of the content, solidity >= ``min_solidity`` = 0.5, a core at
       least ``min_thickness`` = 2 reduced px from the edge), sharply bounded (the median
       score in a ring 2..6 reduced px outside is at most ``edge_ratio`` = 1/2 of the median
       inside: a rubber-sheet warp that crosses the threshold has no edge) and carried by
       consistent flow (on average over the directions at least ``min_reliable`` = 30 % of the
       pixels pass the forward-backward check: texture that re-synthesises itself every
       frame, "boiling", is a background failure, not an object).
    5. **Parts**: components at most ``merge_px`` = 16 px apart whose median velocities differ
       by at most ``merge_speed_px`` = 1 px per frame plus ``merge_speed_share`` = 1 x the
       faster one's speed are parts of one mover (limbs, a body split by its own texture)
       and become one component.
    6. **Tracks**: each track's last mask, shifted by its median flow, is matched greedily to
       the components by overlap (``|A & B| / min(|A|, |B|)`` >= ``match_overlap`` = 0.3);
       tracks survive ``max_gap`` = 2 frames without a detection; hard cuts end all tracks. A
       track becomes an object once detected in ``min_track`` = 6 distinct frames (shorter
       tracks are flicker). A newly confirmed track takes over an existing id when it is a
       part of a confirmed track seen at most ``max_gap`` frames earlier (its centre inside
       that track's last box grown by ``merge_px``), or when it continues a confirmed track
       not seen in its latest frame and last seen at most ``link_gap`` = 60 frames earlier:
       its latest centre within ``link_radius`` = 1.5 object sizes plus ``link_speed_px`` = 6
       px per frame of the gap from where that track's velocity puts it, and colour
       histograms (8x8x8 RGB) within Bhattacharyya distance ``link_hist`` = 0.5; otherwise
       ids are 1, 2, ... in order of confirmation.
       ``labels(t)`` shows the components of frame t whose track is confirmed by the
       detections up to frame t + lookahead - 1, all known once frame t + lookahead was
       pushed, so labels never change once available.

    Duplicated frames copy the labels of the frame they repeat (no new evidence); pairs across
    hard cuts give none. ``regimes`` records the background model of each frame's forward
    pair. Memory: the last ``slow_gap`` reduced grey frames, one frame of scores and the reduced component
    maps of frames not yet released. Deterministic: seeded fits, and DIS is deterministic.
    """

    name = "motion"

    def __init__(
        self,
        info: ClipInfo,
        config: MotionConfig | None = None,
        *,
        flow: FlowBackend | None = None,
        seed: int = 0,
        **overrides: Any,
    ) -> None:
        super().__init__(info)
        self.config = cfg = replace(config or MotionConfig(), **overrides)
        self.flow: FlowBackend = flow if flow is not None else DisFlow()
        self.seed = int(seed)
        x0, y0, x1, y1 = info.content_box
        self._cw, self._ch = x1 - x0, y1 - y0
        aw, ah = cfg.analysis_size
        fit = min(1.0, aw / self._cw, ah / self._ch)
        self._rw = max(16, round(self._cw * fit))
        self._rh = max(16, round(self._ch * fit))
        self._s = self._rw / self._cw  # actual reduced / working factor
        pw, ph = cfg.px_reference
        ref = min(1.0, pw / self._cw, ph / self._ch)
        self._px = self._s / ref  # reduced px per px of a setting (see MotionConfig.px_reference)
        self._evidence = Evidence(cfg, self.flow, self.seed, self._rw, self._rh, self._px)
        self._regions = RegionFinder(cfg, self._rw * self._rh)
        self._tracker = Tracker(cfg, self._extra_warnings, self._px)
        self.lookahead = cfg.lookahead

        self._pushed = 0
        self._finished = False
        self._released = 0
        self._prev_gray: np.ndarray | None = None
        self._history: deque[np.ndarray] = deque(maxlen=max(1, cfg.slow_gap))  # last distinct grey frames
        self._slow: Side | None = None  # slow evidence of the pending frame
        self._rgb: dict[int, np.ndarray] = {}  # reduced colour frames not yet segmented
        self._prev_rep = -1  # representative (last distinct) frame of the previous frame
        self._pending: int | None = None  # representative frame waiting for its forward evidence
        self._pending_bwd: Side | None = None
        self._segs: dict[int, Segmentation] = {}
        self._rep_seg: Segmentation | None = None  # segmentation of the last distinct frame
        self._dups = frozenset(info.duplicates)
        self._cuts = frozenset(info.cuts)
        self._cache: tuple[int, np.ndarray] | None = None
        self.regimes: dict[int, str] = {}
        """Background model used for the forward pair of each frame (``H``, ``F``, ``static``)."""
        self._boiling: dict[int, np.ndarray] = {}  # unexplained pixels of frames not yet segmented
        self.dynamic: dict[int, float] = {}
        """Per frame, the share (0..1) of the content, outside the objects, whose flow to the next
        frame cannot be tracked back (:meth:`_unexplained`): a dynamic background
        (water, fire, smoke, foliage in wind) whose texture re-forms from frame to frame and obeys
        no camera. Measured where the background model of the frame's pair is a homography (a
        still, turning or zooming camera); a translating camera uncovers the background along
        every depth edge, and its frames are not measured (they count as 0 in the record's
        ``dynamic_share``)."""

    # -- streaming -------------------------------------------------------------------------

    def push(self, frame: Frame) -> None:
        p = frame.index
        if self._finished:
            raise ValueError("push() after finish()")
        if p != self._pushed:
            raise ValueError(f"frames must be pushed in order: expected frame {self._pushed}, got {p}")
        W, H = self.info.working_size
        if frame.gray.shape != (H, W):
            raise ValueError(
                f"frame {p} is {frame.gray.shape[1]}x{frame.gray.shape[0]}, expected the {W}x{H} working canvas"
            )
        self._pushed += 1
        if p > 0 and p in self._dups:
            # an exact repeat: same labels as the frame it repeats; no new evidence
            if self._pending is not None:
                self._segment(self._pending, self._pending_bwd, None)
                self._pending = None
            assert self._rep_seg is not None
            self._segs[p] = self._rep_seg  # kept even when the repeated frame was released
            return
        gray = self._reduce(frame.gray)
        self._rgb[p] = self._reduce(frame.rgb)
        bwd = None
        if p > 0 and p in self._cuts:
            if self._pending is not None:
                self._segment(self._pending, self._pending_bwd, None)
                self._pending = None
            self._tracker.cut()
            self._history.clear()
        elif p > 0:
            assert self._prev_gray is not None
            fwd, bwd = self._pair(self._prev_gray, gray, self._prev_rep, p)
            if self._pending is not None:
                self._segment(self._pending, self._pending_bwd, fwd)
                self._pending = None
        self._slow = self._slow_side(gray, p, bwd)
        self._history.append(gray)
        self._prev_gray, self._prev_rep = gray, p
        self._pending, self._pending_bwd = p, bwd

    def finish(self) -> None:
        if self._finished:
            return
        if self._pending is not None:
            self._segment(self._pending, self._pending_bwd, None)
            self._pending = None
        self._finished = True
        self._prev_gray = None

    def _available(self, t: int) -> bool:
        return self._finished or self._pushed >= t + self.lookahead + 1

    def labels(self, t: int) -> np.ndarray:
        if not 0 <= t < self.info.num_frames:
            raise IndexError(f"frame {t} is outside 0..{self.info.num_frames - 1}")
        if t < self._released:
            raise ValueError(f"labels of frame {t} were released")
        if self._finished and t >= self._pushed:
            raise ValueError(f"frame {t} was never pushed (finish() came after {self._pushed} frames)")
        if not self._available(t):
            raise ValueError(
                f"labels of frame {t} are not final before frame {t + self.lookahead} is pushed or finish() is called"
            )
        if self._cache is not None and self._cache[0] == t:
            return self._cache[1]
        seg = self._segs[t]
        lut = np.zeros(256, np.uint8)
        horizon = self._rep_horizon(t)
        by_tid = {tr.tid: tr for tr in self._tracker.tracks}
        for k, tid in enumerate(seg.tracks, start=1):
            tr = by_tid[tid]
            if tr.confirmed_at is not None and tr.confirmed_at <= horizon:
                lut[k] = tr.public
        W, H = self.info.working_size
        out = np.zeros((H, W), np.uint8)
        if lut.any():
            small = lut[seg.comps]
            x0, y0, x1, y1 = self.info.content_box
            out[y0:y1, x0:x1] = cv2.resize(small, (self._cw, self._ch), interpolation=cv2.INTER_NEAREST_EXACT)
        out.flags.writeable = False
        self._cache = (t, out)
        self._record(t, out)
        return out

    def _rep_horizon(self, t: int) -> int:
        """Tracks confirmed at a frame up to this one count for frame t: the frames segmented
        once frame t + lookahead is pushed."""
        return t + self.lookahead - 1

    def release(self, t: int) -> None:
        for k in [k for k in self._segs if k < t]:
            del self._segs[k]
        self._released = max(self._released, t)
        if self._cache is not None and self._cache[0] < t:
            self._cache = None
        # tracks that can no longer be referenced by a kept frame nor matched again
        segs = list(self._segs.values()) + ([self._rep_seg] if self._rep_seg is not None else [])
        self._tracker.prune({tid for s in segs for tid in s.tracks})

    @property
    def analysis_size(self) -> tuple[int, int]:
        """(width, height) of the image the segmentation analyses, px."""
        return (self._rw, self._rh)

    @property
    def px_scale(self) -> float:
        """Analysis pixels per pixel of a setting (see ``MotionConfig.px_reference``)."""
        return self._px

    def _reduce(self, gray: np.ndarray) -> np.ndarray:
        x0, y0, x1, y1 = self.info.content_box
        crop = gray[y0:y1, x0:x1]
        interp = cv2.INTER_AREA if self._s < 1.0 else cv2.INTER_LINEAR
        return cv2.resize(crop, (self._rw, self._rh), interpolation=interp)

    def _pair(self, g0: np.ndarray, g1: np.ndarray, t0: int, t1: int) -> tuple[Side | None, Side | None]:
        f, b = self._evidence.pair(g0, g1, t0, t1)
        self.regimes[t0] = f.regime if f is not None else "none"
        if f is not None and f.regime != "F":  # a translating camera's flow fails along its disocclusions
            self._boiling[t0] = self._unexplained(f)
        return f, b

    def _unexplained(self, fwd: Side) -> np.ndarray:
        """Pixels of the pair's first frame whose flow fails the forward-backward check, in blobs
        at least ``dynamic_open_px`` reduced px across: a texture that re-forms from frame to frame
        (water, fire, smoke) has no motion to track back, while the thin bands where an occluding
        edge uncovers the background are opened away."""
        bad = (~fwd.reliable).astype(np.uint8)
        k = max(1, int(self.config.dynamic_open_px))
        return cv2.morphologyEx(bad, cv2.MORPH_OPEN, np.ones((k, k), np.uint8)) > 0

    def _slow_side(self, gray: np.ndarray, p: int, bwd: Side | None) -> Side | None:
        """Evidence of frame p against the frame ``slow_gap`` distinct frames earlier, when the
        camera is still over that gap (the static regime) and the adjacent pair is static too."""
        k = self.config.slow_gap
        if k < 2 or len(self._history) < k or bwd is None or bwd.regime != "static":
            return None
        side = self._evidence.slow(gray, self._history[0], p)
        return side if side is not None and side.regime == "static" else None

    def _slow_score(self, slow: Side, bwd: Side) -> np.ndarray:
        """Slow-gap score where the flow over the gap is reliable and agrees with ``slow_gap``
        times the adjacent backward flow (a steady slow mover; flow errors in the wake of a
        fast one disagree), within ``min_px`` plus half its length; 0 elsewhere."""
        k = np.float32(self.config.slow_gap)
        diff = np.hypot(*(slow.flow - k * bwd.flow).transpose(2, 0, 1))
        tol = np.float32(self.config.min_px * self._px) + np.float32(0.5) * np.hypot(*slow.flow.transpose(2, 0, 1))
        ok = slow.reliable & bwd.reliable & (diff <= tol)
        return np.where(ok, slow.score, np.float32(0.0))

    def _segment(self, t: int, bwd: Side | None, fwd: Side | None) -> None:
        sides = [s for s in (fwd, bwd) if s is not None]
        comps = np.zeros((self._rh, self._rw), np.uint8)
        rgb = self._rgb.pop(t)
        masks: list[np.ndarray] = []
        if sides:
            score = sides[0].score if len(sides) == 1 else np.minimum(sides[0].score, sides[1].score)
            if self._slow is not None and bwd is not None:
                score = np.maximum(score, self._slow_score(self._slow, bwd))
            min_reliable = self.config.min_reliable
            for m in self._regions.objects(score):
                # flow that is not forward-backward consistent on most of the region is no
                # object moving: e.g. texture that re-synthesises itself every frame (boiling)
                if np.mean([np.count_nonzero(s.reliable[m]) for s in sides]) >= min_reliable * np.count_nonzero(m):
                    masks.append(m)
            boiling = self._boiling.pop(t, None)
            if boiling is not None:
                if masks:
                    boiling = boiling & ~np.logical_or.reduce(masks)
                self.dynamic[t] = float(np.count_nonzero(boiling)) / boiling.size
        vels = [_velocity(m, fwd, bwd) for m in masks]
        parts = merge_parts(masks, vels, self.config, self._px)[:MAX_ID]
        masks = [np.logical_or.reduce([masks[i] for i in g]) for g in parts]
        vels = [_velocity(m, fwd, bwd) for m in masks]
        for k, m in enumerate(masks, start=1):
            comps[m] = k
        seg = Segmentation(comps)
        self._segs[t] = self._rep_seg = seg
        seg.tracks = self._tracker.step(t, masks, vels, [colour_histogram(rgb, m) for m in masks])


def _velocity(m: np.ndarray, fwd: Side | None, bwd: Side | None) -> np.ndarray:
    if fwd is not None:
        return np.median(fwd.flow[m], axis=0).astype(np.float64)
    if bwd is not None:
        return -np.median(bwd.flow[m], axis=0).astype(np.float64)
    return np.zeros(2)
