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
the clean clip is the decoded source itself, never a round trip through RGB.
"""

from __future__ import annotations

import hashlib
import io
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import Any, BinaryIO, Iterator, Sequence

import numpy as np

from ..media import DEFAULT_FPS, ClipError, Mp4Writer, native_path, resolve_clip

__all__ = [
    "ENCODERS",
    "FALLBACK_CODEC",
    "MATCH_FRAMES",
    "PLANAR_FORMATS",
    "Encoder",
    "SourceVideo",
    "decode_planes",
    "file_sha256",
    "match_quality",
    "plane_writer",
    "probe_source",
]

PLANAR_FORMATS: tuple[str, ...] = ("yuv420p", "yuvj420p", "yuv422p", "yuvj422p", "yuv444p", "yuvj444p")
"""Pixel formats kept as they are (8-bit, one plane per component); other sources are converted
to ``yuv420p``."""

MATCH_FRAMES = 32
"""The quality is matched on at most this many first frames (each candidate quantiser encodes them once)."""


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
    (``work_format``), size (w, h), the ``frames`` used (the first ``frames``, at most the limit
    asked for) and the bits per pixel the source spends on them."""

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

    @property
    def encoder(self) -> Encoder:
        """The encoder of the source's family (:data:`ENCODERS`), H.264 for any other."""
        return ENCODERS.get(self.codec, ENCODERS[FALLBACK_CODEC])

    @property
    def subsampling(self) -> list[tuple[int, int]]:
        """(sx, sy) frame pixels per sample of each plane of :attr:`work_format`."""
        return subsampling_of(self.work_format, self.width, self.height)


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
    all when None). Raises :class:`ClipError` when it is no video or fewer than 2 frames decode."""
    import av

    container = _open(path)
    try:
        stream = container.streams.video[0]
        context = stream.codec_context
        codec, pix_fmt = str(context.name), str(context.pix_fmt or "")
        rate = stream.average_rate or stream.guessed_rate or Fraction(DEFAULT_FPS)
        sizes: list[tuple[int | None, int]] = [(p.pts, p.size) for p in container.demux(stream) if p.size]
    except av.FFmpegError as exc:
        container.close()
        raise ClipError(f"{path}: cannot be read as a video ({exc})") from None
    container.close()
    work = pix_fmt if pix_fmt in PLANAR_FORMATS else "yuv420p"
    count, width, height = 0, 0, 0
    for planes in decode_planes(path, work, max_frames):
        height, width = planes[0].shape
        count += 1
    if count < 2:
        raise ClipError(f"{path}: {count} frame{'s' if count != 1 else ''} decoded; at least 2 are needed")
    if "420" in work and (width % 2 or height % 2):
        raise ClipError(f"{path}: its {width}x{height} frames cannot be written in 4:2:0 (an odd side)")
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
    )


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
    in ``work_format``; decoding stops quietly at a damaged packet after the first frame."""
    import av

    container = _open(path)
    try:
        count = 0
        for frame in container.decode(video=0):
            if max_frames is not None and count >= max_frames:
                break
            if frame.format.name != work_format:
                frame = frame.reformat(format=work_format)
            yield [_plane_array(p) for p in frame.planes]
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
