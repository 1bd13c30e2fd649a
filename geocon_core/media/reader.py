"""Reading clips (SPEC section 0): one streaming probe pass, then one streaming frame pass.

>>> info = probe_clip("clip.mp4")                      # doctest: +SKIP
>>> for frame in iter_frames(info):                     # doctest: +SKIP
...     frame.rgb, frame.gray, frame.content            # (H, W, 3), (H, W), (H, W) bool

:func:`probe_clip` decodes the clip once, holding at most two decoded frames, and returns a
:class:`ClipInfo`: the frame count (counted, never taken from container metadata), the
working-resolution layout (scale, centred offset, content box), black bars burned into the
source, duplicated frames and hard cuts. :func:`iter_frames` decodes it a second time and yields
every frame at working resolution.

Damaged input: a clip is scored on the frames that decode. When frames were lost (the container
promises clearly more than decode, a decoder error ends the stream, a GIF stops before its
trailer), :attr:`ClipInfo.warnings` says so in one sentence, which the record carries; the rule
and its tolerances are :meth:`~geocon_core.media.decode.FrameCount.falls_short`. A clip of which fewer
than 2 frames decode raises :class:`ClipError`. A frame file of an image folder that does not
decode raises :class:`ClipError` naming it (it is never skipped: that would silently close the gap
it leaves).

Resolution policy: a clip is never upscaled. A source larger than ``config.working_size`` is
downscaled to fit inside it (aspect kept, area averaging); a smaller one is processed at its own
size. The working canvas is the scaled source itself, so pixel thresholds (``tau_h``, the
Sampson scale of ``tau_f``, ``ge_gate``) are pixels of the image the features were found in.
Upscaling would only interpolate: it adds no detail, but it multiplies the codec's and the
detector's localisation noise (which live on the source's pixel grid) by the scale, and a fixed
threshold then judges that noise as inconsistency.

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

import hashlib
import math
import os
from collections.abc import Iterator
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path
from typing import Any, Literal

import cv2
import numpy as np

from ..config import BarConfig, CutConfig, ScoreConfig
from .decode import (
    DEFAULT_FPS,
    IMAGE_SUFFIXES,
    ClipError,
    ClipKind,
    FrameCount,
    Frames,
    _entry_kind,
    container_frame_count,
    frame_number_gaps,
    gif_cut,
    hidden_frames_note,
    image_frames,
    imread_any,
    open_video,
    resolve_clip,
    timing_note,
    video_tracks,
)

SkipReason = Literal["duplicate_frame", "hard_cut", "fade"]
"""Why a frame is left out of the pairs: a repeat of the previous frame, a hard cut, or a fade."""

__all__ = [
    "ClipError",
    "ClipInfo",
    "ClipKind",
    "Frame",
    "IMAGE_SUFFIXES",
    "SkipReason",
    "check_clip",
    "clip_fingerprint",
    "locate_clip",
    "OtherClipError",
    "iter_frames",
    "probe_clip",
    "probe_frames",
    "source_frames",
    "find_fades",
    "canvas_layout",
    "layout_of",
    "to_working",
]


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
    """(W, H) of the working canvas: the source scaled by :attr:`scale` (records written before
    the resolution policy hold the letterboxed ``config.working_size`` here)."""
    scale: float
    """Source px -> working px: ``min(1, Wmax / w, Hmax / h)`` for ``config.working_size`` =
    (Wmax, Hmax); never above 1."""
    offset: tuple[int, int]
    """(ox, oy): top-left working pixel of the scaled source inside the canvas; (0, 0) unless the
    record predates the resolution policy (then the source was centred in a letterbox)."""
    bars: tuple[int, int, int, int]
    """Burned-in black bars, source px: (top, bottom, left, right) rows/columns."""
    content_box: tuple[int, int, int, int]
    """(x0, y0, x1, y1), end-exclusive, working px: the scaled source minus padding minus
    burned-in bars, shrunk by ``config.bars.margin_px`` on every side that has a bar."""
    duplicates: tuple[int, ...] = ()
    """Sorted t (>= 1) such that frame t duplicates frame t - 1."""
    cuts: tuple[int, ...] = ()
    """Sorted t (>= 1) such that a hard cut lies between frame t - 1 and frame t. A fade (below)
    puts one after its first end and one at its last end."""
    fades: tuple[tuple[int, int], ...] = ()
    """(s, e) of each cross-fade, sorted: frames ``s + 1 .. e - 1`` blend frame ``s`` (the last of
    a shot) into frame ``e`` (the first of the next); ``s + 1`` and ``e`` are in :attr:`cuts`, and
    the frames between belong to no shot. Absent from records written before fades were found."""
    abs_path: str | None = None
    """The clip's absolute path when it was probed (None in records written before it)."""
    fingerprint: str | None = None
    """``size:sha256`` of the clip's bytes (:func:`clip_fingerprint`): which clip this is, wherever
    it lies now (None in records written before it)."""
    from_record: str | None = None
    """The clip's path relative to the folder that holds the record folder, set when the record is
    written: found again when record and clip move together."""
    warnings: tuple[str, ...] = ()
    """One sentence each about frames lost to damage (the container promised more frames than
    decoded, a decoder error ended the stream, a GIF stops before its trailer); the clip is scored
    on the :attr:`num_frames` that decoded. The record's warnings include them. Absent from records
    written before this field (read as none)."""

    def __post_init__(self) -> None:
        if self.kind not in ("video", "gif", "images", "frames"):
            raise ValueError(f"kind must be video, gif, images or frames, got {self.kind!r}")
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
        if not isinstance(self.fades, tuple) or any(
            not (isinstance(f, tuple) and len(f) == 2 and 0 <= f[0] < f[1] - 1 < self.num_frames - 1)
            or f[0] + 1 not in self.cuts
            or f[1] not in self.cuts
            for f in self.fades
        ):
            raise ValueError(f"fades must be (s, e) frame pairs with s + 1 and e in cuts, got {self.fades!r}")
        if not isinstance(self.warnings, tuple) or not all(isinstance(w, str) for w in self.warnings):
            raise ValueError(f"warnings must be a tuple of str, got {self.warnings!r}")

    @property
    def content_mask(self) -> np.ndarray:
        """(H, W) bool, True inside :attr:`content_box`. A new array on each call."""
        W, H = self.working_size
        x0, y0, x1, y1 = self.content_box
        mask = np.zeros((H, W), dtype=bool)
        mask[y0:y1, x0:x1] = True
        return mask

    @property
    def shots(self) -> tuple[tuple[int, int], ...]:
        """(first, last) frame of each shot, inclusive: the spans between :attr:`cuts`, less the
        inside of each fade; one span for a clip without cuts."""
        starts = (0, *self.cuts)
        ends = (*(c - 1 for c in self.cuts), self.num_frames - 1)
        inside = {(s + 1, e - 1) for s, e in self.fades}
        return tuple(span for span in zip(starts, ends, strict=True) if span not in inside)

    def pair_skip_reason(self, t0: int, t1: int) -> SkipReason | None:
        """Why the frame pair (t0, t1), ``0 <= t0 < t1 < num_frames``, must not be scored:
        ``"duplicate_frame"`` if every frame in ``t0 + 1 .. t1`` duplicates its predecessor (the
        two frames are identical), ``"fade"`` if both frames lie inside a fade, ``"hard_cut"`` if a
        cut ``c`` has ``t0 < c <= t1``, else None."""
        if not 0 <= t0 < t1 < self.num_frames:
            raise ValueError(f"need 0 <= t0 < t1 < {self.num_frames}, got ({t0}, {t1})")
        dup = set(self.duplicates)
        if all(t in dup for t in range(t0 + 1, t1 + 1)):
            return "duplicate_frame"
        if any(s < t0 and t1 < e for s, e in self.fades):
            return "fade"
        if any(t0 < c <= t1 for c in self.cuts):
            return "hard_cut"
        return None

    def to_dict(self) -> dict[str, Any]:
        """JSON-able dict (tuples become lists); :meth:`from_dict` inverts it exactly."""
        out = {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}
        out["fades"] = [list(f) for f in self.fades]
        return out

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "ClipInfo":
        """The :class:`ClipInfo` that :meth:`to_dict` made ``d`` from (:attr:`warnings` may be
        absent: records written before it hold none)."""
        names = {f.name for f in fields(cls)}
        unknown, missing = (
            set(d) - names,
            names - set(d) - {"warnings", "fades", "abs_path", "fingerprint", "from_record"},
        )
        if unknown or missing:
            raise ValueError(f"ClipInfo keys: unknown {sorted(unknown)}, missing {sorted(missing)}")
        kw: dict[str, Any] = {
            k: tuple(int(x) for x in v) if isinstance(v, list) and k not in ("warnings", "fades") else v
            for k, v in d.items()
        }
        kw["fades"] = tuple((int(s), int(e)) for s, e in d.get("fades", []))
        kw["fps"], kw["scale"], kw["num_frames"] = float(d["fps"]), float(d["scale"]), int(d["num_frames"])
        warnings = d.get("warnings", [])
        kw["warnings"] = tuple(warnings) if isinstance(warnings, list) else warnings
        return cls(**kw)


