"""Reading a source video as its planes, and writing clips encoded as it was.

A planted clip and its clean twin are encoded the same way, from the same decoded frames, so the
planted damage is the only difference between them. Both keep the source's frame size, frame rate
and pixel format (one of :data:`PLANAR_FORMATS`; any other is converted to ``yuv420p``) and use
the source's codec family where an encoder for it is here (:data:`ENCODERS`; others are written
as H.264). The quality is matched: the constant quantiser (QP) whose encode of the clean frames
(the first :data:`MATCH_FRAMES`) spends the bits per pixel closest to the source's over the same
frames (:func:`match_quality`). A constant quantiser and a fixed group of pictures (no adaptive
B-frames, no scene-cut key frames, no weighted prediction) keep the planted damage from changing
the frame types or the quantiser of the rest of the frame: the two encodes then differ outside the
damage only where the encoder's choices for a block looked at the damaged area (measured on five
RealEstate10K clips: the per-frame median of the optical flow from the clean to the planted clip
outside the region stays within 0.08 px, against 0.09-0.25 px with a constant rate factor, which
lets the frame's quantiser and the frame types follow the damage). Encoders run single-threaded
with settings that make them reproducible, so the same input gives the same bytes.

Frames are handled as planes (uint8 arrays, luma first) in the pixel format they are encoded in:
the clean clip is the decoded source itself, never a round trip through RGB. A source whose display
matrix turns its frames (a phone held upright) is decoded upright, as ``geocon score`` reads it:
its planes are turned by the matrix's quarter turns, and both clips are written upright with no
display matrix (a 4:2:2 source turned a quarter is handled in 4:4:4, :data:`WIDENED`, whose planes survive the
turn); a matrix that mirrors the picture or turns it by another angle is refused. Both clips are
written at a constant frame rate, the source's average; a source of variable frame rate is re-timed
so, and :attr:`SourceVideo.retiming` says so.
"""

from __future__ import annotations

import hashlib
import io
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import Any, BinaryIO, Iterator, Sequence

import numpy as np

from ..media import (
    DEFAULT_FPS,
    ClipError,
    FrameTiming,
    Mp4Writer,
    display_turn,
    frame_timing,
    native_path,
    resolve_clip,
)

__all__ = [
    "ENCODERS",
    "FALLBACK_CODEC",
    "MATCH_FRAMES",
    "PLANAR_FORMATS",
    "RETIME_TOLERANCE",
    "RIGHT_ANGLE_TOLERANCE_DEG",
    "WIDENED",
    "Encoder",
    "SourceVideo",
    "decode_planes",
    "file_sha256",
    "match_quality",
    "plane_writer",
    "probe_source",
    "upright_turns",
]

PLANAR_FORMATS: tuple[str, ...] = ("yuv420p", "yuvj420p", "yuv422p", "yuvj422p", "yuv444p", "yuvj444p")
"""Pixel formats kept as they are (8-bit, one plane per component); other sources are converted
to ``yuv420p``."""

MATCH_FRAMES = 32
"""The quality is matched on at most this many first frames (each candidate quantiser encodes them once)."""

RETIME_TOLERANCE = 0.005
"""A source of steady frame rate whose mean frame interval is within this share of the written
rate's is not re-timed (a mean over rounded stamps keeps 29.97 frames/s to 0.1%); beyond, the
ground truth and a warning say the frames are re-timed."""

WIDENED: dict[str, str] = {"yuv422p": "yuv444p", "yuvj422p": "yuvj444p"}
"""The format a 4:2:2 source turned a quarter is handled in (its chroma, halved across, would be
halved down once turned): each chroma sample is repeated across, so the frame holds exactly the
source's samples (FFmpeg's conversion interpolates them, 5-11 grey levels off on fine colour)."""

RIGHT_ANGLE_TOLERANCE_DEG = 1.0
"""A display matrix whose turn is within this many degrees of a multiple of 90 is that many quarter
turns (what phones write is exact); a turn further from one is refused."""


@dataclass(frozen=True)
class Encoder:
    """How clips of one codec family are written: the FFmpeg encoder, the option that sets its
    constant quantiser and that option's range, and the options that fix its group of pictures and
    make it reproducible."""

    codec: str
    library: str
    quality_option: str
    quality_range: tuple[int, int]
    options: dict[str, str]


