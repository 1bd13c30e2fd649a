"""Moving-object masks behind one small streaming interface (SPEC section 2, "mask-first").

A :class:`MaskSource` turns the frames of a clip into label images at WORKING resolution:
``(H, W)`` uint8, 0 = background, ``k`` = object ``k`` (1..255), zero outside the content box.
The background mask of frame t is ``content & (labels(t) == 0)``.

>>> src = make_mask_source("motion", info)                  # doctest: +SKIP
>>> for frame in iter_frames(info):                          # doctest: +SKIP
...     src.push(frame)
...     t = frame.index - src.lookahead
...     if t >= 0:
...         labels = src.labels(t); src.release(t)
>>> src.finish()                                             # then the last frames  # doctest: +SKIP

Streaming contract: frames are pushed in order ``0 .. T-1``; ``labels(t)`` is final (the same
array whenever it is asked) once frame ``t + lookahead`` was pushed or after ``finish()``;
``release(t)`` promises that labels of frames ``< t`` are not asked again, so their memory is
freed. ``warnings`` lists problems found so far, e.g. masks covering more than
:data:`IMPLAUSIBLE_SHARE` of the content (one entry per clip, with the frame range).
``coverage`` maps each frame whose labels were produced to its masked share of the content.

Sources
-------
``external`` (:class:`ExternalMasks`, lookahead 0)
    Masks shipped with a data set, at SOURCE resolution (the size of the clip's decoded frames,
    ``info.source_size``). Three layouts, detected automatically:

    (a) a folder of label images ``00000.png, 00001.png, ...``: one PNG per frame, 8- or 16-bit
        single channel, 0 = background, k = object id (1..255); file names end in the frame
        number (any zero-padding, any common prefix), taken in natural order, numbered
        consecutively from 0 (or 1). This is what ``geocon synth`` writes as ``<clip>.masks/``.
    (b) a folder of per-object folders ``<id>/NNNNN.png`` or ``obj_<id>/NNNNN.png`` (id 1..255),
        each holding one binary mask per frame (nonzero = object), numbered like (a); where
        objects overlap, the higher id wins.
    (c) an ``.npz`` file with an integer array ``labels`` of shape (T, h, w), values 0..255.

    Every mask is mapped into the working canvas exactly like the reader maps frames (scale
    ``info.scale``, offset ``info.offset``, nearest-neighbour resize with centred pixels), then
    zeroed outside ``info.content_box``. A wrong frame count, a wrong size, missing frame files,
    colour images or ids above 255 raise ValueError with one sentence naming the problem.
    Layouts (a) and (b) read one frame at a time; (c) holds the array in memory.

``motion`` (:class:`MotionSegmenter`, lookahead 2, built in, no weights)
    Dense flow at half resolution, a robust background model per pair (homography, or a
    fundamental matrix with a cheirality check when a moving camera shows parallax), compact,
    sharply bounded residual regions, tracked into stable ids. Background failures
    (breathing, sliding layers, boiling texture) stay background. See the class docstring.

``sam2``
    Not available in this build: SAM-2 needs torch, the ``sam2`` package and a checkpoint, and
    :func:`make_mask_source` says so instead of pretending.
"""

from __future__ import annotations

import importlib.util
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import cv2
import numpy as np

from .flow import DisFlow, FlowBackend, FlowField
from .models import fit_fundamental, fit_homography
from .reader import ClipInfo, Frame, _layout

__all__ = [
    "MaskSource",
    "ExternalMasks",
    "MotionSegmenter",
    "MASK_SOURCES",
    "IMPLAUSIBLE_SHARE",
    "make_mask_source",
    "masked_share",
    "labels_to_canvas",
]

IMPLAUSIBLE_SHARE = 0.5
"""Masks covering more than this share of a frame's content are reported in ``warnings``."""

MAX_ID = 255

CHEIRALITY_MIN_SHARE = 0.6
"""The pose used for the cheirality residual must put at least this share of the fundamental
matrix's inlier vectors in front of both cameras; otherwise that residual is not used."""

F_FIT_POINTS = 600
"""About this many grid vectors feed a fundamental-matrix fit (every k-th one)."""


class MaskSource(Protocol):
    """Object label images, streamed (see the module docstring for the contract)."""

    name: str
    lookahead: int
    warnings: list[str]

    def push(self, frame: Frame) -> None: ...

    def finish(self) -> None: ...

    def labels(self, t: int) -> np.ndarray: ...

    def release(self, t: int) -> None: ...


def masked_share(labels: np.ndarray, content: np.ndarray) -> float:
    """Share of the ``content`` pixels ((H, W) bool) that ``labels`` ((H, W), 0 = background)
    marks as object; 0.0 for an empty content mask."""
    if labels.shape != content.shape:
        raise ValueError(f"labels {labels.shape} and content {content.shape} differ in size")
    n = int(np.count_nonzero(content))
    return 0.0 if n == 0 else int(np.count_nonzero((labels != 0) & content)) / n


