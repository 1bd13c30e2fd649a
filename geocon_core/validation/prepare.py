"""Making the clips of validation cases, once, in a cache folder.

A synthetic scene (family, failure, severity, size, frames, seed) is rendered once as lossless
PNG frames (with its ground truth, :func:`geocon_core.synth.write_clip`) and encoded from those
frames into H.264 at each CRF it is scored at. A real clip longer than ``max_frames`` is cut to its
first frames, stored as lossless PNG frames of the decoded video (so its compression artefacts are
kept as they are). A planted case is planted once (:func:`geocon_core.plant.plant_clip`, into the
real clip's first ``max_frames`` frames) and a clean re-encode made once per source clip
(:func:`geocon_core.plant.write_clean_clip`), keyed by the source's bytes (:func:`source_sha256`),
the kind, severity, seed and frames, the ground truth's format and :func:`plant_code_digest`. Each
entry's folder name carries a digest of its parameters and of the code that makes it, so a
changed renderer never reuses a stale clip; an entry is complete when its ``done.json`` exists.
``done.json`` also keeps the fingerprint of every clip the entry made (:data:`MADE_KEY`), so an
entry whose ``done.json`` is damaged or whose clip was replaced since is made again, and said so
(:func:`entry_problem`).
"""

from __future__ import annotations

import functools
import hashlib
import json
import shutil
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from ..files import SMALL_STATE, ReadRefused, read_text
from .cases import CODEC_CRF, CaseSpec, ValidationPlan, source_sha256

__all__ = [
    "PreparedClip",
    "code_digest",
    "plant_code_digest",
    "source_sha256",
    "prepare_key",
    "prepare_case",
    "clip_for",
]

_DONE = "done.json"
_FPS = 24.0
MADE_KEY = "made"
"""The key of ``done.json`` that maps each clip file or frame folder the entry made (its name in
the entry's folder) to its :func:`~geocon_core.media.clip_fingerprint`; entries made before it
was kept have none, and are taken as they are."""
_NEEDS: dict[str, tuple[str, ...]] = {
    "synthetic": ("clip_id", "frames", "truth"),
    "real": ("clip",),
    "planted": ("source",),
}
"""The keys a complete ``done.json`` of each case kind holds (a planted entry holds ``clip`` or ``error``)."""


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


@functools.cache
def plant_code_digest() -> str:
    """A digest of the source of the code that plants failures and re-encodes clips (the planting
    package, the synthetic fields and the optical flow it uses to follow its region) and of the
    PyAV version that encodes them, 12 hex digits."""
    import av

    import geocon_core

    root = Path(geocon_core.__file__).resolve().parent
    h = hashlib.sha256(str(av.__version__).encode())
    for sub in ("plant", "synth", "flow"):
        for path in sorted(root.joinpath(sub).glob("*.py")):
            h.update(f"{sub}/{path.name}".encode())
            h.update(path.read_bytes())
    h.update((root / "_version.py").read_bytes())
    return h.hexdigest()[:12]


def _digest(*parts: object) -> str:
    return hashlib.sha256(json.dumps([str(p) for p in parts]).encode()).hexdigest()[:12]


def prepare_key(case: CaseSpec, plan: ValidationPlan, code: str) -> str:
    """The cache folder name of a case's clip; cases that share a rendering (the codecs of one
    synthetic scene) share the key."""
    if case.kind == "synthetic":
        slug = f"{case.family}-{case.failure or 'clean'}-{case.severity or 0:g}-h{case.height}"
        return f"synth-{slug}-{_digest(slug, case.width, plan.frames, plan.seed, code)}"
    if case.kind == "planted":
        return _plant_key(case, plan)
    src = Path(str(case.source))
    stat = src.stat()
    return f"real-{src.stem}-{_digest(src.resolve(), stat.st_size, stat.st_mtime_ns, plan.max_frames, code)}"


