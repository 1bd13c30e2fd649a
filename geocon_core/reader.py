"""Reading clips (SPEC section 0): one streaming probe pass, then one streaming frame pass.

>>> info = probe_clip("clip.mp4")                      # doctest: +SKIP
>>> for frame in iter_frames(info):                     # doctest: +SKIP
...     frame.rgb, frame.gray, frame.content            # (H, W, 3), (H, W), (H, W) bool

:func:`probe_clip` decodes the clip once, holding at most two decoded frames, and returns a
:class:`ClipInfo`: the frame count (counted, never taken from container metadata), the
working-resolution layout (scale, centred offset, content box), black bars burned into the
source, duplicated frames and hard cuts. :func:`iter_frames` decodes it a second time and yields
every frame letterboxed into the working canvas (``config.working_size``), padding black.

Inputs: mp4 / avi / mov / webm / gif (OpenCV's FFmpeg backend) and folders of PNG or JPEG
frames in natural order (``frame_2`` before ``frame_10``). Unusable input raises
:class:`ClipError`, whose message is one sentence that names the file.

Coordinates: source pixels are those of the decoded frames, (w, h); working pixels are those of
the canvas, (W, H). A source pixel edge ``x`` maps to ``offset + x * scale`` in working pixels
(pixel centres at integer coordinates, as in the rest of GeoCon: centre ``u`` maps to
``offset + (u + 0.5) * scale - 0.5``), up to the rounding of the scaled size to whole pixels
(under half a working pixel).
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterator
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any, Literal

import cv2
import numpy as np

from .config import ScoreConfig

__all__ = [
    "ClipError",
    "ClipInfo",
    "ClipKind",
    "Frame",
    "IMAGE_SUFFIXES",
    "SkipReason",
    "check_clip",
    "iter_frames",
    "probe_clip",
]

ClipKind = Literal["video", "gif", "images"]
SkipReason = Literal["duplicate_frame", "hard_cut"]

IMAGE_SUFFIXES: frozenset[str] = frozenset({".png", ".jpg", ".jpeg"})
"""File suffixes (lower case) read as frames of an image folder."""

DEFAULT_FPS = 24.0
"""Frame rate for image folders and for containers that report none."""
MIN_CONTENT_SHARE = 0.3
"""Bars that would leave less than this share of the height or width mean a dark clip: no bars."""
BAR_MARGIN_PX = 2
"""Working pixels dropped from the content box on each side that has a burned-in bar (codec
ringing at the bar edge)."""

CUT_THUMB_WIDTH = 64
"""Width (px) of the grey thumbnails compared for hard cuts; height keeps the aspect ratio."""
CUT_HIST_BINS = 32
"""Grey-level histogram bins of a thumbnail."""
CUT_MIN_DISTANCE = 0.1
"""A hard cut between two frames needs all of: a Bhattacharyya distance between their thumbnail
histograms above this (0..1)...,"""
CUT_MIN_MAD = 20.0
"""...a thumbnail mean absolute difference above this (grey levels)...,"""
CUT_MEDIAN_FACTOR = 2.5
"""...a distance above this many times the median distance of the clip's other pairs...,"""
CUT_NEIGHBOUR_FACTOR = 2.0
"""...and above this many times the larger distance of the adjacent pairs (a cut is an isolated
spike; a fast pan or a passing occluder raises several consecutive distances)."""
CUT_LONE_DISTANCE = 0.35
"""The distance a pair needs when the clip has no other pair to compare it with."""

_VIDEO_MAGIC = (b"GIF87a", b"GIF89a", b"RIFF", b"\x1aE\xdf\xa3", b"OggS", b"FLV")
_MP4_BOXES = (b"ftyp", b"moov", b"mdat", b"free", b"wide", b"skip", b"pnot")


class ClipError(ValueError):
    """Unusable input. ``str(err)`` is one sentence that names the file, e.g.
    ``"clip.mp4: no such file"`` or ``"one.png: has 1 frame; at least 2 are needed"``."""