def labels_to_canvas(src: np.ndarray, info: ClipInfo) -> np.ndarray:
    """A source-resolution label image (h, w) -> (H, W) uint8 in the working canvas: resized
    like the reader resizes frames (nearest neighbour, pixel centres aligned), placed at
    ``info.offset`` and zeroed outside ``info.content_box``."""
    w, h = info.source_size
    if src.shape != (h, w):
        raise ValueError(f"mask is {src.shape[1]}x{src.shape[0]} but the clip's frames are {w}x{h}")
    layout = _layout(info.source_size, info.working_size)
    sw, sh = layout.scaled_size
    ox, oy = info.offset
    lab = src if src.dtype == np.uint8 else src.astype(np.uint8)
    if (sw, sh) != (w, h):
        lab = cv2.resize(lab, (sw, sh), interpolation=cv2.INTER_NEAREST_EXACT)
    W, H = info.working_size
    out = np.zeros((H, W), np.uint8)
    x0, y0, x1, y1 = info.content_box
    out[y0:y1, x0:x1] = lab[y0 - oy : y1 - oy, x0 - ox : x1 - ox]
    return out


class _Coverage:
    """Per-frame masked share and the implausible-share warning (shared by the sources)."""

    def __init__(self, info: ClipInfo) -> None:
        self.info = info
        self.coverage: dict[int, float] = {}
        self._content = info.content_mask
        self._extra_warnings: list[str] = []

    def _record(self, t: int, labels: np.ndarray) -> None:
        if t not in self.coverage:
            self.coverage[t] = masked_share(labels, self._content)

    @property
    def warnings(self) -> list[str]:
        out = list(self._extra_warnings)
        bad = sorted(t for t, s in self.coverage.items() if s > IMPLAUSIBLE_SHARE)
        if bad:
            worst = max(self.coverage[t] for t in bad)
            out.append(
                f"{self.name} masks cover more than {IMPLAUSIBLE_SHARE:.0%} of the content in {len(bad)} "
                f"frame(s) (t={bad[0]}..{bad[-1]}, up to {worst:.0%}): implausible for moving objects"
            )
        return out


# --- external masks -------------------------------------------------------------------------

_DIGITS = re.compile(r"(\d+)$")
_OBJECT_DIR = re.compile(r"^(?:obj_)?(\d+)$", re.IGNORECASE)
_LAYOUTS = (
    "expected a folder of label PNGs (00000.png, ...), a folder of per-object folders "
    "(<id>/00000.png or obj_<id>/00000.png) or an .npz file with an array 'labels'"
)


def _frame_files(folder: Path, num_frames: int, what: str) -> list[Path]:
    """The PNGs of ``folder`` in frame order, checked to be numbered consecutively from 0 or 1
    and to be exactly ``num_frames``."""
    files = [p for p in folder.iterdir() if p.is_file() and p.suffix.lower() == ".png"]
    numbered: dict[int, Path] = {}
    for p in files:
        m = _DIGITS.search(p.stem)
        if m is None:
            raise ValueError(f"{p}: a mask file name must end in its frame number")
        k = int(m.group(1))
        if k in numbered:
            raise ValueError(f"{folder}: two mask files for frame {k} ({numbered[k].name}, {p.name})")
        numbered[k] = p
    if not numbered:
        raise ValueError(f"{folder}: holds no PNG {what}")
    idx = sorted(numbered)
    start = idx[0]
    if start not in (0, 1):
        raise ValueError(f"{folder}: mask frames must be numbered from 0 (or 1), the first is {numbered[start].name}")
    missing = sorted(set(range(start, start + max(num_frames, len(idx)))) - set(idx))
    if missing and missing[0] < idx[-1]:
        raise ValueError(f"{folder}: mask file of frame {missing[0] - start} is missing (found {len(idx)} {what})")
    if len(idx) != num_frames:
        raise ValueError(f"{folder}: has {len(idx)} {what} but the clip has {num_frames} frames")
    return [numbered[k] for k in idx]