@dataclass(frozen=True, eq=False)
class Frame:
    """One frame at working resolution (W, H) = ``info.working_size``."""

    index: int
    """Frame index t, 0-based."""
    rgb: np.ndarray
    """(H, W, 3) uint8 RGB, the source at working resolution."""
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


class _Probe:
    """The probe pass's running sums over decoded BGR frames (at most two held): the frame size,
    the brightest row and column (burned-in bars), duplicates, and the cut evidence."""

    def __init__(self, name: str, config: ScoreConfig, files: list[Path] | None = None) -> None:
        self.name, self.config, self.files = name, config, files
        self.row_max: np.ndarray | None = None
        self.col_max: np.ndarray | None = None
        self.prev: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self.dup_flags: list[bool] = []
        self.hist_dist: list[float] = []
        self.thumb_mad: list[float] = []
        self.fade_thumbs: list[np.ndarray] = []
        self.n = 0
        self.size = (0, 0)

    def add(self, bgr: np.ndarray) -> None:
        config, files, n = self.config, self.files, self.n
        gray = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
        h, w = gray.shape
        if n == 0:
            self.size = (w, h)
        elif (w, h) != self.size:
            size = self.size
            which = f"frame {n}" if files is None else f"frame {n} ({files[n].name})"
            turned = ""
            if files is not None and (h, w) == size:  # as stored, before its EXIF orientation is applied?
                stored = imread_any(files[n], cv2.IMREAD_COLOR | cv2.IMREAD_IGNORE_ORIENTATION)
                if stored is not None and (stored.shape[1], stored.shape[0]) == size:
                    turned = (
                        " once its EXIF orientation tag turns it (frame 0's does not); give every frame one orientation"
                    )
            raise ClipError(f"{self.name}: {which} is {w}x{h} but frame 0 is {size[0]}x{size[1]}{turned}")
        rows = cv2.reduce(gray, 1, cv2.REDUCE_AVG, dtype=cv2.CV_32F).ravel()
        cols = cv2.reduce(gray, 0, cv2.REDUCE_AVG, dtype=cv2.CV_32F).ravel()
        self.row_max = rows if self.row_max is None else np.maximum(self.row_max, rows)
        self.col_max = cols if self.col_max is None else np.maximum(self.col_max, cols)
        thumb = _thumbnail(gray, config.cuts.thumb_width)
        hist = cv2.calcHist([thumb], [0], None, [config.cuts.hist_bins], [0, 256])
        if config.cuts.fade_frames:
            self.fade_thumbs.append(_thumbnail(gray, config.cuts.fade_width))
        if self.prev is not None:
            prev_gray, prev_thumb, prev_hist = self.prev
            self.dup_flags.append(float(cv2.mean(cv2.absdiff(gray, prev_gray))[0]) <= config.duplicate_mad)
            self.hist_dist.append(float(cv2.compareHist(prev_hist, hist, cv2.HISTCMP_BHATTACHARYYA)))
            self.thumb_mad.append(float(cv2.mean(cv2.absdiff(thumb, prev_thumb))[0]))
        self.prev = (gray, thumb, hist)
        self.n += 1

    def info(self, **where: Any) -> ClipInfo:
        """The :class:`ClipInfo` of the frames added; ``where`` holds the fields only the source
        knows (path, abs_path, fingerprint, kind, fps, warnings)."""
        config = self.config
        assert self.row_max is not None and self.col_max is not None
        w, h = size = self.size
        bars = _burned_in_bars(self.row_max, self.col_max, config.bar_luma, config.bars)
        layout = canvas_layout(size, config.working_size)
        sw, sh = layout.scaled_size
        duplicates = tuple(t + 1 for t, d in enumerate(self.dup_flags) if d)
        cuts = _hard_cuts(
            np.asarray(self.hist_dist), np.asarray(self.thumb_mad), np.asarray(self.dup_flags), config.cuts
        )
        fades = find_fades(self.fade_thumbs, config.cuts) if self.fade_thumbs else ()
        if fades:  # a fade's ends are cuts; a cut found inside a fade is the fade's
            inside = {t for s, e in fades for t in range(s + 1, e + 1)}
            cuts = tuple(sorted({c for c in cuts if c not in inside} | {t for s, e in fades for t in (s + 1, e)}))
        return ClipInfo(
            source_size=(w, h),
            num_frames=self.n,
            working_size=(sw, sh),
            scale=layout.scale,
            offset=layout.offset,
            bars=bars,
            content_box=_content_box(size, bars, layout, config.bars.margin_px),
            duplicates=duplicates,
            cuts=cuts,
            fades=fades,
            **where,
        )