@dataclass(frozen=True)
class ClipInfo:
    """What the probe pass learnt about a clip; enough to read it again (:func:`iter_frames`).

    Sizes are (width, height). ``bars`` are in source pixels, ``content_box`` in working
    pixels, end-exclusive. Frames are indexed ``0 .. num_frames - 1``; ``duplicates`` and
    ``cuts`` hold indices ``t >= 1`` that refer to the pair (t - 1, t)."""

    path: str
    """The path as the user gave it."""
    kind: ClipKind
    """``"video"``, ``"gif"`` or ``"images"`` (a folder of PNG/JPEG frames)."""
    source_size: tuple[int, int]
    """(w, h) of the decoded source frames, px."""
    fps: float
    """Frames per second from the container; 24.0 for image folders and when unknown."""
    num_frames: int
    """Frames actually decoded (>= 2)."""
    working_size: tuple[int, int]
    """(W, H) of the canvas every frame is letterboxed into (``config.working_size``)."""
    scale: float
    """Source px -> working px: ``min(W / w, H / h)``."""
    offset: tuple[int, int]
    """(ox, oy): top-left working pixel of the scaled source inside the canvas (centred)."""
    bars: tuple[int, int, int, int]
    """Burned-in black bars, source px: (top, bottom, left, right) rows/columns."""
    content_box: tuple[int, int, int, int]
    """(x0, y0, x1, y1), end-exclusive, working px: the scaled source minus padding minus
    burned-in bars, shrunk by :data:`BAR_MARGIN_PX` on every side that has a bar."""
    duplicates: tuple[int, ...] = ()
    """Sorted t (>= 1) such that frame t duplicates frame t - 1."""
    cuts: tuple[int, ...] = ()
    """Sorted t (>= 1) such that a hard cut lies between frame t - 1 and frame t."""

    def __post_init__(self) -> None:
        if self.kind not in ("video", "gif", "images"):
            raise ValueError(f"kind must be video, gif or images, got {self.kind!r}")
        if self.num_frames < 2:
            raise ValueError(f"a clip needs at least 2 frames, got {self.num_frames}")
        for name, n in (("source_size", 2), ("working_size", 2), ("offset", 2), ("bars", 4), ("content_box", 4)):
            value = getattr(self, name)
            if not isinstance(value, tuple) or len(value) != n:
                raise ValueError(f"{name} must be a tuple of {n} ints, got {value!r}")
        x0, y0, x1, y1 = self.content_box
        W, H = self.working_size
        if not (0 <= x0 < x1 <= W and 0 <= y0 < y1 <= H):
            raise ValueError(f"content_box {self.content_box} is empty or outside the {W}x{H} canvas")
        for name in ("duplicates", "cuts"):
            ts = getattr(self, name)
            if (
                not isinstance(ts, tuple)
                or list(ts) != sorted(set(ts))
                or any(not 1 <= t < self.num_frames for t in ts)
            ):
                raise ValueError(
                    f"{name} must be sorted distinct frame indices in 1..{self.num_frames - 1}, got {ts!r}"
                )

    @property
    def content_mask(self) -> np.ndarray:
        """(H, W) bool, True inside :attr:`content_box`. A new array on each call."""
        W, H = self.working_size
        x0, y0, x1, y1 = self.content_box
        mask = np.zeros((H, W), dtype=bool)
        mask[y0:y1, x0:x1] = True
        return mask

    def pair_skip_reason(self, t0: int, t1: int) -> SkipReason | None:
        """Why the frame pair (t0, t1), ``0 <= t0 < t1 < num_frames``, must not be scored:
        ``"duplicate_frame"`` if every frame in ``t0 + 1 .. t1`` duplicates its predecessor (the
        two frames are identical), ``"hard_cut"`` if a cut ``c`` has ``t0 < c <= t1``, else None."""
        if not 0 <= t0 < t1 < self.num_frames:
            raise ValueError(f"need 0 <= t0 < t1 < {self.num_frames}, got ({t0}, {t1})")
        dup = set(self.duplicates)
        if all(t in dup for t in range(t0 + 1, t1 + 1)):
            return "duplicate_frame"
        if any(t0 < c <= t1 for c in self.cuts):
            return "hard_cut"
        return None

    def to_dict(self) -> dict[str, Any]:
        """JSON-able dict (tuples become lists); :meth:`from_dict` inverts it exactly."""
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "ClipInfo":
        """The :class:`ClipInfo` that :meth:`to_dict` made ``d`` from."""
        names = {f.name for f in fields(cls)}
        unknown, missing = set(d) - names, names - set(d)
        if unknown or missing:
            raise ValueError(f"ClipInfo keys: unknown {sorted(unknown)}, missing {sorted(missing)}")
        kw = {k: tuple(int(x) for x in v) if isinstance(v, list) else v for k, v in d.items()}
        kw["fps"], kw["scale"], kw["num_frames"] = float(d["fps"]), float(d["scale"]), int(d["num_frames"])
        return cls(**kw)


