"""Decoding the frames of a clip file or image folder, one at a time, as (h, w, 3) uint8 BGR.

Used by :mod:`geocon_core.media.reader`; every failure is a :class:`ClipError` whose message is one
sentence that names the file. Damage that still leaves frames to score is not an error but is
reported, so that the reader can warn: :func:`container_frame_count` (what the container promises),
:attr:`CaptureFrames.error` (a decoder error that ended the stream) and :func:`gif_cut` (a GIF
that stops before its trailer).
"""

from __future__ import annotations

import functools
import itertools
import math
import os
import re
import shlex
import shutil
import stat
import sys
import tempfile
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, Union

import cv2
import numpy as np

__all__ = [
    "ANIMATED_SUFFIXES",
    "CaptureFrames",
    "Frames",
    "PillowFrames",
    "PyAVFrames",
    "ClipError",
    "ClipKind",
    "DEFAULT_FPS",
    "MAX_FPS",
    "DisplayTurn",
    "FrameCount",
    "FrameTiming",
    "GifCut",
    "IMAGE_SUFFIXES",
    "VIDEO_FILE_SUFFIXES",
    "SHORTFALL_EXACT",
    "SHORTFALL_ESTIMATED",
    "container_frame_count",
    "display_turn",
    "frame_timing",
    "frame_number_gaps",
    "timing_note",
    "video_tracks",
    "gif_cut",
    "hidden_frames_note",
    "image_frames",
    "imread_any",
    "imwrite_any",
    "is_rerun_recording",
    "rerun_command",
    "rerun_refusal",
    "native_path",
    "native_safe",
    "open_video",
    "quiet_decoder_logs",
    "resolve_clip",
]

ClipKind = Literal["video", "gif", "images", "frames"]
"""What a clip is read from: a video container, a GIF, a folder (or list) of images, or decoded
frames held in memory (:func:`~geocon_core.media.reader.probe_frames`)."""


def native_safe(name: str) -> bool:
    """Whether ``name`` can be handed to a native library as it is: valid UTF-8 text (a name read
    from a Latin-1 or zip archive holds undecodable bytes, which OpenCV's bindings do not survive)."""
    try:
        name.encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True


@contextmanager
def native_path(name: str) -> Iterator[str]:
    """``name`` in a form native libraries accept: itself when it is :func:`native_safe`, else a
    link with a plain name in a private temporary folder, removed when the block ends (a decoder
    that opened the file keeps it open). A relative name holding a colon is given as ``./name``:
    FFmpeg reads the text before a colon as a protocol, so ``2024-05-01T12:30:00.mp4`` would name
    the protocol ``2024-05-01T12``, ``file:b.mp4`` the file ``b.mp4`` and ``pipe:0.mp4`` the
    standard input."""
    if native_safe(name):
        yield name if ":" not in name or os.path.isabs(name) else os.path.join(".", name)
        return
    folder = tempfile.mkdtemp(prefix="geocon-link-")
    link = os.path.join(
        folder, "clip" + "".join(c for c in Path(name).suffix if c.isascii() and c.isalnum() or c == ".")
    )
    try:
        os.symlink(os.path.abspath(name), link)
        yield link
    finally:
        shutil.rmtree(folder, ignore_errors=True)


_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_PNG_END = b"IEND\xaeB`\x82"
"""The type and CRC of the ``IEND`` chunk that ends every whole PNG file."""


def imread_any(path: str | Path, flags: int = cv2.IMREAD_COLOR) -> np.ndarray | None:
    """``cv2.imread`` for any file name (the bytes are read by Python, decoded by OpenCV); None
    when the file cannot be read or decoded: a FIFO, a device or a file past
    :data:`~geocon_core.files.bounded.FRAME_IMAGE`'s bound is not read at all
    (:func:`~geocon_core.files.read_bytes`). A PNG cut short (no ``IEND`` chunk at its end) is None
    without being handed to libpng, which would print its own error on the terminal."""
    from ..files import FRAME_IMAGE, read_bytes

    try:
        data = np.frombuffer(read_bytes(path, FRAME_IMAGE), dtype=np.uint8)
        if data[:8].tobytes() == _PNG_SIGNATURE and data[-12:].tobytes()[4:] != _PNG_END:
            return None
        return cv2.imdecode(data, flags) if data.size else None
    except (cv2.error, OSError, ValueError):
        return None


def imwrite_any(path: str | Path, image: np.ndarray, params: Sequence[int] = ()) -> bool:
    """``cv2.imwrite`` for any file name: encoded by OpenCV (format from the suffix), written by
    Python. False when it cannot be encoded; ``OSError`` when it cannot be written (a full disk)."""
    ok, buf = cv2.imencode(Path(path).suffix or ".png", image, list(params))
    if not ok:
        return False
    with open(path, "wb") as fh:
        fh.write(buf.tobytes())
    return True


def quiet_decoder_logs() -> None:
    """Keep the decoders' own lines off the terminal: FFmpeg's per-packet errors inside OpenCV (a
    damaged stream prints dozens) and OpenCV's warnings (``can't be used to capture by name`` before
    each refusal), unless ``OPENCV_FFMPEG_LOGLEVEL`` / ``OPENCV_LOG_LEVEL`` say otherwise. What damage
    cost is said once, in GeoCon's own sentence (a refusal, or a warning in the record). The command
    line calls this at start; it changes the process environment and OpenCV's log level."""
    os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")  # AV_LOG_QUIET, read when FFmpeg is first used
    if "OPENCV_LOG_LEVEL" not in os.environ:
        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)