def probe_clip(path: str | Path, config: ScoreConfig | None = None) -> ClipInfo:
    """One streaming pass over the clip at ``path`` (a video/GIF file or a folder of PNG/JPEG
    frames), holding at most two decoded frames: counts the frames and detects burned-in bars,
    duplicated frames and hard cuts. Deterministic. Raises :class:`ClipError` for unusable input."""
    config = config or ScoreConfig()
    name = str(path)
    kind, files = resolve_clip(Path(path), name)
    fps = DEFAULT_FPS
    video: Frames | None = None
    frames: Iterator[np.ndarray]
    if files is not None:
        frames = image_frames(files, name)
    else:
        fps, opened = open_video(name)
        frames = video = opened
    probe = _Probe(name, config, files)
    for bgr in frames:
        probe.add(bgr)
    n = probe.n
    if n == 0:  # only a video can get here: every file of an image folder decodes or raises
        raise ClipError(f"{name}: unreadable bytes (the container opened but no frame could be decoded)")
    promise = container_frame_count(name) if video is not None else None
    if n == 1:
        if promise is not None and promise.falls_short(n):
            raise ClipError(
                f"{name}: only 1 of the {promise.frames} frames the container promises decoded"
                " (truncated or damaged file); at least 2 are needed"
            )
        raise ClipError(f"{name}: has 1 frame; at least 2 are needed")
    return probe.info(
        path=name,
        abs_path=os.path.abspath(name),
        fingerprint=clip_fingerprint(Path(path)),
        kind=kind,
        fps=fps,
        warnings=_damage_warnings(Path(path), kind, n, None if video is None else video.error, promise)
        + _decoder_note(video)
        + _track_notes(name, kind, video)
        + _timing_notes(name, kind, fps, video)
        + frame_number_gaps(files, name)
        + (hidden_frames_note(Path(path), name) if files is not None else ()),
    )


