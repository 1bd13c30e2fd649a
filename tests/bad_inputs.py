"""Small inputs for the bad-input catalogue (``test_bad_input.py``) and the fuzz tests
(``test_fuzz_inputs.py``): textured frames, videos written with PyAV, GIFs, PNG folders, palette
PNGs, byte mutations and a byte-exact snapshot of a folder.

Everything is rendered from a seed, so the same call gives the same bytes."""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Sequence
from fractions import Fraction
from pathlib import Path

import cv2
import numpy as np

__all__ = [
    "broken_bench_clip",
    "texture",
    "pan_frames",
    "write_video",
    "write_gif",
    "write_audio_only",
    "write_pngs",
    "write_animated",
    "write_palette_png",
    "POSITIONS",
    "mutate",
    "snapshot",
]


def texture(width: int, height: int, seed: int = 0, *, mean: float | None = None) -> np.ndarray:
    """(height, width, 3) uint8 RGB: smooth random blobs with corners to track. ``mean`` shifts
    the brightness (a different histogram, for hard cuts)."""
    rng = np.random.default_rng(seed)
    small = rng.integers(0, 256, (max(height // 4, 2), max(width // 4, 2), 3), dtype=np.uint8)
    img = cv2.resize(small, (width, height), interpolation=cv2.INTER_CUBIC)
    if mean is not None:
        img = np.clip(img.astype(np.float32) * 0.4 + (mean - 0.4 * img.mean()), 0, 255).astype(np.uint8)
    return img


def pan_frames(
    width: int, height: int, num_frames: int, seed: int = 0, *, step: int = 2, mean: float | None = None
) -> list[np.ndarray]:
    """``num_frames`` RGB frames of a camera panning over a flat texture, ``step`` px per frame
    to the right and ``step / 2`` px down (a consistent clip)."""
    big = texture(width + step * num_frames + 8, height + step * num_frames + 8, seed, mean=mean)
    return [
        np.ascontiguousarray(big[t * step // 2 : t * step // 2 + height, t * step : t * step + width])
        for t in range(num_frames)
    ]


def write_video(
    path: str | Path,
    frames: Sequence[np.ndarray],
    *,
    container: str | None = None,
    codec: str = "libx264",
    fps: int = 24,
    faststart: bool = False,
    intra: bool = False,
    pts_ms: Sequence[int] | None = None,
    pix_fmt: str = "yuv420p",
    extra: dict[str, str] | None = None,
) -> Path:
    """Encode RGB ``frames`` with PyAV (single-threaded, so the bytes are reproducible).

    ``container`` forces the format (``"mov"``); ``faststart`` puts the ``moov`` box before the
    media data; ``intra`` makes every frame a key frame (frames of similar size, so a byte
    truncation cuts a predictable share of them); ``pts_ms`` gives each frame its own timestamp in
    milliseconds (a variable frame rate); ``extra`` adds encoder options (``x264-params``: interlaced=1)."""
    import av

    path = Path(path)
    h, w = frames[0].shape[:2]
    options: dict[str, str] = {}
    if codec == "libx264":
        options["preset"] = "ultrafast"
    if intra:
        options["g"] = "1"
    options.update(extra or {})
    with av.open(str(path), mode="w", format=container, options={"movflags": "faststart"} if faststart else {}) as c:
        stream = c.add_stream(codec, rate=fps, options=options)
        stream.width, stream.height, stream.pix_fmt = w, h, pix_fmt
        if codec != "libsvtav1":  # SVT-AV1 needs its own threads
            stream.thread_count = 1
        if pts_ms is not None:
            stream.codec_context.time_base = Fraction(1, 1000)
            stream.time_base = Fraction(1, 1000)
        for t, rgb in enumerate(frames):
            frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb), format="rgb24")
            if pts_ms is not None:
                frame.pts, frame.time_base = int(pts_ms[t]), Fraction(1, 1000)
            for packet in stream.encode(frame):
                c.mux(packet)
        for packet in stream.encode():
            c.mux(packet)
    return path


def _palette_332() -> np.ndarray:
    """(256, 4) uint8 RGBA: 8 levels of red and green, 4 of blue."""
    r, g, b = np.meshgrid(np.arange(8), np.arange(8), np.arange(4), indexing="ij")
    rgb = np.stack([r.ravel() * 255 // 7, g.ravel() * 255 // 7, b.ravel() * 255 // 3], axis=1)
    return np.concatenate([rgb, np.full((256, 1), 255)], axis=1).astype(np.uint8)


def write_gif(path: str | Path, frames: Sequence[np.ndarray], fps: int = 24) -> Path:
    """A GIF of RGB ``frames`` quantized to a fixed 256-colour palette by this function (the
    encoder's own conversion dithers differently per frame, so equal frames would not stay equal)."""
    import av

    path = Path(path)
    h, w = frames[0].shape[:2]
    palette = _palette_332()
    with av.open(str(path), mode="w", format="gif") as c:
        stream = c.add_stream("gif", rate=fps)
        stream.width, stream.height, stream.pix_fmt = w, h, "pal8"
        for rgb in frames:
            q = (rgb.astype(np.int32) * [7, 7, 3] + 127) // 255
            index = (q[..., 0] * 32 + q[..., 1] * 4 + q[..., 2]).astype(np.uint8)
            for packet in stream.encode(av.VideoFrame.from_ndarray((index, palette), format="pal8")):
                c.mux(packet)
        for packet in stream.encode():
            c.mux(packet)
    return path


def write_audio_only(path: str | Path, seconds: float = 0.5) -> Path:
    """An MP4 (``.m4a`` layout) holding one AAC audio stream and no video."""
    import av

    path = Path(path)
    rate = 16000
    with av.open(str(path), mode="w", format="mp4") as c:
        stream = c.add_stream("aac", rate=rate)
        stream.layout = "mono"
        samples = (np.sin(np.arange(int(rate * seconds)) * 2 * np.pi * 440 / rate) * 0.3).astype(np.float32)
        chunk = 1024
        for start in range(0, len(samples), chunk):
            frame = av.AudioFrame.from_ndarray(samples[None, start : start + chunk], format="fltp", layout="mono")
            frame.sample_rate, frame.pts = rate, start
            for packet in stream.encode(frame):
                c.mux(packet)
        for packet in stream.encode():
            c.mux(packet)
    return path


def write_pngs(folder: str | Path, frames: Sequence[np.ndarray]) -> Path:
    """``folder/00000.png, ...``: RGB frames written as BGR (or grey, 2-D frames), 8 or 16 bit."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    for t, img in enumerate(frames):
        out = img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_RGB2BGR)
        assert cv2.imwrite(str(folder / f"{t:05d}.png"), out)
    return folder


def write_palette_png(path: str | Path, ids: np.ndarray) -> Path:
    """An indexed (palette) PNG whose pixel indices are ``ids`` (h, w) uint8, with the DAVIS
    palette (index k gets a colour; the file's pixels are the indices, not colours)."""
    from PIL import Image

    palette = []
    for k in range(256):  # the DAVIS / PASCAL VOC colour map
        r = g = b = 0
        c = k
        for j in range(8):
            r |= ((c >> 0) & 1) << (7 - j)
            g |= ((c >> 1) & 1) << (7 - j)
            b |= ((c >> 2) & 1) << (7 - j)
            c >>= 3
        palette += [r, g, b]
    img = Image.fromarray(np.ascontiguousarray(ids, dtype=np.uint8), mode="P")
    img.putpalette(palette)
    img.save(path)
    return Path(path)


POSITIONS = 10_000
"""Positions of :func:`mutate` are in units of 1/POSITIONS of the current length."""


def mutate(data: bytes, ops: Sequence[tuple[str, int, int, bytes]]) -> bytes:
    """Apply byte mutations in order. Each op is ``(kind, at, n, payload)``: ``at`` in
    ``0..POSITIONS`` is a position as a share of the current length, ``n`` a count taken modulo
    the length: ``flip`` (xor the byte at ``at`` with ``n % 255 + 1``), ``truncate`` (keep the
    bytes before ``at``), ``insert`` (``payload`` before ``at``), ``overwrite`` (``payload`` over
    the bytes from ``at``), ``delete`` (``n % 64 + 1`` bytes from ``at``), ``zero`` (as many zero
    bytes from ``at``), ``repeat`` (the ``n % 64 + 1`` bytes from ``at`` twice)."""
    buf = bytearray(data)
    for kind, at, n, payload in ops:
        size = len(buf)
        i = min(at, POSITIONS) * size // POSITIONS
        if kind == "insert":
            buf[i:i] = payload
            continue
        if size == 0:
            continue
        i = min(i, size - 1)
        m = min(n % 64 + 1, size - i)
        if kind == "flip":
            buf[i] ^= n % 255 + 1
        elif kind == "truncate":
            del buf[i:]
        elif kind == "overwrite":
            buf[i : i + len(payload)] = payload
        elif kind == "delete":
            del buf[i : i + m]
        elif kind == "zero":
            buf[i : i + m] = bytes(m)
        elif kind == "repeat":
            buf[i:i] = buf[i : i + m]
        else:
            raise ValueError(f"unknown mutation {kind!r}")
    return bytes(buf)


SNAPSHOT_HASH_LIMIT = 64 << 20
"""Files larger than this (sparse stand-ins for huge inputs) are compared by size and mtime."""


def snapshot(root: str | Path) -> dict[str, str]:
    """Every file under ``root`` (relative path -> SHA-1 of its bytes; a symlink -> its target;
    a FIFO or device -> ``"special"``), without following links, so a symlink loop is listed, not
    entered, and without opening anything but regular files, so a FIFO cannot block it."""
    root = Path(root)
    found: dict[str, str] = {}
    for folder, dirs, files in os.walk(root, followlinks=False):
        for name in files + [d for d in dirs if os.path.islink(os.path.join(folder, d))]:
            p = Path(folder) / name
            rel = str(p.relative_to(root))
            if p.is_symlink():
                found[rel] = "-> " + os.readlink(p)
            elif p.is_file() and p.stat().st_size > SNAPSHOT_HASH_LIMIT:
                st = p.stat()
                found[rel] = f"{st.st_size} bytes, modified {st.st_mtime_ns}"
            elif p.is_file():
                found[rel] = hashlib.sha1(p.read_bytes()).hexdigest()
            else:
                found[rel] = "special"
    return found


def broken_bench_clip(root: Path) -> None:
    """A clip whose first frames decode (so it passes validation) but whose third frame is
    corrupt: scoring fails, and the failure must be recorded, not dropped."""
    folder = root / "broken" / "frames-c1"
    folder.mkdir(parents=True)
    rng = np.random.default_rng(0)
    img = (rng.random((90, 160, 3)) * 255).astype(np.uint8)
    for t in range(4):
        cv2.imwrite(str(folder / f"{t:03d}.png"), np.roll(img, t, axis=1))
    (folder / "002.png").write_bytes(b"\x89PNG\r\n\x1a\n truncated")
    meta = {
        "clip_id": "broken-c1",
        "prompt": "a corrupt upload",
        "model": "broken",
        "model_version": "1",
        "seed": 0,
        "resolution": [160, 90],
        "fps": 24,
        "duration": 4 / 24,
        "masks_path": None,
        "category": "C1",
        "scene_id": "C1-seed0",
    }
    (root / "broken" / "frames-c1.meta.json").write_text(json.dumps(meta))


def write_animated(path: str | Path, frames: Sequence[np.ndarray], fps: int = 8) -> Path:
    """An animated PNG (``.png``) or WebP (``.webp``, lossless) of RGB ``frames``, written by Pillow."""
    from PIL import Image

    path = Path(path)
    images = [Image.fromarray(np.ascontiguousarray(f)) for f in frames]
    extra = {"lossless": True} if path.suffix.lower() == ".webp" else {}
    images[0].save(path, save_all=True, append_images=images[1:], duration=round(1000 / fps), loop=0, **extra)
    return path