@dataclass(frozen=True, eq=False)
class Frame:
    """One frame at working resolution (W, H) = ``info.working_size``."""

    index: int
    """Frame index t, 0-based."""
    rgb: np.ndarray
    """(H, W, 3) uint8 RGB, the source letterboxed into the canvas (padding black)."""
    gray: np.ndarray
    """(H, W) uint8 luma of :attr:`rgb`."""
    content: np.ndarray
    """(H, W) bool, True inside ``info.content_box``; one array shared by all frames of a clip
    (do not modify it)."""


@dataclass(frozen=True)
class _Layout:
    """Where the scaled source lies in the canvas: size (sw, sh) at (ox, oy), working px."""

    scale: float
    scaled_size: tuple[int, int]
    offset: tuple[int, int]


def probe_clip(path: str | Path, config: ScoreConfig = ScoreConfig()) -> ClipInfo:
    """One streaming pass over the clip at ``path`` (a video/GIF file or a folder of PNG/JPEG
    frames), holding at most two decoded frames: counts the frames and detects burned-in bars,
    duplicated frames and hard cuts. Deterministic. Raises :class:`ClipError` for unusable input."""
    name = str(path)
    kind, files = _resolve(Path(path), name)
    fps = DEFAULT_FPS
    row_max: np.ndarray | None = None
    col_max: np.ndarray | None = None
    prev_gray = prev_thumb = prev_hist = None
    dup_flags: list[bool] = []
    hist_dist: list[float] = []
    thumb_mad: list[float] = []
    n = 0
    size = (0, 0)
    frames = _image_frames(files, name) if files is not None else None
    if frames is None:
        fps, frames = _open_video(name)
    for bgr in frames:
        gray = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
        h, w = gray.shape
        if n == 0:
            size = (w, h)
        elif (w, h) != size:
            which = f"frame {n}" if files is None else f"frame {n} ({files[n].name})"
            raise ClipError(f"{name}: {which} is {w}x{h} but frame 0 is {size[0]}x{size[1]}")
        rows = cv2.reduce(gray, 1, cv2.REDUCE_AVG, dtype=cv2.CV_32F).ravel()
        cols = cv2.reduce(gray, 0, cv2.REDUCE_AVG, dtype=cv2.CV_32F).ravel()
        row_max = rows if row_max is None else np.maximum(row_max, rows)
        col_max = cols if col_max is None else np.maximum(col_max, cols)
        thumb = _thumbnail(gray)
        hist = cv2.calcHist([thumb], [0], None, [CUT_HIST_BINS], [0, 256])
        if prev_gray is not None:
            dup_flags.append(float(cv2.mean(cv2.absdiff(gray, prev_gray))[0]) <= config.duplicate_mad)
            hist_dist.append(float(cv2.compareHist(prev_hist, hist, cv2.HISTCMP_BHATTACHARYYA)))
            thumb_mad.append(float(cv2.mean(cv2.absdiff(thumb, prev_thumb))[0]))
        prev_gray, prev_thumb, prev_hist = gray, thumb, hist
        n += 1
    if n == 0:  # only a video can get here: every file of an image folder decodes or raises
        raise ClipError(f"{name}: unreadable bytes (the container opened but no frame could be decoded)")
    if n == 1:
        raise ClipError(f"{name}: has 1 frame; at least 2 are needed")
    assert row_max is not None and col_max is not None
    w, h = size
    bars = _burned_in_bars(row_max, col_max, config.bar_luma)
    layout = _layout(size, config.working_size)
    duplicates = tuple(t + 1 for t, d in enumerate(dup_flags) if d)
    cuts = _hard_cuts(np.asarray(hist_dist), np.asarray(thumb_mad), np.asarray(dup_flags))
    return ClipInfo(
        path=name,
        kind=kind,
        source_size=(w, h),
        fps=fps,
        num_frames=n,
        working_size=(int(config.working_size[0]), int(config.working_size[1])),
        scale=layout.scale,
        offset=layout.offset,
        bars=bars,
        content_box=_content_box(size, bars, layout),
        duplicates=duplicates,
        cuts=cuts,
    )


