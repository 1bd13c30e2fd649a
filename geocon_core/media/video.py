"""Writing video files. H.264 in MP4 through PyAV (OpenCV's wheels cannot encode H.264),
single-threaded so that the same frames always give the same bytes; or lossless PNG frames in
a folder (the image-folder input of :mod:`geocon_core.media.reader`)."""

from __future__ import annotations

import contextlib
from fractions import Fraction
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np

__all__ = ["Mp4Writer", "PngSequenceWriter"]


class Mp4Writer:
    """Stream RGB frames (H, W, 3) uint8 into an H.264 MP4 (yuv420p, so W and H must be even).

    ``crf`` sets the quality (0 lossless in luma and chroma as coded, 18 visually lossless;
    default 12 keeps sub-pixel geometry intact for tests). Use as a context manager."""

    def __init__(self, path: str | Path, width: int, height: int, fps: float, *, crf: int = 12) -> None:
        import av

        if width % 2 or height % 2:
            raise ValueError(f"H.264 (yuv420p) needs an even width and height, got {width}x{height}")
        self.path = Path(path)
        self.width, self.height = width, height
        # Written through a Python file: any file name works, and a full disk is an OSError here
        # rather than a failure inside the encoder's own file handling.
        self._file: Any = open(self.path, "wb")  # noqa: SIM115  # closed in close()
        try:
            self._container: Any = av.open(self._file, mode="w", format="mp4")
        except BaseException:
            self._file.close()
            raise
        rate = Fraction(fps).limit_denominator(1001)
        # x264's macroblock-tree rate control gave different bytes for the same frames from run to
        # run (seen with PyAV 18.1 / libx264 in its wheel); without it the output is reproducible.
        options = {"crf": str(crf), "preset": "medium", "x264-params": "mbtree=0"}
        self._stream = self._container.add_stream("libx264", rate=rate, options=options)
        self._stream.width, self._stream.height = width, height
        self._stream.pix_fmt = "yuv420p"
        self._stream.thread_count = 1
        self._av = av
        self.frames_written = 0

    def write(self, rgb: np.ndarray) -> None:
        if rgb.shape != (self.height, self.width, 3) or rgb.dtype != np.uint8:
            raise ValueError(f"expected ({self.height}, {self.width}, 3) uint8, got {rgb.shape} {rgb.dtype}")
        frame = self._av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb), format="rgb24")
        for packet in self._stream.encode(frame):
            self._container.mux(packet)
        self.frames_written += 1

    def close(self) -> None:
        if self._container is None:
            return
        try:
            for packet in self._stream.encode():
                self._container.mux(packet)
            self._container.close()
        finally:
            self._container = None
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
