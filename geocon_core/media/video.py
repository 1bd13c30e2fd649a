"""Writing video files. H.264 in MP4 through PyAV (OpenCV's wheels cannot encode H.264),
single-threaded so that the same frames always give the same bytes; or lossless PNG frames in
a folder (the image-folder input of :mod:`geocon_core.media.reader`)."""

from __future__ import annotations

import contextlib
from fractions import Fraction
from pathlib import Path
from types import TracebackType
from typing import Any, BinaryIO, Mapping, Sequence, cast

import numpy as np

__all__ = ["Mp4Writer", "PngSequenceWriter"]


class Mp4Writer:
    """Stream frames into an MP4, single-threaded so that the same frames give the same bytes.

    By default H.264 (libx264) in yuv420p at constant rate factor ``crf`` (0 lossless in luma
    and chroma as coded, 18 visually lossless; default 12 keeps sub-pixel geometry intact for
    tests), fed RGB frames (H, W, 3) uint8 through :meth:`write`. ``library``, ``options`` (they
    replace the crf options) and ``pix_fmt`` choose another encoder and format, fed planes through
    :meth:`write_planes` (how :mod:`geocon_core.plant` writes a clip encoded as its source was).
    ``target`` is a path or an open binary file (left open; an in-memory buffer to measure a
    rate); ``fps`` a float or an exact :class:`~fractions.Fraction`. Use as a context manager: a
    failure removes a partial file."""

    def __init__(
        self,
        target: str | Path | BinaryIO,
        width: int,
        height: int,
        fps: float | Fraction,
        *,
        crf: int = 12,
        library: str = "libx264",
        options: Mapping[str, str] | None = None,
        pix_fmt: str = "yuv420p",
    ) -> None:
        import av

        if pix_fmt.endswith("420p") and (width % 2 or height % 2):
            raise ValueError(f"{pix_fmt} needs an even width and height, got {width}x{height}")
        self.path = Path(target) if isinstance(target, (str, Path)) else None
        self.width, self.height, self.pix_fmt = width, height, pix_fmt
        # Written through a Python file: any file name works, and a full disk is an OSError here
        # rather than a failure inside the encoder's own file handling.
        self._file: Any = cast(Any, open(self.path, "wb") if self.path is not None else target)  # noqa: SIM115  # closed in close()
        try:
            self._container: Any = av.open(self._file, mode="w", format="mp4")
            rate = fps if isinstance(fps, Fraction) else Fraction(fps).limit_denominator(1001)
            if options is None:
                # x264's macroblock-tree rate control gave different bytes for the same frames from
                # run to run (seen with PyAV 18.1 / libx264 in its wheel); without it the output is
                # reproducible.
                options = {"crf": str(crf), "preset": "medium", "x264-params": "mbtree=0"}
            self._stream: Any = cast(Any, self._container.add_stream(library, rate=rate, options=dict(options)))
        except BaseException:
            if self.path is not None:
                self._file.close()
            raise
        self._stream.width, self._stream.height = width, height
        self._stream.pix_fmt = pix_fmt
        self._stream.thread_count = 1
        self._av = av
        self.frames_written = 0
        self.bytes = 0
        """Bytes of the encoded packets so far."""

    def write(self, rgb: np.ndarray) -> None:
        """Encode one RGB frame (H, W, 3) uint8."""
        if rgb.shape != (self.height, self.width, 3) or rgb.dtype != np.uint8:
            raise ValueError(f"expected ({self.height}, {self.width}, 3) uint8, got {rgb.shape} {rgb.dtype}")
        frame = self._av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb), format="rgb24")
        self._mux(self._stream.encode(frame))
        self.frames_written += 1

    def write_planes(self, planes: Sequence[np.ndarray]) -> None:
        """Encode one frame given as its planes in ``pix_fmt`` (uint8 arrays, luma first)."""
        frame = self._av.VideoFrame(self.width, self.height, self.pix_fmt)
        for plane, data in zip(frame.planes, planes, strict=True):
            rows = np.zeros((plane.height, plane.line_size), np.uint8)
            rows[:, : plane.width] = data
            plane.update(rows.tobytes())
        self._mux(self._stream.encode(frame))
        self.frames_written += 1

    def _mux(self, packets: Sequence[Any]) -> None:
        for packet in packets:
            self.bytes += packet.size
            self._container.mux(packet)

    def close(self) -> None:
        if self._container is None:
            return
        try:
            self._mux(self._stream.encode())
            self._container.close()
        finally:
            self._container = None
            if self.path is not None:
                self._file.close()

    def __enter__(self) -> "Mp4Writer":
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        if exc_type is None:
            self.close()
            return
        self.abort()

    def abort(self) -> None:
        """Stop without flushing the encoder (after a failure: a full disk, an interrupt) and
        remove the partial file; errors of the abandoned container are not raised over the first."""
        container, self._container = self._container, None
        if container is not None:
            with contextlib.suppress(Exception):
                container.close()
        if self.path is not None:
            with contextlib.suppress(OSError):
                self._file.close()
            self.path.unlink(missing_ok=True)


class PngSequenceWriter:
    """Stream RGB frames (H, W, 3) uint8 into a folder as lossless ``00000.png``, ``00001.png``,
    ... (natural order, as the reader reads image folders). Same interface as :class:`Mp4Writer`;
    on an exception the folder is removed."""

    def __init__(self, path: str | Path, width: int, height: int) -> None:
        self.path = Path(path)
        self.width, self.height = width, height
        self.path.mkdir(parents=True, exist_ok=True)
        self.frames_written = 0

    def write(self, rgb: np.ndarray) -> None:
        import cv2

        from .decode import imwrite_any

        if rgb.shape != (self.height, self.width, 3) or rgb.dtype != np.uint8:
            raise ValueError(f"expected ({self.height}, {self.width}, 3) uint8, got {rgb.shape} {rgb.dtype}")
        name = self.path / f"{self.frames_written:05d}.png"
        if not imwrite_any(name, np.ascontiguousarray(rgb[..., ::-1]), [cv2.IMWRITE_PNG_COMPRESSION, 3]):
            raise OSError(f"could not write frame {name}")
        self.frames_written += 1

    def close(self) -> None:
        pass

    def __enter__(self) -> "PngSequenceWriter":
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        if exc_type is not None:
            import shutil

            shutil.rmtree(self.path, ignore_errors=True)