def check_clip(path: str | Path) -> None:
    """A cheap readability check (no full decode): the clip exists and its first two frames
    decode. Raises :class:`ClipError` with the same one-sentence messages as :func:`probe_clip`."""
    name = str(path)
    kind, files = _resolve(Path(path), name)
    if kind == "images":
        assert files is not None
        frames = _image_frames(files[:2], name)
    else:
        _, frames = _open_video(name)
    got = 0
    try:
        for _ in frames:
            got += 1
            if got == 2:
                break
    finally:
        close = getattr(frames, "close", None)
        if close is not None:
            close()
    if got == 0:
        raise ClipError(f"{name}: unreadable bytes (the container opened but no frame could be decoded)")
    if got == 1:
        raise ClipError(f"{name}: has 1 frame; at least 2 are needed")


def iter_frames(info: ClipInfo) -> Iterator[Frame]:
    """Decode the clip of ``info`` again and yield its ``info.num_frames`` frames in order at
    working resolution, one at a time (never the whole clip). Raises :class:`ClipError` if the
    clip no longer decodes to the probed frames (e.g. the file changed in between)."""
    name = info.path
    if info.kind == "images":
        _, files = _resolve(Path(name), name)
        assert files is not None
        frames = _image_frames(files, name)
    else:
        if not Path(name).is_file():
            raise ClipError(f"{name}: no such file")
        _, frames = _open_video(name)
    layout = _layout(info.source_size, info.working_size)
    W, H = info.working_size
    content = info.content_mask
    content.flags.writeable = False
    n = 0
    for bgr in frames:
        h, w = bgr.shape[:2]
        if n >= info.num_frames or (w, h) != info.source_size:
            raise ClipError(f"{name}: decodes differently than when it was probed (changed since?)")
        rgb = _letterbox(bgr, layout, W, H)
        yield Frame(index=n, rgb=rgb, gray=cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY), content=content)
        n += 1
    if n != info.num_frames:
        raise ClipError(f"{name}: decoded {n} frames but {info.num_frames} when it was probed (changed since?)")


# --- sources -------------------------------------------------------------------------------


def _resolve(path: Path, name: str) -> tuple[ClipKind, list[Path] | None]:
    """The kind of the clip at ``path`` and, for an image folder, its frame files in natural
    order (None for a video or GIF). Raises :class:`ClipError` for anything unreadable."""
    if not path.exists():
        raise ClipError(f"{name}: no such file")
    if path.is_dir():
        files = sorted(
            (p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file()), key=_natural_key
        )
        if not files:
            raise ClipError(f"{name}: folder holds no PNG or JPEG frames")
        if len(files) == 1:
            raise ClipError(f"{name}: has 1 frame; at least 2 are needed")
        return "images", files
    if not path.is_file():
        raise ClipError(f"{name}: not a regular file")
    if path.suffix.lower() in IMAGE_SUFFIXES:
        if _imread(path) is None:
            raise ClipError(f"{name}: cannot be decoded as a video or image sequence")
        raise ClipError(f"{name}: has 1 frame; at least 2 are needed")
    try:
        with path.open("rb") as fh:
            head = fh.read(16)
    except OSError as err:
        raise ClipError(f"{name}: cannot be read ({err.strerror or err})") from None
    kind: ClipKind = "gif" if path.suffix.lower() == ".gif" or head.startswith(b"GIF8") else "video"
    return kind, None


def _natural_key(path: Path) -> tuple[list[tuple[int, int | str]], str]:
    """Sort key putting ``frame_2`` before ``frame_10`` (digit runs compare as numbers); the
    exact name breaks ties (``f01`` / ``f1``) so that the order never depends on the file system."""
    parts = re.split(r"(\d+)", path.name.lower())
    return [(0, int(p)) if p.isdigit() else (1, p) for p in parts if p], path.name


def _imread(path: Path) -> np.ndarray | None:
    """(h, w, 3) uint8 BGR of an image file (grey and alpha converted, 16 bit reduced), or None."""
    try:
        data = np.fromfile(str(path), dtype=np.uint8)
        return cv2.imdecode(data, cv2.IMREAD_COLOR) if data.size else None
    except (cv2.error, OSError):
        return None


def _image_frames(files: list[Path], name: str) -> Iterator[np.ndarray]:
    """(h, w, 3) uint8 BGR frames of an image folder, one file at a time."""
    for f in files:
        bgr = _imread(f)
        if bgr is None:
            raise ClipError(f"{f}: cannot be decoded as an image (frame of {name})")
        yield bgr