IMAGE_SUFFIXES: frozenset[str] = frozenset({".png", ".jpg", ".jpeg"})
"""File suffixes (lower case) read as frames of an image folder."""
ANIMATED_SUFFIXES: frozenset[str] = frozenset({".png", ".apng", ".webp", ".tif", ".tiff"})
"""Single files that may hold an animation, or pages (a multi-page TIFF): read as a clip by Pillow when
they hold 2 frames or more."""

DEFAULT_FPS = 24.0
"""Frame rate for image folders and for containers that report none."""
SHORTFALL_EXACT = 0.05
"""Share of an exact frame count (:attr:`FrameCount.exact`) that may fail to decode without a
warning; a shortfall of one frame is never warned about. Warning-only: it changes no score."""
SHORTFALL_ESTIMATED = 1 / 3
"""Share of a duration-based estimate (a container without a frame count: webm, mkv) that may fail
to decode without a warning: the estimate is duration x average frame rate (for a variable frame
rate, the packets counted and scaled to the duration: :func:`container_frame_count`). Warning-only."""
VIDEO_FILE_SUFFIXES: frozenset[str] = frozenset(
    {".mp4", ".avi", ".mov", ".webm", ".gif", ".mkv", ".m4v", ".mpg", ".mpeg", ".ts", ".mts", ".m2ts"}
)
"""Suffixes of video files: a folder holding these rather than frames is a dataset for ``geocon bench``."""
_RRD_MAGIC = (b"RRF0", b"RRF1", b"RRF2")
"""How a Rerun recording (``.rrd``) starts."""
_VIDEO_MAGIC = (b"GIF87a", b"GIF89a", b"RIFF", b"\x1aE\xdf\xa3", b"OggS", b"FLV")
_MP4_BOXES = (b"ftyp", b"moov", b"mdat", b"free", b"wide", b"skip", b"pnot")


class ClipError(ValueError):
    """Unusable input. ``str(err)`` is one sentence that names the file, e.g.
    ``"clip.mp4: no such file"`` or ``"one.png: has 1 frame; at least 2 are needed"``."""


@dataclass(frozen=True)
class FrameCount:
    """How many frames a container says its first video stream holds."""

    frames: int
    """The promised frame count (>= 1)."""
    exact: bool
    """True: counted in the container's index (mp4/mov ``stts``, avi header, a GIF scan), capped by
    the stream's duration x frame rate (an mp4 edit list hides frames the index still counts).
    False: estimated as duration x average frame rate (no count stored: webm, mkv)."""

    def falls_short(self, decoded: int) -> bool:
        """True if ``decoded`` frames are clearly fewer than promised: short by at least 2 frames
        and by more than :data:`SHORTFALL_EXACT` (exact counts) or :data:`SHORTFALL_ESTIMATED`
        (estimates) of the promise."""
        share = SHORTFALL_EXACT if self.exact else SHORTFALL_ESTIMATED
        return self.frames - decoded >= 2 and decoded < self.frames * (1.0 - share)


@dataclass(frozen=True)
class GifCut:
    """Where a GIF's block structure stops before its trailer block (``;``)."""

    complete: int
    """Images stored whole before the cut."""
    partial: bool
    """True if the cut falls inside image :attr:`complete` (0-based): a frame is lost for sure;
    False if it falls between blocks (frames may be missing, or only the trailer)."""


def resolve_clip(path: Path, name: str) -> tuple[ClipKind, list[Path] | None]:
    """The kind of the clip at ``path`` and, for an image folder, its frame files in natural
    order (None for a video or GIF). Raises :class:`ClipError` for anything unreadable."""
    if not path.exists():
        raise ClipError(f"{name}: no such file")
    if path.is_dir():
        files = _frame_files(path, name)
        if not files:
            videos = _videos_in(path)
            if videos:
                raise ClipError(
                    f"{name}: folder holds no PNG or JPEG frames but {videos} video file{'s' if videos > 1 else ''}: "
                    f"score them all with `geocon bench {shlex.quote(name)}`, or one with `geocon score FILE`"
                )
            raise ClipError(f"{name}: folder holds no PNG or JPEG frames")
        if len(files) == 1:
            raise ClipError(f"{name}: has 1 frame; at least 2 are needed")
        return "images", files
    if not path.is_file():
        raise ClipError(
            f"{name}: is {_entry_kind(path)}, not a clip file; GeoCon reads a clip twice (a probe, then the frames), "
            "so it needs a file: save the clip to one first"
        )
    if is_rerun_recording(path):
        raise ClipError(rerun_refusal(name))
    if path.suffix.lower() in ANIMATED_SUFFIXES and _animated_frames(path) >= 2:
        return "video", None  # an animated PNG or WebP: decoded by Pillow (open_video)
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


