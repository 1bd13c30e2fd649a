"""Making the clips of validation cases, once, in a cache folder.

A synthetic scene (family, failure, severity, size, frames, seed) is rendered once as lossless
PNG frames (with its ground truth, :func:`geocon_core.synth.write_clip`) and encoded from those
frames into H.264 at each CRF it is scored at. A real clip longer than ``max_frames`` is cut to its
first frames, stored as lossless PNG frames of the decoded video (so its compression artefacts are
kept as they are). Each entry's folder name carries a digest of its parameters and of the code
that makes it, so a changed renderer never reuses a stale clip; an entry is complete when its
``done.json`` exists.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from .cases import CODEC_CRF, CaseSpec, ValidationPlan

__all__ = ["PreparedClip", "code_digest", "prepare_key", "prepare_case", "clip_for"]

_DONE = "done.json"
_FPS = 24.0


@dataclass(frozen=True)
class PreparedClip:
    """The clip to score for a case and, for a synthetic case, its ground truth (``.gt.json``)."""

    clip: Path
    truth: Path | None


def code_digest() -> str:
    """A digest of the source of the code that makes the clips (the synthetic renderer and the
    video writer), 12 hex digits."""
    import geocon_core

    root = Path(geocon_core.__file__).resolve().parent
    h = hashlib.sha256()
    for path in sorted([*root.joinpath("synth").glob("*.py"), root / "media" / "video.py", root / "_version.py"]):
        h.update(path.name.encode())
        h.update(path.read_bytes())
    return h.hexdigest()[:12]


def _digest(*parts: object) -> str:
    return hashlib.sha256(json.dumps([str(p) for p in parts]).encode()).hexdigest()[:12]


def prepare_key(case: CaseSpec, plan: ValidationPlan, code: str) -> str:
    """The cache folder name of a case's clip; cases that share a rendering (the codecs of one
    synthetic scene) share the key."""
    if case.kind == "synthetic":
        slug = f"{case.family}-{case.failure or 'clean'}-{case.severity or 0:g}-h{case.height}"
        return f"synth-{slug}-{_digest(slug, case.width, plan.frames, plan.seed, code)}"
    src = Path(str(case.source))
    stat = src.stat()
    return f"real-{src.stem}-{_digest(src.resolve(), stat.st_size, stat.st_mtime_ns, plan.max_frames, code)}"


def clip_for(case: CaseSpec, folder: Path) -> PreparedClip:
    """Where the prepared clip of ``case`` lies in its cache folder (see :func:`prepare_case`)."""
    done = json.loads((folder / _DONE).read_text())
    if case.kind == "real":
        return PreparedClip(Path(done["clip"]), None)
    truth = folder / done["truth"]
    if case.codec == "png":
        return PreparedClip(folder / done["frames"], truth)
    return PreparedClip(folder / f"{done['clip_id']}.{case.codec}.mp4", truth)


def prepare_case(case: CaseSpec, plan: ValidationPlan, cache: Path, code: str, codecs: tuple[str, ...]) -> Path:
    """Make the clip of ``case`` (and, for a synthetic scene, its encodings for every codec in
    ``codecs``) in ``cache`` unless it is there; returns its folder."""
    folder = cache / prepare_key(case, plan, code)
    if not (folder / _DONE).is_file():
        tmp = folder.with_name(folder.name + ".part")
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir(parents=True)
        start = time.perf_counter()
        done = _render(case, plan, tmp) if case.kind == "synthetic" else _cut(case, plan, tmp, folder)
        done["seconds"] = round(time.perf_counter() - start, 3)
        (tmp / _DONE).write_text(json.dumps(done, indent=1) + "\n")
        shutil.rmtree(folder, ignore_errors=True)
        tmp.rename(folder)
    if case.kind == "synthetic":
        _encode(folder, codecs, _FPS)
    return folder


def _render(case: CaseSpec, plan: ValidationPlan, out: Path) -> dict:
    from ..synth import ClipPlan, write_clip

    assert case.family is not None and case.height is not None and case.width is not None
    gt = write_clip(
        ClipPlan(case.family, case.failure, case.severity),
        out,
        seed=plan.seed,
        width=case.width,
        height=case.height,
        num_frames=plan.frames,
        fps=_FPS,
        codec="png",
    )
    return {"clip_id": gt.clip_id, "frames": gt.video_path, "truth": f"{gt.clip_id}.gt.json"}


def _encode(folder: Path, codecs: tuple[str, ...], fps: float) -> None:
    """Encode a rendered scene's PNG frames as H.264 at each CRF of ``codecs`` that is missing."""
    from ..media import Mp4Writer

    done = json.loads((folder / _DONE).read_text())
    frames = sorted((folder / done["frames"]).glob("*.png"))
    for codec in codecs:
        target = folder / f"{done['clip_id']}.{codec}.mp4"
        if codec not in CODEC_CRF or target.is_file():
            continue
        h, w = _imread(frames[0]).shape[:2]
        tmp = target.with_name(f".{target.name}.part")
        with Mp4Writer(tmp, w, h, fps, crf=CODEC_CRF[codec]) as writer:
            for f in frames:
                writer.write(np.ascontiguousarray(_imread(f)[..., ::-1]))
        tmp.replace(target)


def _cut(case: CaseSpec, plan: ValidationPlan, out: Path, final: Path) -> dict:
    """Cut a real clip to its first ``plan.max_frames`` frames when it is longer; a clip that is
    short enough is scored as it is."""
    src = Path(str(case.source))
    frames_dir = out / "frames"
    frames_dir.mkdir()
    kept = 0
    for bgr in _frames(src):
        if kept == plan.max_frames:
            return {"clip": str(final / "frames"), "frames": kept, "cut": True, "source": str(src)}
        name = frames_dir / f"{kept:05d}.png"
        if not cv2.imwrite(str(name), bgr):
            raise OSError(f"could not write {name}")
        kept += 1
    shutil.rmtree(frames_dir)
    return {"clip": str(src), "frames": kept, "cut": False}


def _imread(path: Path) -> np.ndarray:
    """(h, w, 3) uint8 BGR image; OSError when it cannot be decoded."""
    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if bgr is None:
        raise OSError(f"{path}: cannot be decoded as an image")
    return bgr


def _frames(src: Path) -> Iterator[np.ndarray]:
    """The decoded BGR frames of a video file or an image folder, one at a time."""
    if src.is_dir():
        for f in sorted(p for p in src.iterdir() if p.suffix.lower() in (".png", ".jpg", ".jpeg")):
            yield _imread(f)
        return
    cap = cv2.VideoCapture(str(src), cv2.CAP_FFMPEG)
    try:
        while True:
            ok, bgr = cap.read()
            if not ok:
                return
            yield bgr
    finally:
        cap.release()