def probe_frames(
    frames: np.ndarray, name: str, config: ScoreConfig | None = None, fps: float = DEFAULT_FPS
) -> ClipInfo:
    """:func:`probe_clip` for decoded frames held in memory: ``frames`` is a (T, h, w, 3) uint8
    **BGR** array (:func:`~geocon_core.media.memory.as_bgr_frames` makes one from RGB numpy or
    torch frames); ``name`` stands in for the path in the record. The same frames give the same
    :class:`ClipInfo` as a folder of lossless PNG files of them, less the file's identity."""
    config = config or ScoreConfig()
    if frames.ndim != 4 or frames.shape[-1] != 3 or frames.dtype != np.uint8:
        raise ClipError(f"{name}: frames must be a (T, h, w, 3) uint8 array, got {frames.dtype} {frames.shape}")
    if len(frames) < 2:
        raise ClipError(f"{name}: has {len(frames)} frame{'s' if len(frames) != 1 else ''}; at least 2 are needed")
    probe = _Probe(name, config)
    for bgr in frames:
        probe.add(bgr)
    return probe.info(path=name, kind="frames", fps=float(fps))


DECODER_NOTES = {
    "pyav": "decoded with PyAV (a stream OpenCV cannot read, e.g. AV1)",
    "pyav (deinterlaced: yadif)": "an interlaced stream: deinterlaced with FFmpeg's yadif (one frame per frame) "
    "before scoring; its geometry is that of the deinterlaced frames",
    "pillow": "an animated or multi-page image: decoded with Pillow",
}
"""What the record says when a clip was not decoded by OpenCV (:func:`~geocon_core.media.decode.open_video`)."""