def _read_png(path: Path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ValueError(f"{path}: cannot be read as an image")
    if img.ndim == 3:
        if img.shape[2] == 1 or all(np.array_equal(img[..., 0], img[..., c]) for c in range(1, min(3, img.shape[2]))):
            img = img[..., 0]
        else:
            raise ValueError(f"{path}: is a colour image; label masks must be single-channel 8- or 16-bit PNGs")
    if img.dtype not in (np.uint8, np.uint16):
        raise ValueError(f"{path}: has {img.dtype} pixels; label masks must be 8- or 16-bit")
    return img


def _check_ids(lab: np.ndarray, where: str) -> np.ndarray:
    if lab.size and int(lab.max()) > MAX_ID:
        raise ValueError(f"{where}: object id {int(lab.max())} is above {MAX_ID}")
    if lab.size and lab.dtype.kind == "i" and int(lab.min()) < 0:
        raise ValueError(f"{where}: negative label {int(lab.min())}")
    return lab.astype(np.uint8, copy=False)


def _check_size(img: np.ndarray, info: ClipInfo, where: str) -> None:
    w, h = info.source_size
    if img.shape[:2] != (h, w):
        raise ValueError(f"{where}: mask is {img.shape[1]}x{img.shape[0]} but the clip's frames are {w}x{h}")


class ExternalMasks(_Coverage):
    """Masks from files (``name = "external"``, lookahead 0); layouts in the module docstring.

    Labels do not depend on the pushed frames: ``labels(t)`` may be asked for any frame at any
    time (``push`` only checks the frame order)."""

    name = "external"
    lookahead = 0

    def __init__(self, path: str | Path, info: ClipInfo) -> None:
        super().__init__(info)
        self.path = Path(path)
        T = info.num_frames
        self._files: list[Path] | None = None
        self._objects: list[tuple[int, list[Path]]] | None = None
        self._array: np.ndarray | None = None
        self._next = 0
        self._cache: tuple[int, np.ndarray] | None = None
        p = self.path
        if not p.exists():
            raise ValueError(f"{p}: masks path does not exist")
        if p.is_file():
            if p.suffix.lower() != ".npz":
                raise ValueError(f"{p}: not a masks layout; {_LAYOUTS}")
            self.layout = "npz"
            self._array = self._load_npz(p, info)
        elif any(c.is_file() and c.suffix.lower() == ".png" for c in p.iterdir()):
            self.layout = "label_images"
            self._files = _frame_files(p, T, "label images")
            _check_size(_read_png(self._files[0]), info, str(self._files[0]))
        else:
            dirs = []
            for c in p.iterdir():
                m = _OBJECT_DIR.match(c.name)
                if c.is_dir() and m:
                    oid = int(m.group(1))
                    if not 1 <= oid <= MAX_ID:
                        raise ValueError(f"{c}: object id {oid} is outside 1..{MAX_ID}")
                    dirs.append((oid, c))
            if not dirs:
                raise ValueError(f"{p}: not a masks layout; {_LAYOUTS}")
            ids = [oid for oid, _ in dirs]
            if len(set(ids)) != len(ids):
                raise ValueError(f"{p}: two folders name the same object id")
            self.layout = "object_folders"
            self._objects = [(oid, _frame_files(d, T, "masks")) for oid, d in sorted(dirs)]
            for _, files in self._objects:
                _check_size(_read_png(files[0]), info, str(files[0]))

    @staticmethod
    def _load_npz(p: Path, info: ClipInfo) -> np.ndarray:
        try:
            with np.load(p, allow_pickle=False) as z:
                if "labels" not in z.files:
                    raise ValueError(f"{p}: has no array 'labels' (found {', '.join(z.files) or 'none'})")
                arr = z["labels"]
        except (OSError, EOFError) as err:
            raise ValueError(f"{p}: cannot be read as an .npz file ({err})") from None
        if arr.ndim != 3:
            raise ValueError(f"{p}: 'labels' must have shape (T, h, w), got {arr.shape}")
        if arr.dtype.kind not in "iub":
            raise ValueError(f"{p}: 'labels' must be integer, got {arr.dtype}")
        if arr.shape[0] != info.num_frames:
            raise ValueError(f"{p}: 'labels' has {arr.shape[0]} frames but the clip has {info.num_frames}")
        _check_size(arr[0], info, f"{p} 'labels'")
        return _check_ids(arr, f"{p} 'labels'")

    def _source_labels(self, t: int) -> np.ndarray:
        if self._array is not None:
            return self._array[t]
        if self._files is not None:
            f = self._files[t]
            img = _read_png(f)
            _check_size(img, self.info, str(f))
            return _check_ids(img, str(f))
        assert self._objects is not None
        w, h = self.info.source_size
        out = np.zeros((h, w), np.uint8)
        for oid, files in self._objects:  # ascending ids: the higher id wins where they overlap
            img = _read_png(files[t])
            _check_size(img, self.info, str(files[t]))
            out[img != 0] = oid
        return out

    def push(self, frame: Frame) -> None:
        if frame.index != self._next:
            raise ValueError(f"frames must be pushed in order: expected frame {self._next}, got {frame.index}")
        self._next += 1

    def finish(self) -> None:
        pass

    def labels(self, t: int) -> np.ndarray:
        if not 0 <= t < self.info.num_frames:
            raise IndexError(f"frame {t} is outside 0..{self.info.num_frames - 1}")
        if self._cache is not None and self._cache[0] == t:
            return self._cache[1]
        lab = labels_to_canvas(self._source_labels(t), self.info)
        lab.flags.writeable = False
        self._cache = (t, lab)
        self._record(t, lab)
        return lab

    def release(self, t: int) -> None:
        if self._cache is not None and self._cache[0] < t:
            self._cache = None


# --- built-in motion segmentation ---------------------------------------------------------


@dataclass
class _Side:
    """Motion evidence of one frame from one pair: residual / threshold per reduced pixel, the
    flow to the other frame, and the model that explained the background."""

    score: np.ndarray
    flow: np.ndarray
    reliable: np.ndarray
    direction: int  # +1: flow to a later frame, -1: to an earlier one
    regime: str  # "H", "F" or "static"
    threshold: float  # px at the reduced scale


@dataclass
class _Track:
    tid: int
    mask: np.ndarray  # (rh, rw) bool, at the last detection
    velocity: np.ndarray  # (2,) px per step at the reduced scale
    last_step: int
    count: int = 1
    public: int = 0
    confirmed_at: int | None = None


@dataclass
class _Seg:
    """Segmentation of one frame: accepted components (reduced map, 1..n) and their tracks."""

    comps: np.ndarray  # (rh, rw) uint8
    tracks: list[int] = field(default_factory=list)  # tid of component k + 1


class MotionSegmenter(_Coverage):
    """Built-in motion segmentation (``name = "motion"``, lookahead 2, no weights).

    Lengths below are working pixels unless marked *reduced* (pixels of the analysis scale).
    For every pair of consecutive distinct frames (t, t+1), at ``scale`` (default 1/2) of the
    working resolution, over the content box only:

    1. **Flow**: forward and backward dense flow (``flow``, default :class:`DisFlow`, medium
       preset) with the forward-backward reliability check.
    2. **Background model**, fitted separately to each direction on a grid of reliable flow
       vectors (every ``fit_step`` = 12 reduced px, about 1000 vectors at 1024x576) with
       OpenCV USAC (MAGSAC++, seeded, via :func:`geocon_core.models.fit_homography` and
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
       translating camera). Threshold ``max(k_sigma * sigma, min_px)`` with ``sigma = 1.4826 *
       median`` grid residual, ``k_sigma`` = 4, ``min_px`` = 2 px per frame: a breathing or
       drifting background moves less than that per frame (and is, if it moves more, still
       smooth; see 4) and is left to the scorer, which reports it as a failure. Frame t's
       score is residual / threshold from the pair (t, t+1) and from the backward pair
       (t, t-1); where both exist their minimum is taken, which removes the occlusion strips
       ahead of and behind a moving object (only one direction is occluded there).
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
    5. **Tracks**: each track's last mask, shifted by its median flow, is matched greedily to
       the components by overlap (``|A & B| / min(|A|, |B|)`` >= ``match_overlap`` = 0.3);
       tracks survive ``max_gap`` = 2 frames without a detection; hard cuts end all tracks. A
       track becomes an object once detected in ``min_track`` = 2 distinct frames (each
       detection already needs consistent motion over three frames, t-1..t+1, so a confirmed
       object moved coherently over at least four); object ids are 1, 2, ... in order of
       confirmation. ``labels(t)`` shows the components of frame t whose track is confirmed
       by the detections up to frame t + 1, all known once frame t + 2 was pushed
       (lookahead 2), so labels never change once available.

    Duplicated frames copy the labels of the frame they repeat (no new evidence); pairs across
    hard cuts give none. ``regimes`` records the background model of each frame's forward
    pair. Memory: the last reduced grey frame, one frame of scores and the reduced component
    maps of frames not yet released. Deterministic: seeded fits, and DIS is deterministic.
    """

    name = "motion"
    lookahead = 2

    def __init__(
        self,
        info: ClipInfo,
        *,
        flow: FlowBackend | None = None,
        scale: float = 0.5,
        seed: int = 0,
        fit_step: int = 12,
        fit_tau_px: float = 1.0,
        static_px: float = 0.5,
        f_gain: float = 0.05,
        k_sigma: float = 4.0,
        min_px: float = 2.0,
        min_area: float = 0.001,
        max_area: float = 0.35,
        min_solidity: float = 0.5,
        min_thickness: float = 2.0,
        edge_ratio: float = 0.5,
        refine: float = 0.5,
        halo_px: int = 6,
        min_reliable: float = 0.3,
        fov_deg: float = 60.0,
        match_overlap: float = 0.3,
        max_gap: int = 2,
        min_track: int = 2,
    ) -> None:
        super().__init__(info)
        if not 0.05 <= scale <= 1.0:
            raise ValueError(f"scale must be in [0.05, 1], got {scale}")
        if min_track < 1:
            raise ValueError(f"min_track must be at least 1, got {min_track}")
        self.flow: FlowBackend = flow if flow is not None else DisFlow()
        self.scale = float(scale)
        self.seed = int(seed)
        self.fit_step = int(fit_step)
        self.fit_tau_px, self.static_px, self.f_gain = float(fit_tau_px), float(static_px), float(f_gain)
        self.k_sigma, self.min_px = float(k_sigma), float(min_px)
        self.min_area, self.max_area = float(min_area), float(max_area)
        self.min_solidity, self.min_thickness, self.edge_ratio = (
            float(min_solidity),
            float(min_thickness),
            float(edge_ratio),
        )
        self.refine = float(refine)
        self.halo_px = int(halo_px)
        self._halo_kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * self.halo_px + 1, 2 * self.halo_px + 1))
        self.min_reliable = float(min_reliable)
        if not 1.0 < fov_deg < 179.0:
            raise ValueError(f"fov_deg must be in (1, 179), got {fov_deg}")
        self.fov_deg = float(fov_deg)
        self.match_overlap, self.max_gap, self.min_track = float(match_overlap), int(max_gap), int(min_track)

        x0, y0, x1, y1 = info.content_box
        self._cw, self._ch = x1 - x0, y1 - y0
        self._rw = max(16, round(self._cw * self.scale))
        self._rh = max(16, round(self._ch * self.scale))
        self._s = self._rw / self._cw  # actual reduced / working factor
        area = self._rw * self._rh
        self._min_area_px = max(16, round(self.min_area * area))
        self._max_area_px = self.max_area * area

        self._pushed = 0
        self._finished = False
        self._released = 0
        self._prev_gray: np.ndarray | None = None
        self._prev_rep = -1  # representative (last distinct) frame of the previous frame
        self._pending: int | None = None  # representative frame waiting for its forward evidence
        self._pending_bwd: _Side | None = None
        self._segs: dict[int, _Seg] = {}
        self._rep_seg: _Seg | None = None  # segmentation of the last distinct frame
        self._step = 0  # tracking steps (distinct frames segmented)
        self._tracks: list[_Track] = []
        self._alive: list[_Track] = []
        self._next_tid = 1
        self._next_public = 1
        self._dups = frozenset(info.duplicates)
        self._cuts = frozenset(info.cuts)
        self._cache: tuple[int, np.ndarray] | None = None
        self._gxy: tuple[np.ndarray, np.ndarray] | None = None
        f = 0.5 * self._rw / math.tan(math.radians(self.fov_deg) / 2.0)
        self._K = np.array([[f, 0.0, (self._rw - 1) / 2.0], [0.0, f, (self._rh - 1) / 2.0], [0.0, 0.0, 1.0]])
        self._Kinv = np.linalg.inv(self._K)
        self.regimes: dict[int, str] = {}
        """Background model used for the forward pair of each frame (``H``, ``F``, ``static``)."""

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
        bwd = None
        if p > 0 and p in self._cuts:
            if self._pending is not None:
                self._segment(self._pending, self._pending_bwd, None)
                self._pending = None
            self._alive = []  # a cut ends every track
        elif p > 0:
            assert self._prev_gray is not None
            fwd, bwd = self._pair(self._prev_gray, gray, self._prev_rep, p)
            if self._pending is not None:
                self._segment(self._pending, self._pending_bwd, fwd)
                self._pending = None
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
        by_tid = {tr.tid: tr for tr in self._tracks}
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
        keep = {tid for s in segs for tid in s.tracks} | {tr.tid for tr in self._alive}
        self._tracks = [tr for tr in self._tracks if tr.tid in keep]

    # -- evidence ----------------------------------------------------------------------------

    def _reduce(self, gray: np.ndarray) -> np.ndarray:
        x0, y0, x1, y1 = self.info.content_box
        crop = gray[y0:y1, x0:x1]
        interp = cv2.INTER_AREA if self._s < 1.0 else cv2.INTER_LINEAR
        return cv2.resize(crop, (self._rw, self._rh), interpolation=interp)

    def _pair(self, g0: np.ndarray, g1: np.ndarray, t0: int, t1: int) -> tuple[_Side | None, _Side | None]:
        both = getattr(self.flow, "compute_both", None)
        if both is not None:
            fwd, bwd = both(g0, g1)
        else:
            fwd, bwd = self.flow.compute(g0, g1), self.flow.compute(g1, g0)
        f = self._side(fwd, +1, self.seed * 7919 + 2 * t0)
        b = self._side(bwd, -1, self.seed * 7919 + 2 * t1 + 1)
        self.regimes[t0] = f.regime if f is not None else "none"
        return f, b

    def _side(self, field: FlowField, direction: int, seed: int) -> _Side | None:
        flow, rel = field.flow, field.reliable
        h, w = rel.shape
        st = self.fit_step
        ys, xs = np.mgrid[st // 2 : h : st, st // 2 : w : st]
        ok = rel[ys, xs]
        if np.count_nonzero(ok) < 30:
            return None
        p1 = np.stack([xs[ok], ys[ok]], axis=1).astype(np.float64)
        p2 = p1 + flow[ys[ok], xs[ok]].astype(np.float64)
        tau = self.fit_tau_px * self._s
        seed &= 0x7FFFFFFF
        fh = fit_homography(p1, p2, tau=tau, min_inliers=30, seed=seed, iters=1000)
        if fh.model is None or not fh.valid:
            return None
        Hm = fh.model
        n = p1.shape[0]
        n_h = fh.n_inliers
        moved = _apply_h(Hm, p1) - p1  # where the data are: extrapolated corners are noisy
        static = bool(np.percentile(np.hypot(moved[:, 0], moved[:, 1]), 95) <= self.static_px * self._s)
        regime = "static" if static else "H"
        Fm = None
        if not static and n - n_h >= self.f_gain * n:
            sub = slice(None, None, max(1, n // F_FIT_POINTS))  # every k-th vector: F fits are costly
            ff = fit_fundamental(p1[sub], p2[sub], tau=0.1, min_inliers=30, iters=1000, proposal_px=tau)
            if ff.model is not None:
                d = _epipolar_distance(ff.model, p1, p2)
                n_f = int(np.count_nonzero(d <= tau))
                if n_f - n_h >= max(self.f_gain * n, 0.5 * (n - n_h)):
                    Fm, regime = ff.model, "F"
        gx, gy = self._grid()
        x2, y2 = gx + flow[..., 0], gy + flow[..., 1]
        M = (Fm if Fm is not None else Hm).astype(np.float32)
        a = M[0, 0] * gx + M[0, 1] * gy + M[0, 2]
        b = M[1, 0] * gx + M[1, 1] * gy + M[1, 2]
        c = M[2, 0] * gx + M[2, 1] * gy + M[2, 2]
        if Fm is not None:  # distance of x2 to the epipolar line (a, b, c) = F x1
            res = np.abs(a * x2 + b * y2 + c) / np.maximum(np.sqrt(a * a + b * b), np.float32(1e-12))
            grid = _epipolar_distance(Fm, p1, p2)
            inl = grid <= tau
            wrong = self._wrong_way(Fm, p1[inl], p2[inl], x2, y2)
            if wrong is not None:
                res = np.maximum(res, wrong)
        else:  # transfer error |x2 - H x1|
            res = np.hypot(x2 - a / c, y2 - b / c)
            grid = np.hypot(*(p2 - _apply_h(Hm, p1)).T)
        sigma = 1.4826 * float(np.median(grid))
        thr = max(self.k_sigma * sigma, self.min_px * self._s)
        score = (res * np.float32(1.0 / thr)).astype(np.float32)
        return _Side(score=score, flow=flow, reliable=rel, direction=direction, regime=regime, threshold=thr)

    def _wrong_way(
        self, Fm: np.ndarray, p1: np.ndarray, p2: np.ndarray, x2: np.ndarray, y2: np.ndarray
    ) -> np.ndarray | None:
        """Parallax against cheirality (px, (h, w)), or None when the pose is ambiguous.

        The epipolar distance cannot see motion along the epipolar lines, e.g. an object
        moving against the flow of a translating camera. With the default intrinsics ``K``
        (``fov_deg`` horizontal field of view over the content, principal point at its
        centre), ``E = K^T F K`` is decomposed into the (R, t) that puts most grid vectors
        (``p1 -> p2``, the fundamental matrix's inliers) in front of both cameras. A static
        point at depth Z then maps to ``x2 ~ Z a + e`` with ``a = K R K^-1 x1`` and ``e = K t``:
        its parallax from the point at infinity ``a`` points along ``e_xy - e_z a``
        (normalised ``a``), never against it. The component against it is returned."""
        K, Kinv = self._K, self._Kinv
        E = K.T @ Fm @ K
        try:
            R1, R2, tt = cv2.decomposeEssentialMat(E)
        except cv2.error:
            return None
        tt = tt.ravel()
        n1 = np.c_[p1, np.ones(len(p1))] @ Kinv.T
        n2 = np.c_[p2, np.ones(len(p2))] @ Kinv.T
        best, votes = None, -1
        for R, t in ((R1, tt), (R1, -tt), (R2, tt), (R2, -tt)):
            # depths from z2 n2 = z1 R n1 + t, least squares per point
            u, v = n1 @ R.T, -n2
            uu, uv, vv = np.sum(u * u, 1), np.sum(u * v, 1), np.sum(v * v, 1)
            ut, vt = u @ t, v @ t
            det = uu * vv - uv * uv
            with np.errstate(divide="ignore", invalid="ignore"):
                z1 = (-ut * vv + vt * uv) / det
                z2 = (-vt * uu + ut * uv) / det
            k = int(np.count_nonzero((z1 > 0) & (z2 > 0)))
            if k > votes:
                best, votes = (R, t), k
        if best is None or votes < CHEIRALITY_MIN_SHARE * len(p1):
            return None
        R, t = best
        Hinf = (K @ R @ Kinv).astype(np.float32)
        e = (K @ t).astype(np.float32)
        gx, gy = self._grid()
        c = Hinf[2, 0] * gx + Hinf[2, 1] * gy + Hinf[2, 2]
        ax = (Hinf[0, 0] * gx + Hinf[0, 1] * gy + Hinf[0, 2]) / c
        ay = (Hinf[1, 0] * gx + Hinf[1, 1] * gy + Hinf[1, 2]) / c
        dx, dy = e[0] - e[2] * ax, e[1] - e[2] * ay
        along = ((x2 - ax) * dx + (y2 - ay) * dy) / np.maximum(np.sqrt(dx * dx + dy * dy), np.float32(1e-12))
        return np.maximum(-along, np.float32(0.0))

    def _grid(self) -> tuple[np.ndarray, np.ndarray]:
        if self._gxy is None:
            gx, gy = np.meshgrid(np.arange(self._rw, dtype=np.float32), np.arange(self._rh, dtype=np.float32))
            self._gxy = (gx, gy)
        return self._gxy

    # -- objects -----------------------------------------------------------------------------

    def _segment(self, t: int, bwd: _Side | None, fwd: _Side | None) -> None:
        sides = [s for s in (fwd, bwd) if s is not None]
        rh, rw = self._rh, self._rw
        comps = np.zeros((rh, rw), np.uint8)
        masks: list[np.ndarray] = []
        if sides:
            score = sides[0].score if len(sides) == 1 else np.minimum(sides[0].score, sides[1].score)
            for m in self._objects(score):
                # flow that is not forward-backward consistent on most of the region is no
                # object moving: e.g. texture that re-synthesises itself every frame (boiling)
                if np.mean([np.count_nonzero(s.reliable[m]) for s in sides]) < self.min_reliable * np.count_nonzero(m):
                    continue
                if len(masks) >= MAX_ID:
                    break
                comps[m] = len(masks) + 1
                masks.append(m)
        seg = _Seg(comps)
        self._segs[t] = self._rep_seg = seg
        seg.tracks = self._track(t, masks, [self._velocity(m, fwd, bwd) for m in masks])

    def _objects(self, score: np.ndarray) -> list[np.ndarray]:
        """Accepted object masks ((rh, rw) bool) of one frame's score map, in raster order of
        their first pixel.

        Flow is smoothed across object edges, so the residual falls off gradually around an
        object (a halo of a few pixels). A pixel is kept only where its score reaches
        ``refine`` (half) of the highest score within ``halo_px`` (a local half-maximum
        boundary): this trims the halo and separates objects whose halos touch, while a
        smooth change of score inside an object (a turning card) keeps the object whole."""
        level = cv2.dilate(score, self._halo_kernel)
        keep = (score >= 1.0) & (score >= self.refine * level)
        binary = cv2.morphologyEx(keep.astype(np.uint8), cv2.MORPH_OPEN, _ELLIPSE3)
        binary = cv2.morphologyEx(binary, cv2.MORPH_CLOSE, _ELLIPSE5)
        binary[(score >= 1.0) & ~keep] = 0  # closing fills holes, never a trimmed halo
        n, cc, stats, _ = cv2.connectedComponentsWithStats(binary, connectivity=8)
        rh, rw = score.shape
        out: list[np.ndarray] = []
        pad = 8
        for k in range(1, n):
            area = int(stats[k, cv2.CC_STAT_AREA])
            if not self._min_area_px <= area <= self._max_area_px:
                continue
            x, y, bw, bh = (
                int(stats[k, i]) for i in (cv2.CC_STAT_LEFT, cv2.CC_STAT_TOP, cv2.CC_STAT_WIDTH, cv2.CC_STAT_HEIGHT)
            )
            X0, Y0, X1, Y1 = max(0, x - pad), max(0, y - pad), min(rw, x + bw + pad), min(rh, y + bh + pad)
            piece = cc[Y0:Y1, X0:X1] == k
            if self._accept(piece, score[Y0:Y1, X0:X1], area):
                full = np.zeros((rh, rw), bool)
                full[Y0:Y1, X0:X1] = piece
                out.append(full)
        return out

    def _accept(self, piece: np.ndarray, sc: np.ndarray, area: int) -> bool:
        """Compact (solidity, thickness) and sharply bounded (ring vs inside score)."""
        m = piece.astype(np.uint8)
        contours, _ = cv2.findContours(m, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        hull = cv2.convexHull(np.concatenate(contours))
        if area / max(float(cv2.contourArea(hull)), 1.0) < self.min_solidity:
            return False
        core = cv2.distanceTransform(np.pad(m, 1), cv2.DIST_L2, 5)
        if float(core.max()) < self.min_thickness:
            return False
        near = cv2.dilate(m, _ELLIPSE5)
        far = cv2.dilate(m, _ELLIPSE13)
        ring = (far > 0) & (near == 0)
        if np.count_nonzero(ring) < 8:
            return True
        return float(np.median(sc[ring])) <= self.edge_ratio * float(np.median(sc[piece]))

    def _velocity(self, m: np.ndarray, fwd: _Side | None, bwd: _Side | None) -> np.ndarray:
        if fwd is not None:
            return np.median(fwd.flow[m], axis=0).astype(np.float64)
        if bwd is not None:
            return -np.median(bwd.flow[m], axis=0).astype(np.float64)
        return np.zeros(2)

    def _track(self, t: int, masks: list[np.ndarray], vels: list[np.ndarray]) -> list[int]:
        self._step += 1
        step = self._step
        alive = [tr for tr in self._alive if step - tr.last_step <= self.max_gap + 1]
        cand = []
        for i, tr in enumerate(alive):
            pred = _shift(tr.mask, tr.velocity * (step - tr.last_step))
            npred = int(np.count_nonzero(pred))
            for j, m in enumerate(masks):
                inter = int(np.count_nonzero(pred & m))
                if inter == 0 or npred == 0:
                    continue
                ov = inter / min(npred, int(np.count_nonzero(m)))
                if ov >= self.match_overlap:
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
        for j, m in enumerate(masks):
            if out[j]:
                continue
            tr = _Track(tid=self._next_tid, mask=m, velocity=vels[j], last_step=step)
            self._next_tid += 1
            self._tracks.append(tr)
            alive.append(tr)
            out[j] = tr.tid
        for tr in alive:  # confirm, in order of creation
            if tr.confirmed_at is None and tr.count >= self.min_track:
                if self._next_public > MAX_ID:
                    msg = f"more than {MAX_ID} moving objects: later ones are not labelled"
                    if msg not in self._extra_warnings:
                        self._extra_warnings.append(msg)
                    continue
                tr.confirmed_at, tr.public = t, self._next_public
                self._next_public += 1
        self._alive = alive
        return out


_ELLIPSE3 = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (3, 3))
_ELLIPSE5 = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5))
_ELLIPSE13 = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (13, 13))