ENCODERS: dict[str, Encoder] = {
    "h264": Encoder(
        "h264",
        "libx264",
        "qp",
        (1, 51),
        {"preset": "medium", "x264-params": "mbtree=0:b-adapt=0:scenecut=0:weightp=0"},
    ),
    "hevc": Encoder(
        "hevc",
        "libx265",
        "qp",
        (1, 51),
        {
            "preset": "medium",
            "x265-params": "log-level=error:pools=none:frame-threads=1:b-adapt=0:scenecut=0:weightp=0",
        },
    ),
}
"""The encoder per source codec family (FFmpeg's codec name). x264's macroblock-tree rate control
gave different bytes for the same frames from run to run, so it is off; x265 runs without thread
pools. QP 0 is left out (lossless in x264, a different coding mode)."""

FALLBACK_CODEC = "h264"
"""The family a source of any other codec (MPEG-4, VP9, AV1, GIF, ...) is written in."""


@dataclass(frozen=True)
class SourceVideo:
    """What the planting needs of a source clip: its file ``name`` and ``sha256``, the codec, pixel
    format and frame rate its first video stream states, the format its planes are handled in
    (``work_format``), the upright size (w, h), the ``frames`` used (the first ``frames``, at most
    the limit asked for) and the bits per pixel the source spends on them; ``rotation``, the
    counter-clockwise turn (0, 90, 180 or 270 degrees) its display matrix gives the stored frames,
    which are ``stored_size`` (w, h); ``timing``, the intervals of the frames used (None when
    fewer than 3 carry a time)."""

    path: Path
    name: str
    sha256: str
    codec: str
    pix_fmt: str
    work_format: str
    width: int
    height: int
    rate: Fraction
    frames: int
    bits_per_pixel: float
    rotation: int = 0
    stored_size: tuple[int, int] = (0, 0)
    timing: FrameTiming | None = None

    @property
    def encoder(self) -> Encoder:
        """The encoder of the source's family (:data:`ENCODERS`), H.264 for any other."""
        return ENCODERS.get(self.codec, ENCODERS[FALLBACK_CODEC])

    @property
    def subsampling(self) -> list[tuple[int, int]]:
        """(sx, sy) frame pixels per sample of each plane of :attr:`work_format`."""
        return subsampling_of(self.work_format, self.width, self.height)

    @property
    def retimed(self) -> bool:
        """Whether writing the frames at the constant :attr:`rate` changes when they are shown: the
        source's frames come at a variable rate (:attr:`~geocon_core.media.FrameTiming.variable`), or
        at a steady one whose mean interval is not that of :attr:`rate` (:data:`RETIME_TOLERANCE`)."""
        t = self.timing
        return t is not None and (t.variable or abs(float(self.rate) * t.mean - 1.0) > RETIME_TOLERANCE)

    @property
    def retiming(self) -> str | None:
        """One sentence saying how the frames are re-timed (None when they are not, :attr:`retimed`)."""
        if not self.retimed or self.timing is None:
            return None
        t = self.timing
        kind = (
            f"a variable frame rate (frames {1000 * t.low:.0f} to {1000 * t.high:.0f} ms apart)"
            if t.variable
            else f"its frames {1000 * t.mean:.3g} ms apart ({1.0 / t.mean:.4g} frames/s)"
        )
        return (
            f"{self.name} has {kind}; the planted and the clean clip are re-timed to a constant "
            f"{float(self.rate):.4g} frames/s (the average rate its container states): every frame is kept, but not "
            "shown when the source shows it"
        )

    def timing_entry(self) -> dict[str, Any]:
        """What the ground truth's ``source.timing`` says: the source's timing (``variable``,
        ``constant`` or ``unknown``), its frame intervals (ms), the constant rate written and
        whether that re-times the frames."""
        t = self.timing
        kind = "unknown" if t is None else "variable" if t.variable else "constant"
        entry: dict[str, Any] = {"source": kind}
        if t is not None:
            entry["intervals_ms"] = {
                "min": round(1000 * t.low, 3),
                "median": round(1000 * t.median, 3),
                "mean": round(1000 * t.mean, 3),
                "max": round(1000 * t.high, 3),
            }
        entry["written"] = f"constant {self.rate} frames/s"
        entry["retimed"] = self.retimed
        return entry


def subsampling_of(fmt: str, width: int, height: int) -> list[tuple[int, int]]:
    import av

    f = av.VideoFormat(fmt, width, height)
    planes: dict[int, tuple[int, int]] = {}
    for c in f.components:
        planes.setdefault(c.plane, (max(1, round(width / c.width)), max(1, round(height / c.height))))
    return [planes[i] for i in sorted(planes)]