def _frame_files(folder: Path, name: str) -> list[Path]:
    """The frames of the image folder ``folder`` (given as ``name``): its entries with an image
    suffix, in natural order, less hidden ones (:func:`hidden_frames_note`). An entry with an image
    suffix that is not a regular file (a folder, a device, a FIFO, a socket, a link to one of them
    or to nothing) raises :class:`ClipError`: read, a device never ends and a FIFO blocks; left
    out, it would silently join its neighbours. So does one frame stored twice (:func:`_twice`)."""
    files: list[Path] = []
    odd: list[Path] = []
    for p in folder.iterdir():
        if p.suffix.lower() in IMAGE_SUFFIXES and not p.name.startswith("."):
            (files if p.is_file() else odd).append(p)
    if odd:
        bad = min(odd, key=_natural_key)
        raise ClipError(
            f"{bad}: is {_entry_kind(bad)}, not an image file, among the frames of {name}; a folder of frames must "
            "hold image files only, so move it out"
        )
    files.sort(key=_natural_key)
    _check_frame_sizes(files, name)
    twice = _twice(files)
    if twice is not None:
        a, b = twice
        raise ClipError(
            f"{a.name} and {b.name} in {name} look like one frame stored twice (the same name with another suffix, or "
            "a file manager's copy): a folder of frames holds one file per frame, so move one of them out"
        )
    return files


def _check_frame_sizes(files: Sequence[Path], name: str) -> None:
    """Refuse a frame file larger than :data:`~geocon_core.files.bounded.FRAME_IMAGE`'s bound
    (read whole to be decoded, it would fill the memory; no frame of a clip is that large)."""
    from ..files import FRAME_IMAGE, ReadRefused, regular_file

    for t, f in enumerate(files):
        try:
            regular_file(f, FRAME_IMAGE)
        except ReadRefused as exc:
            if exc.reason == "size":
                raise ClipError(f"{f}: is {exc.why} (frame {t} of {name}); check that it is a frame") from None


_COPY_NAME = re.compile(r"(.+?)(?: \(\d+\)| copy(?: \d+)?| - copy(?: \(\d+\))?)", re.IGNORECASE)
"""A file manager's name for a copy of ``NAME``: ``NAME (1)``, ``NAME copy``, ``NAME copy 2``,
``NAME - Copy``, ``NAME - Copy (2)``."""


def _twice(files: Sequence[Path]) -> tuple[Path, Path] | None:
    """Two frame files of one folder that hold one frame: the same name with another suffix
    (``00003.png`` and ``00003.jpg``, ``00003.PNG``), or a copy's name beside its original
    (``frame_0003 (1).png`` beside ``frame_0003.png``). Either would be scored as a frame of its own,
    sorted next to the original: a pair that does not move, or one that goes back in time."""
    stems: dict[str, Path] = {}
    for f in files:
        seen = stems.setdefault(f.stem.lower(), f)
        if seen is not f:
            return seen, f
    for f in files:
        m = _COPY_NAME.fullmatch(f.stem)
        if m is not None and m[1].lower() in stems:
            return stems[m[1].lower()], f
    return None


def hidden_frames_note(path: Path, name: str) -> tuple[str, ...]:
    """The note, if any, that the image folder ``path`` holds hidden files with an image suffix
    (``._00000.png``: the metadata macOS writes beside each file it copies to a foreign disk,
    ``.thumb.jpg``), which are not read as frames."""
    try:
        hidden = sorted(
            (p.name for p in path.iterdir() if p.name.startswith(".") and p.suffix.lower() in IMAGE_SUFFIXES),
            key=lambda n: _natural_key(Path(n)),
        )
    except OSError:
        return ()
    if not hidden:
        return ()
    shown = ", ".join(hidden[:3]) + (f" and {len(hidden) - 3} more" if len(hidden) > 3 else "")
    return (
        f"left out {len(hidden)} hidden file{'s' if len(hidden) > 1 else ''} of {name} ({shown}): names that start "
        "with a dot are not frames (macOS writes ._ files beside the files it copies)",
    )


def _entry_kind(path: Path) -> str:
    """What a folder entry that is not a regular file is, in words (``a link to a device``)."""
    link = "a link to " if path.is_symlink() else ""
    try:
        mode = path.stat().st_mode
    except OSError:
        return "a link to nothing (or a loop of links)" if link else "unreadable"
    if stat.S_ISDIR(mode):
        return link + "a folder"
    if stat.S_ISFIFO(mode):
        return link + "a FIFO (named pipe)"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return link + "a device"
    return link + ("a socket" if stat.S_ISSOCK(mode) else "not a regular file")


MAX_GAPS_NAMED = 8
"""Gaps in a frame folder's numbering named one by one; more are counted."""


