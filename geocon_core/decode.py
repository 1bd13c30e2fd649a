"""Decoding the frames of a clip file or image folder, one at a time, as (h, w, 3) uint8 BGR.

Used by :mod:`geocon_core.reader`; every failure is a :class:`ClipError` whose message is one
sentence that names the file.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Literal

import cv2
import numpy as np

__all__ = ["ClipError", "ClipKind", "DEFAULT_FPS", "IMAGE_SUFFIXES", "resolve_clip", "image_frames", "open_video"]

ClipKind = Literal["video", "gif", "images"]

IMAGE_SUFFIXES: frozenset[str] = frozenset({".png", ".jpg", ".jpeg"})
"""File suffixes (lower case) read as frames of an image folder."""

DEFAULT_FPS = 24.0
"""Frame rate for image folders and for containers that report none."""
_VIDEO_MAGIC = (b"GIF87a", b"GIF89a", b"RIFF", b"\x1aE\xdf\xa3", b"OggS", b"FLV")
_MP4_BOXES = (b"ftyp", b"moov", b"mdat", b"free", b"wide", b"skip", b"pnot")


class ClipError(ValueError):
    """Unusable input. ``str(err)`` is one sentence that names the file, e.g.
    ``"clip.mp4: no such file"`` or ``"one.png: has 1 frame; at least 2 are needed"``."""


def resolve_clip(path: Path, name: str) -> tuple[ClipKind, list[Path] | None]:
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


def image_frames(files: list[Path], name: str) -> Iterator[np.ndarray]:
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


def open_video(name: str) -> tuple[float, Iterator[np.ndarray]]:
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