def _decoder_note(video: Frames | None) -> tuple[str, ...]:
    decoder = getattr(video, "decoder", "opencv")
    return (DECODER_NOTES[decoder],) if decoder in DECODER_NOTES else ()


FINGERPRINT_BYTES = 1 << 20
"""Bytes hashed from each end of a clip file (and of the first and last file of an image folder)."""


def clip_fingerprint(path: Path) -> str | None:
    """``size:sha256`` of a clip: its byte count and a hash of its first and last
    :data:`FINGERPRINT_BYTES` (a folder: its file names and sizes, and its first and last files
    likewise). Cheap on any size, and different for another clip of the same name. None when the
    clip cannot be read, or is a FIFO, a device or a socket (never opened:
    :func:`~geocon_core.files.open_regular`)."""
    from ..files import CLIP, ReadRefused, open_regular

    h = hashlib.sha256()
    try:
        if path.is_dir():
            _, files = resolve_clip(path, str(path))
            assert files is not None
            sizes = [f.stat().st_size for f in files]
            for f, size in zip(files, sizes, strict=True):
                h.update(os.fsencode(f.name) + b"\0" + str(size).encode() + b"\0")
            parts, total = [files[0], files[-1]], sum(sizes)
        else:
            parts, total = [path], path.stat().st_size
        for part in parts:
            with open_regular(part, CLIP) as fh:
                h.update(fh.read(FINGERPRINT_BYTES))
                size = os.fstat(fh.fileno()).st_size
                if size > FINGERPRINT_BYTES:
                    fh.seek(max(FINGERPRINT_BYTES, size - FINGERPRINT_BYTES))
                    h.update(fh.read())
    except (OSError, ClipError, ReadRefused):
        return None
    return f"{total}:{h.hexdigest()}"


class OtherClipError(ClipError):
    """The clip found where a record's clip should be is another clip (its bytes differ)."""


def locate_clip(info: ClipInfo, record_dir: str | Path) -> ClipInfo:
    """The record's clip where it lies now, as a :class:`ClipInfo` whose ``path`` can be read: the
    path as given (from here), its absolute path when scored, or its place relative to the record
    (record and clip moved together). A clip found there must be the one scored (same
    :attr:`~ClipInfo.fingerprint`, when the record has one). Raises :class:`ClipError` with one
    sentence when the clip is gone, :class:`OtherClipError` when every candidate is another clip."""
    folder = Path(record_dir)
    candidates = [Path(info.path)]
    if info.abs_path:
        candidates.append(Path(info.abs_path))
    if info.from_record:
        candidates.append(Path(os.path.normpath(folder.resolve().parent / info.from_record)))
    seen: list[Path] = []
    other: Path | None = None
    for cand in candidates:
        if cand in seen or not cand.exists():
            continue
        if not cand.is_file() and not cand.is_dir():  # read, a FIFO would block and a device never end
            raise ClipError(
                f"{cand}: is {_entry_kind(cand)}, not a clip file, where this record's clip was; put the clip back "
                "as a file"
            )
        seen.append(cand)
        if info.fingerprint is None or clip_fingerprint(cand) == info.fingerprint:
            return replace(info, path=str(cand))
        other = other or cand
    if other is not None:
        raise OtherClipError(
            f"{other} is not the clip this record was scored on (its bytes differ; the record's clip was "
            f"{info.abs_path or info.path}); score it again or put the original back"
        )
    looked = ", ".join(dict.fromkeys(str(c) for c in candidates))
    raise ClipError(f"the clip of this record is gone (looked at {looked})")


def _timing_notes(name: str, kind: ClipKind, fps: float, video: Frames | None) -> tuple[str, ...]:
    """The timestamps of a video (not a GIF, an animated image or a frame folder) against its rate."""
    if kind != "video" or video is None or getattr(video, "decoder", "") == "pillow":
        return ()
    note = timing_note(name, fps)
    return () if note is None else (note,)


