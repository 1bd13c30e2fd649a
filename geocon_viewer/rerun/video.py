"""The frames of a recording as one AV1 video, encoded in memory as they arrive (SVT-AV1 through
PyAV), and the clean-up of what the encoder does to thread scheduling."""

from __future__ import annotations

import contextlib
import os
from typing import Any

import numpy as np

__all__ = ["FrameVideo", "MAX_RATE", "MIN_SIDE", "quiet_encoder_logs"]


def quiet_encoder_logs() -> None:
    """Let the AV1 encoder (SVT-AV1) print errors only, unless ``SVT_LOG`` is set already. The
    command line calls this before writing a recording; it changes the process environment."""
    os.environ.setdefault("SVT_LOG", "1")


def _thread_ids() -> set[int]:
    try:
        return {int(t) for t in os.listdir("/proc/self/task")}
    except OSError:
        return set()


def _is_realtime(tid: int) -> bool:
    with contextlib.suppress(OSError):
        return os.sched_getscheduler(tid) in (os.SCHED_FIFO, os.SCHED_RR)
    return False


class _EncoderThreads:
    """Undoes what SVT-AV1 does to scheduling, and nothing else.

    SVT-AV1 running as root gives its worker threads, and the thread that opens the encoder,
    ``SCHED_FIFO`` priority 99. Left alone, they and every process started afterwards (the rerun
    server, a browser) starve the rest of the machine; on two cores the box stops responding.
    This remembers the threads that ran under a real-time policy before the encoder opened (a
    caller's choice, kept) and puts every other real-time thread back to the normal policy."""

    def __init__(self) -> None:
        supported = hasattr(os, "sched_getscheduler") and hasattr(os, "sched_setscheduler")
        self.kept = {t for t in _thread_ids() if _is_realtime(t)} if supported else set()
        self.enabled = supported

    def restore(self) -> None:
        if not self.enabled:
            return
        for tid in _thread_ids() - self.kept:
            with contextlib.suppress(OSError):
                if _is_realtime(tid):
                    os.sched_setscheduler(tid, os.SCHED_OTHER, os.sched_param(0))


MIN_SIDE = 32
"""Frames whose shorter side (trimmed to even) is below this many pixels are not encoded: SVT-AV1
never returns from encoding a frame less than 32 px high that is 128 px wide or wider (or the
transposed), and refuses sides under 4 px. Such frames (a 2048x16 strip) are logged as images."""
MAX_RATE = 240
"""The highest frame rate SVT-AV1 accepts; a faster clip (a 960 frames/s slow-motion camera) is
encoded at this rate. Only the video's own playback speed changes: every frame is referenced by
the timestamp the container gives it."""


class FrameVideo:
    """Frames encoded into one AV1 mp4 in memory as they arrive (SVT-AV1, low-delay: no frame
    reordering), logged at the end as an ``AssetVideo`` with one ``VideoFrameReference`` per
    frame. AV1 decodes in both the native and the web viewer without extra software."""

    @staticmethod
    def encodes(width: int, height: int) -> bool:
        """Whether frames of ``width`` x ``height`` can go into the video (:data:`MIN_SIDE`)."""
        return min(width - width % 2, height - height % 2) >= MIN_SIDE

    def __init__(self, fps: float, crf: int) -> None:
        import io

        import av

        self.buf = io.BytesIO()
        self.container = av.open(self.buf, "w", format="mp4")
        self.fps, self.crf = fps, crf
        self.stream: Any = None
        self.indices: list[int] = []
        self._threads = _EncoderThreads()

    def add(self, index: int, rgb: np.ndarray) -> None:
        import av

        if self.stream is None:
            h, w = rgb.shape[:2]
            from fractions import Fraction

            rate = Fraction(min(self.fps, MAX_RATE)).limit_denominator(1001)
            st = self.container.add_stream("libsvtav1", rate=rate)
            st.width, st.height, st.pix_fmt = w - w % 2, h - h % 2, "yuv420p"
            st.options = {"preset": "10", "crf": str(self.crf), "svtav1-params": "pred-struct=1:keyint=48"}
            self.stream = st
        frame = av.VideoFrame.from_ndarray(
            np.ascontiguousarray(rgb[: self.stream.height, : self.stream.width]), format="rgb24"
        )
        frame.pts = len(self.indices)
        self.indices.append(index)
        for packet in self.stream.encode(frame):
            self.container.mux(packet)
        self._threads.restore()

    def finish(self) -> bytes | None:
        if self.stream is None:
            return None
        for packet in self.stream.encode():
            self.container.mux(packet)
        self.container.close()
        self._threads.restore()
        return self.buf.getvalue()