def _open_capture(name: str) -> cv2.VideoCapture:
    """An opened FFmpeg capture of ``name``; :class:`ClipError` if it cannot be opened."""
    try:
        cap = cv2.VideoCapture(name, cv2.CAP_FFMPEG)
        opened = cap.isOpened()
    except cv2.error as err:
        raise ClipError(f"{name}: unreadable bytes ({_cv_reason(err)})") from None
    if not opened:
        cap.release()
        if _looks_like_video(Path(name)):
            raise ClipError(f"{name}: unreadable bytes (a video header but no decodable stream)")
        raise ClipError(f"{name}: cannot be decoded as a video or image sequence")
    return cap


def _open_video(name: str) -> tuple[float, Iterator[np.ndarray]]:
    """The frame rate of the video or GIF ``name`` (:data:`DEFAULT_FPS` when the container reports
    none) and an iterator over its (h, w, 3) uint8 BGR frames until the decoder stops."""
    cap = _open_capture(name)
    try:
        fps = float(cap.get(cv2.CAP_PROP_FPS))
    except cv2.error:
        fps = 0.0
    fps = fps if math.isfinite(fps) and 0.0 < fps < 1000.0 else DEFAULT_FPS
    return fps, _read_capture(cap, name)


def _read_capture(cap: cv2.VideoCapture, name: str) -> Iterator[np.ndarray]:
    """(h, w, 3) uint8 BGR frames of an opened capture; releases it when done."""
    t = 0
    try:
        while True:
            try:
                ok, frame = cap.read()
            except cv2.error as err:
                if t == 0:
                    raise ClipError(f"{name}: unreadable bytes ({_cv_reason(err)})") from None
                return  # a decode error after some frames ends the clip, like a truncated file
            if not ok or frame is None:
                return
            yield _as_bgr(frame)
            t += 1
    finally:
        cap.release()


def _as_bgr(frame: np.ndarray) -> np.ndarray:
    """(h, w, 3) uint8 BGR from a decoded grey, BGR or BGRA frame."""
    if frame.dtype != np.uint8:
        frame = (
            cv2.convertScaleAbs(frame, alpha=255.0 / np.iinfo(frame.dtype).max)
            if frame.dtype.kind == "u"
            else frame.astype(np.uint8)
        )
    if frame.ndim == 2 or frame.shape[2] == 1:
        return cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR)
    if frame.shape[2] == 4:
        return cv2.cvtColor(frame, cv2.COLOR_BGRA2BGR)
    return frame


def _looks_like_video(path: Path) -> bool:
    """True if the first bytes carry a known video/GIF container signature."""
    try:
        with path.open("rb") as fh:
            head = fh.read(12)
    except OSError:
        return False
    return head.startswith(_VIDEO_MAGIC) or head[4:8] in _MP4_BOXES


def _cv_reason(err: cv2.error) -> str:
    """The short message of an OpenCV error, without its source location."""
    msg = (getattr(err, "err", "") or str(err)).strip().splitlines()
    return msg[-1].strip() if msg else "decoder error"


# --- geometry of the working canvas ---------------------------------------------------------