def _track_notes(name: str, kind: ClipKind, video: Frames | None) -> tuple[str, ...]:
    """Which video track was scored, when the file holds more than one (the first, always)."""
    if kind != "video" or video is None or getattr(video, "decoder", "") == "pillow":
        return ()
    tracks = video_tracks(name)
    if len(tracks) < 2:
        return ()
    sizes = ", ".join(f"{w}x{h}" for w, h in tracks)
    w, h = tracks[0]
    return (
        f"the file holds {len(tracks)} video tracks ({sizes}): scored video track 1 of {len(tracks)} (the "
        f"first, {w}x{h}) and ignored the others; to score another, copy it into a file of its own first "
        "(ffmpeg's -map option)",
    )


def _damage_warnings(
    path: Path, kind: ClipKind, n: int, error: str | None, promise: FrameCount | None
) -> tuple[str, ...]:
    """The warning, if any, that frames of the clip at ``path`` were lost to damage although ``n``
    decoded: a decoder ``error`` ended the stream, the container's ``promise`` is clearly larger
    (:meth:`~geocon_core.media.decode.FrameCount.falls_short`), or a GIF stops before its trailer."""
    if error is not None:
        of = f" of the {promise.frames} the container promises" if promise is not None and promise.frames > n else ""
        return (f"decoding stopped with an error at frame {n}{of} ({error}); scored on the {n} frames before it",)
    if promise is not None and promise.falls_short(n):
        said = (
            f"the container promises {promise.frames} frames"
            if promise.exact
            else f"the container's duration implies about {promise.frames} frames"
        )
        return (f"{said} but only {n} decoded (truncated or damaged file); scored on those",)
    cut = gif_cut(path) if kind == "gif" else None
    if cut is not None:
        where = (
            f"is cut short inside frame {cut.complete} (truncated or damaged file)"
            if cut.partial
            else "ends without its trailer block, so later frames may be missing"
        )
        return (f"the GIF {where}; scored on the {n} frames that decoded",)
    return ()


def source_frames(path: str | Path, max_frames: int | None = None) -> Iterator[np.ndarray]:
    """The clip's decoded BGR frames as stored (no crop, no working size), at most ``max_frames``:
    videos, GIFs and folders of PNG / JPEG frames, one at a time."""
    name = str(path)
    _, files = resolve_clip(Path(path), name)
    frames = image_frames(files, name) if files is not None else open_video(name)[1]
    for n, bgr in enumerate(frames):
        if max_frames is not None and n >= max_frames:
            break
        yield bgr


def check_clip(path: str | Path) -> None:
    """A cheap readability check (no full decode): the clip exists and its first two frames
    decode. Raises :class:`ClipError` with the same one-sentence messages as :func:`probe_clip`."""
    name = str(path)
    kind, files = resolve_clip(Path(path), name)
    if kind == "images":
        assert files is not None
        frames = image_frames(files[:2], name)
    else:
        _, frames = open_video(name)
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


def iter_frames(info: ClipInfo, held: np.ndarray | None = None) -> Iterator[Frame]:
    """Decode the clip of ``info`` again and yield its ``info.num_frames`` frames in order at
    working resolution, one at a time (never the whole clip). Frames held in memory
    (:func:`probe_frames`, kind ``"frames"``) are read from ``held``, the array probed. Raises
    :class:`ClipError` if the clip no longer decodes to the probed frames (e.g. the file changed
    in between)."""
    name = info.path
    frames: Iterator[np.ndarray]
    if info.kind == "frames":
        if held is None:
            raise ClipError(f"{name}: frames held in memory; pass them again to read them")
        frames = iter(held)
    elif info.kind == "images":
        _, files = resolve_clip(Path(name), name)
        assert files is not None
        frames = image_frames(files, name)
    else:
        if not Path(name).is_file():
            raise ClipError(f"{name}: no such file")
        _, frames = open_video(name)
    layout = layout_of(info)
    W, H = info.working_size
    content = info.content_mask
    content.flags.writeable = False
    n = 0
    for bgr in frames:
        h, w = bgr.shape[:2]
        if n >= info.num_frames or (w, h) != info.source_size:
            raise ClipError(f"{name}: decodes differently than when it was probed (changed since?)")
        rgb = to_working(bgr, layout, W, H)
        yield Frame(index=n, rgb=rgb, gray=cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY), content=content)
        n += 1
    if n != info.num_frames:
        raise ClipError(f"{name}: decoded {n} frames but {info.num_frames} when it was probed (changed since?)")


# --- geometry of the working canvas ---------------------------------------------------------