def file_sha256(path: Path) -> str:
    """The SHA-256 of the bytes of ``path``, hex."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _open(path: Path) -> Any:
    """A PyAV container of ``path`` with a video stream; :class:`ClipError` in one sentence otherwise."""
    import av

    name = str(path)
    kind, _files = resolve_clip(path, name)  # a missing file, a FIFO, a recording, a single image: one sentence
    if kind == "images":
        raise ClipError(
            f"{name}: is a folder of frames; geocon plant reads a video file (it matches the video's codec and "
            "quality): encode the frames into one first"
        )
    try:
        with native_path(name) as safe:
            container = av.open(safe)
    except (av.FFmpegError, OSError, ValueError, UnicodeError) as exc:
        reason = getattr(exc, "strerror", None) or str(exc)
        raise ClipError(f"{name}: cannot be read as a video ({reason})") from None
    if not container.streams.video:
        container.close()
        raise ClipError(f"{name}: has no video stream")
    return container


def probe_source(path: Path, max_frames: int | None = None) -> SourceVideo:
    """Read what :class:`SourceVideo` holds from ``path`` (decoding its first ``max_frames`` frames,
    all when None). Raises :class:`ClipError` when it is no video, fewer than 2 frames decode or
    its display matrix cannot be written upright (:func:`upright_turns`)."""
    import av

    container = _open(path)
    try:
        stream = container.streams.video[0]
        context = stream.codec_context
        codec, pix_fmt = str(context.name), str(context.pix_fmt or "")
        rate = stream.average_rate or stream.guessed_rate or Fraction(DEFAULT_FPS)
        base = stream.time_base
        sizes: list[tuple[int | None, int]] = [(p.pts, p.size) for p in container.demux(stream) if p.size]
    except av.FFmpegError as exc:
        container.close()
        raise ClipError(f"{path}: cannot be read as a video ({exc})") from None
    container.close()
    turns = _first_frame_turns(path)
    work = pix_fmt if pix_fmt in PLANAR_FORMATS else "yuv420p"
    if turns % 2 and work in WIDENED:
        work = WIDENED[work]
    count, width, height = 0, 0, 0
    for planes in decode_planes(path, work, max_frames):
        height, width = planes[0].shape
        count += 1
    if count < 2:
        raise ClipError(f"{path}: {count} frame{'s' if count != 1 else ''} decoded; at least 2 are needed")
    if "420" in work and (width % 2 or height % 2):
        raise ClipError(f"{path}: its {width}x{height} frames cannot be written in 4:2:0 (an odd side)")
    stamps = sorted(pts for pts, _ in sizes if pts is not None)[:count]
    return SourceVideo(
        path=path,
        name=path.name,
        sha256=file_sha256(path),
        codec=codec,
        pix_fmt=pix_fmt,
        work_format=work,
        width=width,
        height=height,
        rate=Fraction(rate),
        frames=count,
        bits_per_pixel=_bits_per_pixel(sizes, count, width * height),
        rotation=90 * turns,
        stored_size=(height, width) if turns % 2 else (width, height),
        timing=frame_timing(stamps, base) if len(stamps) == count else None,
    )


def _first_frame_turns(path: Path) -> int:
    """:func:`upright_turns` of the first frame of ``path`` (0 when none decodes)."""
    import av

    container = _open(path)
    try:
        return next((upright_turns(frame, path) for frame in container.decode(video=0)), 0)
    except av.FFmpegError:
        return 0  # the decode that follows says what is wrong
    finally:
        container.close()


def upright_turns(frame: Any, path: Path) -> int:
    """The counter-clockwise quarter turns (0 to 3) that show the decoded ``frame`` of ``path``
    upright (its display matrix, :func:`~geocon_core.media.display_turn`: what ``geocon score``
    reads); 0 without one. Raises :class:`ClipError` for a matrix that mirrors the picture or turns
    it by an angle that is no multiple of 90 degrees (:data:`RIGHT_ANGLE_TOLERANCE_DEG`)."""
    turn = display_turn(frame)
    if turn is None:
        return 0
    upright = "re-encode it upright first (ffmpeg -i CLIP upright.mp4 applies the matrix)"
    if turn.mirrored:
        raise ClipError(
            f"{path}: its display matrix mirrors the picture (turned {turn.degrees:g} degrees and flipped), which "
            f"geocon plant does not write; {upright}"
        )
    turns = turn.quarter_turns(RIGHT_ANGLE_TOLERANCE_DEG)
    if turns is None:
        raise ClipError(
            f"{path}: its display matrix turns the picture {turn.degrees:g} degrees, not a multiple of 90, which "
            f"geocon plant does not write; {upright}"
        )
    return turns


def _bits_per_pixel(sizes: Sequence[tuple[int | None, int]], frames: int, pixels: int) -> float:
    """Bits per pixel the source spends on its first ``frames`` frames: the packets of the
    ``frames`` earliest presentation times (a share of all bytes when packets carry no times)."""
    if not sizes:
        return 0.0
    if all(pts is not None for pts, _ in sizes):
        first = sorted(sizes, key=lambda s: s[0] or 0)[:frames]
        total = float(sum(size for _, size in first))
    else:
        total = sum(size for _, size in sizes) * min(1.0, frames / len(sizes))
    return 8.0 * total / (pixels * frames)


def decode_planes(path: Path, work_format: str, max_frames: int | None = None) -> Iterator[list[np.ndarray]]:
    """The planes (uint8, luma first) of the first ``max_frames`` frames of ``path`` (all when None),
    in ``work_format``, upright: turned as the display matrix says (:func:`upright_turns`; a quarter
    turn needs a ``work_format`` whose chroma is halved alike in both directions, or not at all);
    decoding stops quietly at a damaged packet after the first frame."""
    import av

    container = _open(path)
    try:
        count = 0
        for frame in container.decode(video=0):
            if max_frames is not None and count >= max_frames:
                break
            turns = upright_turns(frame, path)  # before a reformat, which drops the side data
            if WIDENED.get(frame.format.name) == work_format:
                luma, *chroma = [_plane_array(p) for p in frame.planes]
                planes = [luma, *(np.repeat(c, 2, axis=1)[:, : luma.shape[1]] for c in chroma)]
            else:
                if frame.format.name != work_format:
                    frame = frame.reformat(format=work_format)
                planes = [_plane_array(p) for p in frame.planes]
            if turns:
                planes = [np.ascontiguousarray(np.rot90(p, turns)) for p in planes]
            yield planes
            count += 1
    except av.FFmpegError as exc:
        if count == 0:
            raise ClipError(f"{path}: cannot be read as a video ({exc})") from None
    finally:
        container.close()


def _plane_array(plane: Any) -> np.ndarray:
    rows = np.frombuffer(memoryview(plane), np.uint8).reshape(plane.height, plane.line_size)
    return rows[:, : plane.width].copy()


def plane_writer(
    target: Path | BinaryIO, encoder: Encoder, quality: int, fmt: str, width: int, height: int, rate: Fraction
) -> Mp4Writer:
    """A writer of frames given as planes (:meth:`~geocon_core.media.video.Mp4Writer.write_planes`)
    with ``encoder`` at quantiser ``quality``, in ``fmt`` at ``rate``, single-threaded (reproducible
    bytes). ``target`` is a path or a binary file object (an in-memory buffer for
    :func:`match_quality`)."""
    options = {encoder.quality_option: str(quality), **encoder.options}
    return Mp4Writer(target, width, height, rate, library=encoder.library, options=options, pix_fmt=fmt)


def match_quality(source: SourceVideo, sample: Sequence[Sequence[np.ndarray]]) -> tuple[int, float]:
    """The quantiser of :attr:`SourceVideo.encoder` whose encode of ``sample`` (the clean planes of
    the first frames) spends the bits per pixel closest (by ratio) to the source's, and that rate.
    A bisection over the integer quantisers (the rate falls as the quantiser grows)."""
    rates: dict[int, float] = {}

    def rate(quality: int) -> float:
        if quality not in rates:
            buffer = io.BytesIO()
            with plane_writer(
                buffer, source.encoder, quality, source.work_format, source.width, source.height, source.rate
            ) as writer:
                for planes in sample:
                    writer.write_planes(planes)
            rates[quality] = 8.0 * writer.bytes / (source.width * source.height * len(sample))
        return rates[quality]

    lo, hi = source.encoder.quality_range
    target = max(source.bits_per_pixel, 1e-6)
    while lo < hi:  # the lowest quantiser whose rate is at most the target (hi when none is)
        mid = (lo + hi) // 2
        if rate(mid) <= target:
            hi = mid
        else:
            lo = mid + 1
    best = lo
    if lo > source.encoder.quality_range[0] and abs(np.log(rate(lo - 1) / target)) < abs(np.log(rate(lo) / target)):
        best = lo - 1
    return best, rate(best)