def _layout(source_size: tuple[int, int], working_size: tuple[int, int]) -> _Layout:
    """Fit (w, h) inside (W, H), aspect kept, centred: scale, scaled size and offset."""
    (w, h), (W, H) = source_size, working_size
    scale = min(W / w, H / h)
    sw, sh = min(W, max(1, round(w * scale))), min(H, max(1, round(h * scale)))
    return _Layout(scale=float(scale), scaled_size=(sw, sh), offset=((W - sw) // 2, (H - sh) // 2))


def _letterbox(bgr: np.ndarray, layout: _Layout, W: int, H: int) -> np.ndarray:
    """(H, W, 3) uint8 RGB canvas holding the resized ``bgr`` (h, w, 3) at ``layout``."""
    sw, sh = layout.scaled_size
    ox, oy = layout.offset
    h, w = bgr.shape[:2]
    if (sw, sh) != (w, h):
        interp = cv2.INTER_AREA if layout.scale < 1.0 else cv2.INTER_LINEAR
        bgr = cv2.resize(bgr, (sw, sh), interpolation=interp)
    canvas = np.zeros((H, W, 3), dtype=np.uint8)
    canvas[oy : oy + sh, ox : ox + sw] = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
    return canvas


def _content_box(
    source_size: tuple[int, int], bars: tuple[int, int, int, int], layout: _Layout
) -> tuple[int, int, int, int]:
    """(x0, y0, x1, y1) end-exclusive working pixels lying wholly inside the unbarred source,
    less :data:`BAR_MARGIN_PX` on each side with a bar."""
    (w, h), (sw, sh), (ox, oy) = source_size, layout.scaled_size, layout.offset
    top, bottom, left, right = bars
    fx, fy = sw / w, sh / h  # the resize's exact per-axis factors
    x0 = ox + math.ceil(left * fx - 1e-9) + (BAR_MARGIN_PX if left else 0)
    x1 = ox + math.floor((w - right) * fx + 1e-9) - (BAR_MARGIN_PX if right else 0)
    y0 = oy + math.ceil(top * fy - 1e-9) + (BAR_MARGIN_PX if top else 0)
    y1 = oy + math.floor((h - bottom) * fy + 1e-9) - (BAR_MARGIN_PX if bottom else 0)
    if x1 <= x0 or y1 <= y0:  # a tiny source: keep the whole scaled source rather than nothing
        return ox, oy, ox + sw, oy + sh
    return x0, y0, x1, y1


# --- detectors ------------------------------------------------------------------------------


def _burned_in_bars(row_max: np.ndarray, col_max: np.ndarray, bar_luma: float) -> tuple[int, int, int, int]:
    """(top, bottom, left, right) bar widths, source px, from the per-row (h,) and per-column
    (w,) maximum over frames of the mean luma: the dark runs from each edge. All zero when they
    would leave less than :data:`MIN_CONTENT_SHARE` of the height or width (a dark clip)."""

    def run(profile: np.ndarray) -> int:
        bright = np.flatnonzero(profile > bar_luma)
        return int(bright[0]) if bright.size else profile.size

    top, bottom = run(row_max), run(row_max[::-1])
    left, right = run(col_max), run(col_max[::-1])
    h, w = row_max.size, col_max.size
    if h - top - bottom < MIN_CONTENT_SHARE * h or w - left - right < MIN_CONTENT_SHARE * w:
        return (0, 0, 0, 0)
    return (top, bottom, left, right)


def _thumbnail(gray: np.ndarray) -> np.ndarray:
    """(th, 64) uint8 grey thumbnail (area-averaged), aspect kept."""
    h, w = gray.shape
    th = max(1, round(CUT_THUMB_WIDTH * h / w))
    interp = cv2.INTER_AREA if w >= CUT_THUMB_WIDTH else cv2.INTER_LINEAR
    return cv2.resize(gray, (CUT_THUMB_WIDTH, th), interpolation=interp)


def _hard_cuts(dist: np.ndarray, mad: np.ndarray, duplicate: np.ndarray) -> tuple[int, ...]:
    """Frame indices t with a hard cut between frames t - 1 and t.

    Inputs are per pair i = (i, i + 1), shape (T - 1,): ``dist`` the Bhattacharyya distance
    (0..1) between the thumbnails' grey histograms, ``mad`` their mean absolute difference (grey
    levels), ``duplicate`` the duplicate flags. Duplicate pairs are never cuts and are left out of
    the medians and neighbours. Thresholds: :data:`CUT_MIN_DISTANCE`, :data:`CUT_MIN_MAD`,
    :data:`CUT_MEDIAN_FACTOR`, :data:`CUT_NEIGHBOUR_FACTOR`, :data:`CUT_LONE_DISTANCE`."""
    valid = ~duplicate
    cuts = []
    for i in np.flatnonzero(valid & (dist > CUT_MIN_DISTANCE) & (mad > CUT_MIN_MAD)):
        others = valid.copy()
        others[i] = False
        if not others.any():
            if dist[i] > CUT_LONE_DISTANCE:
                cuts.append(int(i) + 1)
            continue
        if dist[i] <= CUT_MEDIAN_FACTOR * float(np.median(dist[others])):
            continue
        neighbours = [dist[j] for j in (i - 1, i + 1) if 0 <= j < dist.size and valid[j]]
        if neighbours and dist[i] <= CUT_NEIGHBOUR_FACTOR * float(max(neighbours)):
            continue
        cuts.append(int(i) + 1)
    return tuple(cuts)