def _plant_key(case: CaseSpec, plan: ValidationPlan) -> str:
    """The cache folder name of a planted case (or of its source's clean re-encode, which depends on
    neither the kind, the severity nor the seed: one per source clip and frames). The ground
    truth's format (:data:`geocon_core.plant.PLANT_FORMAT`) is part of the key: a new format
    re-plants."""
    from ..plant import PLANT_FORMAT

    src = Path(str(case.source))
    sha, stem = source_sha256(src), src.stem if src.suffix else src.name
    code = plant_code_digest()
    if case.failure is None:
        return f"plant-{stem}-clean-f{plan.max_frames}-{_digest(sha, plan.max_frames, PLANT_FORMAT, code)}"
    slug = f"{case.failure}-{case.level}-s{plan.seed}-f{plan.max_frames}"
    digest = _digest(sha, case.failure, case.level, plan.seed, plan.max_frames, PLANT_FORMAT, code)
    return f"plant-{stem}-{slug}-{digest}"


def _read_done(case: CaseSpec, folder: Path) -> dict:
    """The ``done.json`` of a cache entry; ValueError (one sentence naming it) when it is missing,
    not JSON or lacks what an entry of ``case``'s kind holds."""
    path = folder / _DONE
    try:
        done = json.loads(read_text(path, SMALL_STATE))  # a regular file within its bound
    except ReadRefused as exc:
        raise ValueError(f"{path} cannot be read ({exc.why})") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path} cannot be read ({type(exc).__name__})") from None
    if not isinstance(done, dict):
        raise ValueError(f"{path} is not the record of a finished cache entry (not a JSON object)")
    needs = _NEEDS[case.kind] + (() if case.kind != "planted" or "error" in done else ("clip",))
    if any(not isinstance(done.get(k), str) for k in needs):
        raise ValueError(f"{path} is not the record of a finished cache entry (it lacks {', '.join(needs)})")
    return done


def entry_problem(case: CaseSpec, folder: Path) -> str | None:
    """What is wrong with the finished cache entry of ``case`` in ``folder``: its ``done.json``
    damaged, or a clip it made (:data:`MADE_KEY`) replaced or removed since; None when it is
    whole (or not finished: no ``done.json``)."""
    from ..media import clip_fingerprint

    if not (folder / _DONE).is_file():
        return None
    try:
        done = _read_done(case, folder)
    except ValueError as exc:
        return str(exc)
    made = done.get(MADE_KEY, {})
    for name, fingerprint in made.items() if isinstance(made, dict) else ():
        if clip_fingerprint(folder / name) != fingerprint:
            state = "was replaced since it was made" if (folder / name).exists() else "is gone"
            return f"{folder / name} {state}"
    return None


def clip_for(case: CaseSpec, folder: Path) -> PreparedClip:
    """Where the prepared clip of ``case`` lies in its cache folder (see :func:`prepare_case`).
    ValueError (one sentence) for a planted case whose clip could not be planted, or an entry whose
    ``done.json`` is damaged."""
    done = _read_done(case, folder)
    if case.kind == "planted":
        if done.get("error"):
            raise ValueError(f"could not be planted: {done['error']}")
        return PreparedClip(folder / done["clip"], None if done.get("truth") is None else folder / done["truth"])
    if case.kind == "real":
        return PreparedClip(Path(done["clip"]), None)
    truth = folder / done["truth"]
    if case.codec == "png":
        return PreparedClip(folder / done["frames"], truth)
    return PreparedClip(folder / f"{done['clip_id']}.{case.codec}.mp4", truth)