def frame_number_gaps(files: Sequence[Path] | None, name: str) -> tuple[str, ...]:
    """The warning, if any, that the frames of an image folder (``files``, in natural order; None
    for a video) skip numbers: frames either side of a gap are scored as neighbours, one frame
    apart. The number is a name's last run of digits; the folder is judged only when every name
    has one, around the same text, and no number repeats. The step is the largest that fits every
    number (frames exported every other one, ``0, 2, 4``, have no gap)."""
    if not files or len(files) < 2:
        return ()
    shape, numbers = set(), []
    for f in files:
        m = re.fullmatch(r"(.*?)(\d+)(\D*)", f.stem)
        if m is None:
            return ()
        shape.add((m[1].lower(), m[3].lower(), f.suffix.lower()))
        numbers.append(int(m[2]))
    if len(shape) > 1 or len(set(numbers)) < len(numbers):
        return ()
    numbers.sort()
    step = math.gcd(*(b - a for a, b in itertools.pairwise(numbers)))
    gaps = [(a + step, b - step) for a, b in itertools.pairwise(numbers) if b - a > step]
    if not gaps:
        return ()
    spans = [str(lo) if lo == hi else f"{lo}-{hi}" for lo, hi in gaps[:MAX_GAPS_NAMED]]
    missing = sum((hi - lo) // step + 1 for lo, hi in gaps)
    more = f" and {len(gaps) - MAX_GAPS_NAMED} more gaps ({missing} in all)" if len(gaps) > MAX_GAPS_NAMED else ""
    by = f" (numbered in steps of {step})" if step > 1 else ""
    return (
        f"frame number{'s' if missing > 1 else ''} {', '.join(spans)}{more} {'are' if missing > 1 else 'is'} missing "
        f"from {name}{by}: the frames either side of a gap are scored as neighbours, one frame apart",
    )


def _videos_in(folder: Path, limit: int = 10_000) -> int:
    """Video files (:data:`VIDEO_FILE_SUFFIXES`) in ``folder`` and its sub-folders one level down
    (a dataset's platform folders), counting at most ``limit`` entries."""
    found = 0
    try:
        entries = list(itertools.islice(folder.iterdir(), limit))
        for entry in entries:
            if entry.is_dir():
                inner = itertools.islice(entry.iterdir(), limit)
                found += sum(p.suffix.lower() in VIDEO_FILE_SUFFIXES and p.is_file() for p in inner)
            elif entry.suffix.lower() in VIDEO_FILE_SUFFIXES and entry.is_file():
                found += 1
    except OSError:
        return found
    return found


def is_rerun_recording(path: Path) -> bool:
    """Whether the file at ``path`` is a Rerun recording (``.rrd`` suffix or its magic bytes)."""
    if path.suffix.lower() == ".rrd":
        return True
    try:
        with path.open("rb") as fh:
            return fh.read(4) in _RRD_MAGIC
    except OSError:
        return False


def rerun_refusal(name: str) -> str:
    """The sentence for a Rerun recording given where a clip or a record is expected: what it is,
    and the command that opens it."""
    return f"{name} is a Rerun recording, not a clip or a record: open it with `{rerun_command()} {shlex.quote(name)}`"


def rerun_command() -> str:
    """How to start the Rerun viewer from here: ``rerun`` when it is on the PATH, else the one
    installed beside this Python (a virtual environment that is not activated)."""
    if shutil.which("rerun"):
        return "rerun"
    beside = Path(sys.executable).parent / "rerun"
    if beside.is_file():
        rel = os.path.relpath(beside)
        return shlex.quote(rel if not rel.startswith("..") else str(beside))
    return "rerun"


def _natural_key(path: Path) -> tuple[list[tuple[int, int | str]], str]:
    """Sort key putting ``frame_2`` before ``frame_10`` (digit runs compare as numbers); the
    exact name breaks ties (``f01`` / ``f1``) so that the order never depends on the file system."""
    parts = re.split(r"(\d+)", path.name.lower())
    return [(0, int(p)) if p.isdigit() else (1, p) for p in parts if p], path.name


def _imread(path: Path) -> np.ndarray | None:
    """(h, w, 3) uint8 BGR of an image file (grey and alpha converted, 16 bit reduced), or None."""
    return imread_any(path)


def image_frames(files: list[Path], name: str) -> Iterator[np.ndarray]:
    """(h, w, 3) uint8 BGR frames of an image folder, one file at a time.

    A file that does not decode (corrupt or cut short) raises :class:`ClipError` naming it rather
    than being skipped: a skipped frame would silently join its neighbours into one pair, scored
    as one frame apart when two apart, and the folder's frame count would not reveal the loss."""
    for t, f in enumerate(files):
        bgr = _imread(f)
        if bgr is None:
            raise ClipError(f"{f}: cannot be decoded as an image (frame {t} of {name})")
        yield bgr


def _open_capture(name: str) -> cv2.VideoCapture:
    """An opened FFmpeg capture of ``name``; :class:`ClipError` if it cannot be opened."""
    try:
        with native_path(name) as safe:
            cap = cv2.VideoCapture(safe, cv2.CAP_FFMPEG)
            opened = cap.isOpened()
    except cv2.error as err:
        raise ClipError(f"{name}: unreadable bytes ({_cv_reason(err)})") from None
    if not opened:
        cap.release()
        if _looks_like_video(Path(name)):
            raise ClipError(f"{name}: unreadable bytes (a video header but no decodable stream)")
        raise ClipError(f"{name}: cannot be decoded as a video or image sequence")
    return cap


MAX_FPS = 1000.0
"""Stated frame rates from this many frames/s up are not taken as the clip's (a time base, such
as Matroska's 1000 or MPEG-TS's 90000, stated as a rate): :data:`DEFAULT_FPS` is used, and
:func:`timing_note` says so."""


def _fps(value: float | None) -> float:
    return value if value is not None and math.isfinite(value) and 0.0 < value < MAX_FPS else DEFAULT_FPS


def open_video(name: str) -> tuple[float, "Frames"]:
    """The frame rate of the video, GIF or animated image ``name`` (:data:`DEFAULT_FPS` when the
    container reports none) and an iterator over its (h, w, 3) uint8 BGR frames until the decoder
    stops.

    One decoder policy: OpenCV where it reads the stream (fast, the frames every record so far
    was scored on); PyAV for what OpenCV cannot read (AV1, and any stream OpenCV opens but decodes
    no frame of) and for interlaced streams, which it deinterlaces (``yadif``: one frame per frame);
    Pillow for animated PNG and WebP. The iterator's ``decoder`` names the one used."""
    if Path(name).suffix.lower() in ANIMATED_SUFFIXES and _animated_frames(Path(name)) >= 2:
        animated = PillowFrames(name)
        return animated.fps, animated
    peek = _pyav_peek(name)
    if peek is not None and peek.interlaced:
        return _fps(peek.fps), PyAVFrames(name, deinterlace=True)
    try:
        cap = _open_capture(name)
    except ClipError:
        if peek is None or not peek.decodes:
            raise
        return _fps(peek.fps), PyAVFrames(name)
    try:
        fps = float(cap.get(cv2.CAP_PROP_FPS))
    except cv2.error:
        fps = 0.0
    frames = CaptureFrames(cap, name)
    try:
        frames._pending = next(frames)
    except (StopIteration, ClipError):
        frames.close()
        if peek is not None and peek.decodes:
            return _fps(peek.fps), PyAVFrames(name)
        if frames.decoded == 0 and peek is None:
            raise ClipError(f"{name}: unreadable bytes (the container opened but no frame could be decoded)") from None
    return _fps(fps), frames


@dataclass(frozen=True)
class _Peek:
    """What PyAV sees of a video's first frame: whether it decodes, is interlaced, the frame rate;
    and the (w, h) of each of the file's video tracks (cover pictures left out), the first being
    the one decoded."""

    decodes: bool
    interlaced: bool
    fps: float | None
    tracks: tuple[tuple[int, int], ...] = ()


def _pyav_peek(name: str) -> _Peek | None:
    """PyAV's view of the first video frame of ``name`` (None when PyAV cannot open it); kept for
    the file as it is (a clip is opened twice per score: probe, then frames)."""
    try:
        st = os.stat(name)
    except OSError:
        return None
    return _pyav_peek_file(name, st.st_size, st.st_mtime_ns)


@functools.lru_cache(maxsize=64)
def _pyav_peek_file(name: str, _size: int, _mtime_ns: int) -> _Peek | None:
    import av

    try:
        with native_path(name) as safe, av.open(safe) as container:
            if not container.streams.video:
                return None
            stream = container.streams.video[0]
            rate = stream.average_rate or stream.guessed_rate
            fps = float(rate) if rate else None
            cover = av.stream.Disposition.attached_pic
            tracks = tuple(
                _track_size(s) for s in container.streams.video if s.index == stream.index or not s.disposition & cover
            )
            for frame in container.decode(stream):
                return _Peek(True, bool(getattr(frame, "interlaced_frame", False)), fps, tracks)
            return _Peek(False, False, fps, tracks)
    except (av.FFmpegError, OSError, ValueError, UnicodeError):
        return None


def _track_size(stream: Any) -> tuple[int, int]:
    """(w, h) of a video stream as its header states it; (0, 0) for a codec PyAV does not know."""
    context = getattr(stream, "codec_context", None)
    return (int(context.width or 0), int(context.height or 0)) if context is not None else (0, 0)


def video_tracks(name: str) -> tuple[tuple[int, int], ...]:
    """The (w, h) of each video track of the file ``name``, in the file's order (cover pictures
    left out); the first is the one :func:`open_video` decodes (as OpenCV and PyAV both do). Empty
    when PyAV cannot open the file."""
    peek = _pyav_peek(name)
    return () if peek is None else peek.tracks


UPRIGHT_TOLERANCE_DEG = 1.0
"""A display matrix within this many degrees of a quarter turn is applied to PyAV's frames (as
OpenCV applies it to its own); another angle, or a mirroring one, leaves the frames as stored."""


@dataclass(frozen=True)
class DisplayTurn:
    """How a video's display matrix (FFmpeg's ``DISPLAYMATRIX`` side data, a phone's orientation)
    shows its stored frames: turned ``degrees`` counter-clockwise, in (-180, 180], and ``mirrored``
    (a flip) or not."""

    degrees: float
    mirrored: bool

    def quarter_turns(self, tolerance_deg: float) -> int | None:
        """The counter-clockwise quarter turns (0 to 3) that the turn is, to within ``tolerance_deg``
        degrees; None when it is no multiple of 90 degrees."""
        turns = round(self.degrees / 90.0)
        return turns % 4 if abs(self.degrees - 90.0 * turns) <= tolerance_deg else None


def display_turn(frame: Any) -> DisplayTurn | None:
    """The :class:`DisplayTurn` of a decoded PyAV video ``frame`` (read before any reformat, which
    drops side data); None when it carries no display matrix. The angle is FFmpeg's
    ``av_display_rotation_get`` (the one OpenCV turns its frames by)."""
    import struct

    side = getattr(frame, "side_data", None)
    if side is None:
        return None
    data = next((bytes(sd) for sd in side if "DISPLAYMATRIX" in str(sd.type)), None)
    if data is None or len(data) < 36:
        return None
    m = struct.unpack("<9i", data[:36])
    scale0, scale1 = math.hypot(m[0], m[3]), math.hypot(m[1], m[4])
    if scale0 == 0 or scale1 == 0:
        return None
    degrees = -math.degrees(math.atan2(m[1] / scale1, m[0] / scale0))
    degrees = 180.0 if degrees <= -180.0 else degrees
    return DisplayTurn(degrees + 0.0, m[0] * m[4] - m[1] * m[3] < 0)


class _LibraryFrames(Iterator[np.ndarray]):
    """What :class:`PyAVFrames` and :class:`PillowFrames` share: the count of decoded frames, the
    error that ended the stream after the first one, and closing."""

    def __init__(self, name: str) -> None:
        self._name = name
        self.decoded = 0
        self.error: str | None = None

    def _stopped(self, err: Exception) -> StopIteration:
        """Close; before the first frame raise :class:`ClipError`, after it keep ``err`` and end."""
        self.close()
        if self.decoded == 0:
            raise ClipError(f"{self._name}: unreadable bytes ({err})") from None
        self.error = str(err)
        return StopIteration()

    def close(self) -> None:
        raise NotImplementedError

    def __del__(self) -> None:
        self.close()


class PyAVFrames(_LibraryFrames):
    """(h, w, 3) uint8 BGR frames decoded by PyAV (FFmpeg), with ``deinterlace`` through
    FFmpeg's ``yadif`` (one output frame per input frame). Same interface as
    :class:`CaptureFrames`."""

    def __init__(self, name: str, *, deinterlace: bool = False) -> None:
        import av

        super().__init__(name)
        self._av = av
        self.decoder = "pyav (deinterlaced: yadif)" if deinterlace else "pyav"
        with native_path(name) as safe:
            self._container: Any = av.open(safe)  # the file stays open after the link is gone
        stream = self._container.streams.video[0]
        self._decode = self._container.decode(stream)
        self._graph: Any = None
        self._queue: list[Any] = []
        self._flushed = False
        if deinterlace:
            graph = av.filter.Graph()
            src = graph.add_buffer(template=stream)
            yadif = graph.add("yadif", "mode=send_frame:parity=auto:deint=interlaced")
            sink = graph.add("buffersink")
            src.link_to(yadif)
            yadif.link_to(sink)
            graph.configure()
            self._graph = graph

    def _drain(self) -> None:
        while True:
            try:
                self._queue.append(self._graph.pull())
            except (self._av.BlockingIOError, self._av.EOFError):
                return

    def _next_frame(self) -> Any:
        if self._graph is None:
            return next(self._decode)
        while not self._queue:
            if self._flushed:
                raise StopIteration
            try:
                self._graph.push(next(self._decode))
            except StopIteration:
                self._graph.push(None)
                self._flushed = True
            self._drain()
        return self._queue.pop(0)

    def __next__(self) -> np.ndarray:
        if self._container is None:
            raise StopIteration
        try:
            frame = self._next_frame()
        except StopIteration:
            self.close()
            raise
        except self._av.FFmpegError as err:
            raise self._stopped(err) from None
        self.decoded += 1
        turn = display_turn(frame)  # read before the reformat, which drops the side data
        bgr = frame.to_ndarray(format="bgr24")
        turns = None if turn is None or turn.mirrored else turn.quarter_turns(UPRIGHT_TOLERANCE_DEG)
        # upright as OpenCV's own path shows a phone's clip (its display matrix applied)
        return np.ascontiguousarray(np.rot90(bgr, turns)) if turns else bgr

    def close(self) -> None:
        if getattr(self, "_container", None) is not None:
            self._container.close()
            self._container = None


class PillowFrames(_LibraryFrames):
    """(h, w, 3) uint8 BGR frames of an animated PNG or WebP, decoded by Pillow; ``fps`` from
    the first frame's duration. Same interface as :class:`CaptureFrames`."""

    decoder = "pillow"

    def __init__(self, name: str) -> None:
        from PIL import Image

        super().__init__(name)
        self._image: Any = Image.open(name)
        self._count = int(getattr(self._image, "n_frames", 1))
        duration = float(self._image.info.get("duration") or 0.0)  # ms
        self.fps = _fps(1000.0 / duration if duration > 0 else None)

    def __next__(self) -> np.ndarray:
        if self._image is None or self.decoded >= self._count:
            self.close()
            raise StopIteration
        try:
            self._image.seek(self.decoded)
            rgb = np.asarray(self._image.convert("RGB"))
        except (OSError, EOFError, ValueError) as err:
            raise self._stopped(err) from None
        self.decoded += 1
        return np.ascontiguousarray(rgb[..., ::-1])

    def close(self) -> None:
        if getattr(self, "_image", None) is not None:
            self._image.close()
            self._image = None


Frames = Union["CaptureFrames", PyAVFrames, PillowFrames]
"""A decoder's frame iterator (``decoded``, ``error``, ``decoder``, ``close()``)."""


def _animated_frames(path: Path) -> int:
    """Frames of an animated PNG or WebP (1 for a still image, 0 when Pillow cannot read it)."""
    try:
        from PIL import Image

        with Image.open(path) as im:
            return int(getattr(im, "n_frames", 1))
    except Exception:  # any unreadable image is "not animated"; the caller's own reading says why
        return 0


class CaptureFrames(Iterator[np.ndarray]):
    """(h, w, 3) uint8 BGR frames of an opened capture until the decoder stops; releases the
    capture when exhausted or closed. A decoder error before the first frame raises
    :class:`ClipError`; one after it ends the frames and is kept in :attr:`error`."""

    decoder = "opencv"
    """Which library decodes the frames (``opencv``; :class:`PyAVFrames` and :class:`PillowFrames`
    say theirs)."""

    def __init__(self, cap: cv2.VideoCapture, name: str) -> None:
        self._cap: cv2.VideoCapture | None = cap
        self._name = name
        self._pending: np.ndarray | None = None
        self.decoded = 0
        """Frames yielded so far."""
        self.error: str | None = None
        """The decoder's message if an error ended the stream after :attr:`decoded` frames."""

    def __next__(self) -> np.ndarray:
        if self._pending is not None:
            frame, self._pending = self._pending, None
            return frame
        if self._cap is None:
            raise StopIteration
        try:
            ok, frame = self._cap.read()
        except cv2.error as err:
            self.close()
            if self.decoded == 0:
                raise ClipError(f"{self._name}: unreadable bytes ({_cv_reason(err)})") from None
            self.error = _cv_reason(err)
            raise StopIteration from None
        if not ok or frame is None:
            self.close()
            raise StopIteration
        self.decoded += 1
        return _as_bgr(frame)

    def close(self) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None

    def __del__(self) -> None:
        self.close()


TIMING_PACKETS = 1000
"""Packets whose timestamps :func:`timing_note` reads (the start of a long clip tells)."""
TIMING_TOLERANCE = 0.25
"""Frame intervals that differ from their median by more than this share (or a median that differs
from the stated frame rate by more) are reported (:func:`timing_note`)."""


@dataclass(frozen=True)
class FrameTiming:
    """The intervals between the presentation times of a video's frames, in seconds."""

    median: float
    low: float
    """The shortest interval."""
    high: float
    """The longest interval."""
    mean: float
    """The mean interval (exact where timestamps are rounded: Matroska's millisecond stamps put a
    29.97 frames/s clip's frames 33 or 34 ms apart)."""

    @property
    def variable(self) -> bool:
        """A variable frame rate: an interval differs from the median by more than :data:`TIMING_TOLERANCE`."""
        return self.high > self.median * (1 + TIMING_TOLERANCE) or self.low < self.median * (1 - TIMING_TOLERANCE)

    def keeps(self, fps: float) -> bool:
        """Whether the median interval is that of ``fps`` frames/s, to within :data:`TIMING_TOLERANCE`."""
        return abs(1.0 / self.median - fps) <= TIMING_TOLERANCE * fps


def frame_timing(stamps: Sequence[int | None], time_base: Any) -> FrameTiming | None:
    """The :class:`FrameTiming` of frames stamped ``stamps`` (in units of ``time_base``, any order,
    None for a frame without a time); None when fewer than 3 frames carry a time or fewer than two
    intervals are positive."""
    pts = sorted(t for t in stamps if t is not None)
    if time_base is None or len(pts) < 3:
        return None
    gaps = np.diff(np.asarray(pts, dtype=np.float64)) * float(time_base)
    gaps = gaps[gaps > 0]
    if len(gaps) < 2:
        return None
    return FrameTiming(float(np.median(gaps)), float(gaps.min()), float(gaps.max()), float(gaps.mean()))


def timing_note(name: str, fps: float) -> str | None:
    """One sentence when the container's timestamps disagree with a steady ``fps``: a variable
    frame rate (:attr:`FrameTiming.variable`), or a stated rate the timestamps do not keep. Reads
    packet timestamps only (no decoding); None when they agree or cannot be read. A stated rate that
    ``fps`` replaced (one of :data:`MAX_FPS` or more) is named as such, whatever the timestamps say."""
    import av

    try:
        with native_path(name) as safe, av.open(safe) as container:
            if not container.streams.video:
                return None
            stream = container.streams.video[0]
            base = stream.time_base
            rate = stream.average_rate or stream.guessed_rate
            codec = stream.codec_context.name
            stamps = [p.pts for p in itertools.islice(container.demux(stream), TIMING_PACKETS)]
    except (av.FFmpegError, OSError, ValueError, UnicodeError):
        return None
    if len(stamps) >= 2 and all(t is None for t in stamps):
        return (
            f"the file stores no timestamps (a bare {codec} stream, outside any container such as MP4), so no frame "
            f"rate: durations in the record use {fps:g} frames/s"
        )
    stated = float(rate) if rate else 0.0
    if stated >= MAX_FPS and fps < MAX_FPS:
        return (
            f"the container states {stated:g} frames/s, which GeoCon does not take as a frame rate (it reads rates "
            f"below {MAX_FPS:g} frames/s); durations in the record use {fps:g} frames/s"
        )
    timing = frame_timing(stamps, base)
    if timing is None:
        return None
    if timing.variable:
        return (
            f"variable frame rate: frames are {1000 * timing.low:.0f} to {1000 * timing.high:.0f} ms apart (the "
            f"container states {fps:g} frames/s); frame pairs are taken frame by frame, so a gap of g frames is not a "
            "fixed time"
        )
    if not timing.keeps(fps):
        return (
            f"the container states {fps:g} frames/s but its timestamps are {1000 * timing.median:.0f} ms apart "
            f"({1.0 / timing.median:.3g} frames/s); durations in the record use the stated rate"
        )
    return None


def container_frame_count(name: str) -> FrameCount | None:
    """What the container of the video or GIF ``name`` promises about its first video stream's
    frame count (see :class:`FrameCount`), read from its header and index without decoding; None
    when it states neither a count nor a duration and frame rate, or cannot be parsed."""
    import av  # a core dependency; loaded only when a clip is probed

    try:
        with native_path(name) as safe, av.open(safe) as container:
            if not container.streams.video:
                return None
            stream = container.streams.video[0]
            index = int(stream.frames or 0)
            rate = stream.average_rate
            duration, time_base = stream.duration, stream.time_base
            own = duration is not None and time_base is not None  # the stream's own duration
            if duration is not None and time_base is not None:  # (spelt out: mypy narrows on it)
                seconds = float(duration * time_base)
            else:  # Matroska stores no per-stream duration: its track tag, else the container's
                seconds = _track_seconds(container, stream)
            by_duration = round(seconds * float(rate)) if rate and seconds > 0 and math.isfinite(seconds) else 0
            if index == 0 and by_duration > 0:
                by_stamps = _variable_rate_estimate(container, stream, seconds)
                if by_stamps is not None:
                    return by_stamps
    except (av.error.FFmpegError, OSError, ValueError, ZeroDivisionError):
        return None
    if index > 0:
        return FrameCount(min(index, by_duration) if own and by_duration > 0 else index, exact=True)
    return FrameCount(by_duration, exact=False) if by_duration > 0 else None


def _variable_rate_estimate(container: Any, stream: Any, seconds: float) -> FrameCount | None:
    """For a stream without a frame count whose first :data:`TIMING_PACKETS` packets are stamped at
    a variable frame rate (:attr:`FrameTiming.variable`): the frames its packets hold, scaled up by
    the share of the duration ``seconds`` they leave uncovered (a file cut short holds packets up to
    the cut only); None for a steady rate, whose duration x rate stands. Duration x average rate
    would take the rate of the first frames for the whole clip (a clip that slows down after a
    second would promise several times the frames it holds). Reads packets only (no decoding)."""
    packets = container.demux(stream)
    stamps = [p.pts for p in itertools.islice(packets, TIMING_PACKETS) if p.size]
    timing = frame_timing(stamps, stream.time_base)
    if timing is None or not timing.variable:
        return None
    stamps += [p.pts for p in packets if p.size]
    pts = [t for t in stamps if t is not None]
    covered = (max(pts) - min(pts)) * float(stream.time_base) + timing.median  # the last frame lasts a median interval
    return FrameCount(max(len(pts), round(len(pts) * seconds / covered)), exact=False)


def _hms(text: str) -> float | None:
    """Seconds of a ``HH:MM:SS.fraction`` duration tag (Matroska's per-track ``DURATION``)."""
    match = re.fullmatch(r"\s*(\d+):(\d{1,2}):(\d{1,2}(?:\.\d*)?)\s*", text)
    if match is None:
        return None
    h, m, sec = match.groups()
    return int(h) * 3600 + int(m) * 60 + float(sec)


def _track_seconds(container: Any, stream: Any) -> float:
    """How long the video ``stream`` lasts when the container stores no duration per stream
    (Matroska, WebM), 0 when unknown: the track's ``DURATION`` tag, else the container's duration
    when the video is its only stream. The container's duration spans every track (a longer audio
    track, a second video track), so it says nothing about this one's frames when there are
    others. Both may be counted from time 0 rather than from the track's first frame (FFmpeg's
    Matroska muxer writes the end time), so a duration longer than the start time is taken as the
    end time and the start is subtracted: a clip whose timestamps start late (at 10^6 s) is not
    taken for a clip that long."""
    start = 0.0
    if stream.start_time is not None and stream.time_base is not None:
        start = max(0.0, float(stream.start_time * stream.time_base))
    tag = next((v for k, v in stream.metadata.items() if k.upper() == "DURATION"), None)
    seconds = _hms(tag) if isinstance(tag, str) else None
    if seconds is None:
        if len(container.streams) != 1 or not container.duration:
            return 0.0
        seconds = container.duration / 1e6
        if container.start_time:
            start = max(start, container.start_time / 1e6)
    return seconds - start if start and seconds > start else seconds


def gif_cut(path: Path) -> GifCut | None:
    """None if the GIF at ``path`` runs block by block to its trailer; else where it stops (end
    of file or an unknown block). Reads the file, without decoding its images."""
    try:
        data = path.read_bytes()
    except OSError:
        return None
    if len(data) < 13 or not data.startswith(b"GIF8"):
        return None  # not a GIF to check; the decoder has had its say
    pos, images = 13, 0
    if data[10] & 0x80:  # global colour table
        pos += 3 * (2 << (data[10] & 7))
    while pos < len(data):
        block = data[pos]
        if block == 0x3B:
            return None
        if block == 0x21:  # extension: introducer, label, sub-blocks
            pos += 2
        elif block == 0x2C:  # image: descriptor, local colour table, LZW code size, sub-blocks
            if pos + 10 > len(data):
                return GifCut(images, partial=True)
            flags = data[pos + 9]
            pos += 10 + (3 * (2 << (flags & 7)) if flags & 0x80 else 0) + 1
        else:
            return GifCut(images, partial=False)
        while pos < len(data) and data[pos] != 0:
            pos += 1 + data[pos]
        if pos >= len(data):
            return GifCut(images, partial=block == 0x2C)
        pos += 1  # the block terminator
        images += block == 0x2C
    return GifCut(images, partial=False)


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