def _apply_h(H: np.ndarray, x: np.ndarray) -> np.ndarray:
    p = x @ H[:, :2].T + H[:, 2]
    return p[:, :2] / p[:, 2:3]


def _epipolar_distance(F: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    """Distance (px) of each x2 to the epipolar line ``F x1``."""
    l = x1 @ F[:, :2].T + F[:, 2]
    num = np.abs(np.sum(x2 * l[:, :2], axis=1) + l[:, 2])
    return num / np.maximum(np.hypot(l[:, 0], l[:, 1]), 1e-12)


def _shift(mask: np.ndarray, d: np.ndarray) -> np.ndarray:
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


# --- registry -------------------------------------------------------------------------------

MASK_SOURCES: dict[str, type] = {"external": ExternalMasks, "motion": MotionSegmenter}
"""Available mask sources by name."""


def _sam2_missing() -> str:
    have = [m for m in ("torch", "sam2") if importlib.util.find_spec(m) is not None]
    state = f"{' and '.join(have)} installed but " if have else ""
    return (
        "SAM-2 needs torch, the sam2 package and a checkpoint, which are not available in this build "
        f"({state}no checkpoint or loader is shipped); use one of: {', '.join(MASK_SOURCES)}"
    )


def make_mask_source(name: str, info: ClipInfo, **kwargs: Any) -> MaskSource:
    """The mask source called ``name`` for the clip of ``info``: ``external`` (``path=...``,
    see :class:`ExternalMasks`) or ``motion`` (tunables of :class:`MotionSegmenter`). Raises
    ValueError for ``sam2`` (not in this build) and for unknown names, listing the valid ones."""
    key = str(name).strip().lower()
    if key in ("sam2", "sam-2"):
        raise ValueError(_sam2_missing())
    if key not in MASK_SOURCES:
        raise ValueError(
            f"unknown mask source {name!r}; valid: {', '.join(MASK_SOURCES)} (sam2 needs torch, the sam2 package and a checkpoint)"
        )
    if key == "external":
        if "path" not in kwargs:
            raise ValueError("external masks need path=... (a folder of label PNGs, per-object folders or an .npz)")
        extra = set(kwargs) - {"path"}
        if extra:
            raise ValueError(f"external masks take only path=..., got also {', '.join(sorted(extra))}")
        return ExternalMasks(kwargs["path"], info)
    return MotionSegmenter(info, **kwargs)