def canvas_layout(source_size: tuple[int, int], working_size: tuple[int, int]) -> _Layout:
    """The working layout of a (w, h) source under the largest canvas (Wmax, Hmax): scaled by
    ``min(1, Wmax / w, Hmax / h)`` (never up), aspect kept, at offset (0, 0)."""
    (w, h), (W, H) = source_size, working_size
    scale = min(1.0, W / w, H / h)
    return _Layout(scale=float(scale), scaled_size=_scaled(source_size, scale, (W, H)), offset=(0, 0))


def layout_of(info: ClipInfo) -> _Layout:
    """The layout a probed clip was read with (also for records made before the resolution
    policy, whose sources were letterboxed into a larger canvas)."""
    return _Layout(
        scale=info.scale, scaled_size=_scaled(info.source_size, info.scale, info.working_size), offset=info.offset
    )


def _scaled(source_size: tuple[int, int], scale: float, bound: tuple[int, int]) -> tuple[int, int]:
    (w, h), (W, H) = source_size, bound
    return min(W, max(1, round(w * scale))), min(H, max(1, round(h * scale)))


def to_working(bgr: np.ndarray, layout: _Layout, W: int, H: int) -> np.ndarray:
    """(H, W, 3) uint8 RGB canvas holding the resized ``bgr`` (h, w, 3) at ``layout``: a decoded
    frame as :func:`iter_frames` gives it at working resolution."""
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
    source_size: tuple[int, int], bars: tuple[int, int, int, int], layout: _Layout, margin: int
) -> tuple[int, int, int, int]:
    """(x0, y0, x1, y1) end-exclusive working pixels lying wholly inside the unbarred source,
    less ``margin`` px on each side with a bar."""
    (w, h), (sw, sh), (ox, oy) = source_size, layout.scaled_size, layout.offset
    top, bottom, left, right = bars
    fx, fy = sw / w, sh / h  # the resize's exact per-axis factors
    x0 = ox + math.ceil(left * fx - 1e-9) + (margin if left else 0)
    x1 = ox + math.floor((w - right) * fx + 1e-9) - (margin if right else 0)
    y0 = oy + math.ceil(top * fy - 1e-9) + (margin if top else 0)
    y1 = oy + math.floor((h - bottom) * fy + 1e-9) - (margin if bottom else 0)
    if x1 <= x0 or y1 <= y0:  # a tiny source: keep the whole scaled source rather than nothing
        return ox, oy, ox + sw, oy + sh
    return x0, y0, x1, y1


# --- detectors ------------------------------------------------------------------------------


def _burned_in_bars(
    row_max: np.ndarray, col_max: np.ndarray, bar_luma: float, config: BarConfig
) -> tuple[int, int, int, int]:
    """(top, bottom, left, right) bar widths, source px, from the per-row (h,) and per-column
    (w,) maximum over frames of the mean luma: the dark runs from each edge. All zero when they
    would leave less than ``config.min_content_share`` of the height or width (a dark clip)."""

    def run(profile: np.ndarray) -> int:
        bright = np.flatnonzero(profile > bar_luma)
        return int(bright[0]) if bright.size else profile.size

    top, bottom = run(row_max), run(row_max[::-1])
    left, right = run(col_max), run(col_max[::-1])
    h, w = row_max.size, col_max.size
    share = config.min_content_share
    if h - top - bottom < share * h or w - left - right < share * w:
        return (0, 0, 0, 0)
    return (top, bottom, left, right)


def _thumbnail(gray: np.ndarray, width: int) -> np.ndarray:
    """(th, width) uint8 grey thumbnail (area-averaged), aspect kept."""
    h, w = gray.shape
    th = max(1, round(width * h / w))
    interp = cv2.INTER_AREA if w >= width else cv2.INTER_LINEAR
    return cv2.resize(gray, (width, th), interpolation=interp)


def _blend_fit(thumbs: np.ndarray, s: int, e: int) -> tuple[np.ndarray, np.ndarray]:
    """(alpha, residual) of each frame strictly between ``s`` and ``e`` as the blend
    ``(1 - alpha) T_s + alpha T_e`` of the two ends that fits it best (least squares), the
    residual as RMS over the RMS of ``T_e - T_s`` (the ends must differ)."""
    d = thumbs[e] - thumbs[s]
    dd = float(d @ d)
    inner = thumbs[s + 1 : e] - thumbs[s]
    alpha = inner @ d / dd
    rest = inner - alpha[:, None] * d
    return alpha, np.sqrt(np.mean(rest**2, axis=1)) / math.sqrt(dd / d.size)