def prepare_case(
    case: CaseSpec,
    plan: ValidationPlan,
    cache: Path,
    code: str,
    codecs: tuple[str, ...],
    remade: list[str] | None = None,
) -> Path:
    """Make the clip of ``case`` (and, for a synthetic scene, its encodings for every codec in
    ``codecs``) in ``cache`` unless it is there; returns its folder. An entry that is there but not
    whole (:func:`entry_problem`) is made again, and ``remade`` (when given) hears what was wrong."""
    from ..media import clip_fingerprint

    folder = cache / prepare_key(case, plan, code)
    problem = entry_problem(case, folder)
    if problem is not None and remade is not None:
        remade.append(problem)
    if problem is not None or not (folder / _DONE).is_file():
        tmp = folder.with_name(folder.name + ".part")
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir(parents=True)
        start = time.perf_counter()
        if case.kind == "synthetic":
            done = _render(case, plan, tmp)
        else:
            done = _plant(case, plan, tmp) if case.kind == "planted" else _cut(case, plan, tmp, folder)
        done["seconds"] = round(time.perf_counter() - start, 3)
        named = {"frames", *(done[k] for k in ("frames", "clip", "truth") if isinstance(done.get(k), str))}
        made = sorted(n for n in named if "/" not in n and (tmp / n).exists())  # the files it made, by name
        done[MADE_KEY] = {name: clip_fingerprint(tmp / name) for name in made}
        (tmp / _DONE).write_text(json.dumps(done, indent=1) + "\n")
        shutil.rmtree(folder, ignore_errors=True)
        tmp.rename(folder)
    if case.kind == "synthetic":
        _encode(folder, codecs, _FPS, remade)
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


def _plant(case: CaseSpec, plan: ValidationPlan, out: Path) -> dict:
    """Plant ``case``'s failure into the first ``plan.max_frames`` frames of its source clip (the
    planted clip and its ``.gt.json``; the clean twin :func:`~geocon_core.plant.plant_clip` writes
    beside it is dropped, the clean re-encode being an entry of its own), or write the clean
    re-encode. A clip that cannot be planted (no readable video, a folder of frames, too small for
    the severity) is recorded with the reason, so its cases fail with it instead of stopping the run."""
    from ..plant import plant_clip, plant_names, write_clean_clip

    src = Path(str(case.source))
    stem = src.stem if src.suffix else src.name
    try:
        if case.failure is None:
            name = f"{stem}.clean.mp4"
            summary = write_clean_clip(src, out / name, frames=plan.max_frames)
            return {"clip": name, "truth": None, "source": str(src), "encoding": summary}
        result = plant_clip(src, case.failure, str(case.level), plan.seed, out, frames=plan.max_frames)
    except ValueError as exc:  # ClipError included: the clip, not the machine
        return {"error": str(exc), "source": str(src)}
    names = plant_names(src, case.failure, str(case.level), plan.seed)
    for key in ("clean", "clean_meta"):
        (out / names[key]).unlink(missing_ok=True)
    return {"clip": result.planted.name, "truth": result.ground_truth.name, "source": str(src)}


def _encode(folder: Path, codecs: tuple[str, ...], fps: float, remade: list[str] | None = None) -> None:
    """Encode a rendered scene's PNG frames as H.264 at each CRF of ``codecs`` that is missing, or
    that was replaced since it was encoded (its fingerprint in ``done.json``; ``remade`` hears of it)."""
    from ..media import Mp4Writer, clip_fingerprint

    done = json.loads(read_text(folder / _DONE, SMALL_STATE))
    frames = sorted((folder / done["frames"]).glob("*.png"))
    made = done.setdefault(MADE_KEY, {})
    for codec in codecs:
        target = folder / f"{done['clip_id']}.{codec}.mp4"
        if codec not in CODEC_CRF:
            continue
        if target.is_file() and target.name in made and clip_fingerprint(target) != made[target.name]:
            if remade is not None:
                remade.append(f"{target} was replaced since it was made")
            target.unlink()
        if target.is_file():
            continue
        h, w = _imread(frames[0]).shape[:2]
        tmp = target.with_name(f".{target.name}.part")
        with Mp4Writer(tmp, w, h, fps, crf=CODEC_CRF[codec]) as writer:
            for f in frames:
                writer.write(np.ascontiguousarray(_imread(f)[..., ::-1]))
        tmp.replace(target)
        made[target.name] = clip_fingerprint(target)
        part = folder / f".{_DONE}.part"
        part.write_text(json.dumps(done, indent=1) + "\n")
        part.replace(folder / _DONE)


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