def find_fades(thumbs: list[np.ndarray], config: CutConfig) -> tuple[tuple[int, int], ...]:
    """Cross-fades among a clip's grey thumbnails (one per frame, same size): (s, e) such that every
    frame strictly between is a blend of frames s and e (:func:`_blend_fit` residual at most
    ``config.fade_residual``, blend weights rising from below a half to above it), the two ends
    differ by more than ``config.min_mad`` grey levels and are different pictures (normalised
    cross-correlation below ``config.fade_max_ncc``: a change of light is no fade), and ``e - s``
    is 3 to ``config.fade_frames``. The two tests of the ends run first, on every start at once;
    the blend is fitted only where they pass (on most clips, nowhere).
    Overlapping fades are merged and trimmed to the frames whose weight moves (a still stretch
    before or after a fade is a blend of its ends too, with weight 0 or 1)."""
    n = len(thumbs)
    if n < 4 or config.fade_frames < 3:
        return ()
    t = np.stack([x.astype(np.float32).ravel() for x in thumbs])
    z = t - t.mean(axis=1, keepdims=True)
    z /= np.maximum(np.linalg.norm(z, axis=1, keepdims=True), 1e-6)  # zero-mean unit rows: ncc is a dot product
    windows = []
    for e in range(3, n):
        starts = np.arange(max(0, e - config.fade_frames), e - 2)
        ends_differ = (np.mean(np.abs(t[starts] - t[e]), axis=1) > config.min_mad) & (
            z[starts] @ z[e] < config.fade_max_ncc
        )
        for s in starts[ends_differ]:
            alpha, residual = _blend_fit(t, int(s), e)
            if residual.max() > config.fade_residual:
                continue
            if alpha.min() < -0.1 or alpha.max() > 1.1 or np.any(np.diff(alpha) < -0.1):
                continue
            if alpha[0] < 0.5 < alpha[-1]:
                windows.append((int(s), e))
    merged: list[list[int]] = []
    for s, e in sorted(windows):
        if merged and s < merged[-1][1]:
            merged[-1][1] = max(merged[-1][1], e)
        else:
            merged.append([s, e])
    fades = []
    for s, e in merged:
        if np.array_equal(t[s], t[e]):  # ends of two merged windows that show the same picture
            continue
        alpha, _ = _blend_fit(t, s, e)
        moving = np.flatnonzero((alpha > 0.05) & (alpha < 0.95))
        if not len(moving):
            continue
        s2, e2 = s + int(moving[0]), s + 2 + int(moving[-1])  # the last still frame before, the first after
        if e2 - s2 >= 3:
            fades.append((s2, e2))
    return tuple(fades)


def _hard_cuts(dist: np.ndarray, mad: np.ndarray, duplicate: np.ndarray, config: CutConfig) -> tuple[int, ...]:
    """Frame indices t with a hard cut between frames t - 1 and t.

    Inputs are per pair i = (i, i + 1), shape (T - 1,): ``dist`` the Bhattacharyya distance
    (0..1) between the thumbnails' grey histograms, ``mad`` their mean absolute difference (grey
    levels), ``duplicate`` the duplicate flags. Duplicate pairs are never cuts and are left out of
    the medians and neighbours. Thresholds: ``config`` (:class:`~geocon_core.config.stages.CutConfig`)."""
    valid = ~duplicate
    cuts = []
    for i in np.flatnonzero(valid & (dist > config.min_distance) & (mad > config.min_mad)):
        others = valid.copy()
        others[i] = False
        if not others.any():
            if dist[i] > config.lone_distance:
                cuts.append(int(i) + 1)
            continue
        if dist[i] <= config.median_factor * float(np.median(dist[others])):
            continue
        near = [j for j in (i - 1, i + 1) if 0 <= j < dist.size and valid[j]]
        # an isolated spike of the histogram distance or of the picture difference: a change of
        # exposure just before a cut raises the histogram distance of its neighbour, not its picture
        if near and not any(v[i] > config.neighbour_factor * float(max(v[j] for j in near)) for v in (dist, mad)):
            continue
        cuts.append(int(i) + 1)
    return tuple(cuts)
