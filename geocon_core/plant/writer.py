"""``geocon plant``: a failure planted into a real clip, written with its clean twin and its ground truth.

For ``CLIP`` = ``<stem>.<ext>``, ``FAILURE`` = ``<kind>-<level>-s<seed>``, the folder gets:

- ``<stem>.<FAILURE>.mp4``: the planted clip;
- ``<stem>.<FAILURE>.gt.json``: its ground truth (:func:`read_plant_truth`; the exact displacement
  of any frame: :func:`planted_displacement`);
- ``<stem>.clean.mp4``: the clean clip, the same frames encoded the same way (only the planted
  damage differs; every planting of one clip into one folder writes the same bytes here);
- ``<stem>.<FAILURE>.meta.json`` and ``<stem>.clean.meta.json``: sidecars for ``geocon bench`` (the
  platforms ``geocon-plant/<kind>`` and ``geocon-plant/clean``, one ``scene_id``, the source's stem,
  so a report pairs each planted clip with its clean twin).

Everything is written beside its place and renamed into it at the end: a run that fails or is
stopped leaves the folder as it was.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import Any, Callable, Iterator, Mapping

import numpy as np

from ..files import check_apart, check_out_dir, deferred_signals, parents_made, part_path, replace_file
from .encode import MATCH_FRAMES, decode_planes, file_sha256, match_quality, plane_writer, probe_source
from .fields import Planting, plan_planting
from .kinds import amplitude_of

__all__ = [
    "PLANT_FORMAT",
    "PlantResult",
    "plant_clip",
    "plant_names",
    "planted_displacement",
    "read_plant_truth",
    "write_clean_clip",
]

PLANT_FORMAT = "geocon-plant-gt/1"
"""The ``format`` of a planted clip's ``.gt.json``."""


@dataclass(frozen=True)
class PlantResult:
    """What :func:`plant_clip` wrote: the ground truth (the ``.gt.json`` as a dict), the paths of the
    planted clip, the clean clip and the ground truth, the :class:`~.fields.Planting`, and the
    ``warnings`` a user should read (one sentence each: the frames re-timed to a constant rate)."""

    truth: dict[str, Any]
    planted: Path
    clean: Path
    ground_truth: Path
    planting: Planting
    warnings: tuple[str, ...] = ()


def plant_names(clip: Path, kind: str, level: str, seed: int) -> dict[str, str]:
    """The names :func:`plant_clip` writes for ``clip``: ``planted``, ``truth``, ``planted_meta``,
    ``clean`` and ``clean_meta``."""
    stem = clip.stem if clip.suffix else clip.name
    case = f"{stem}.{kind}-{level}-s{seed}"
    return {
        "planted": f"{case}.mp4",
        "truth": f"{case}.gt.json",
        "planted_meta": f"{case}.meta.json",
        "clean": f"{stem}.clean.mp4",
        "clean_meta": f"{stem}.clean.meta.json",
    }


def plant_clip(
    clip: str | Path,
    kind: str,
    level: str,
    seed: int,
    out_dir: str | Path,
    *,
    frames: int | None = None,
    on_frame: Callable[[int], object] | None = None,
) -> PlantResult:
    """Plant failure ``kind`` (:data:`~.kinds.PLANT_KINDS`) at severity ``level`` (low, middle,
    high), drawn from ``seed``, into the first ``frames`` frames of ``clip`` (all when None), and
    write the planted clip, the clean clip and the ground truth into ``out_dir`` (:mod:`.writer`).
    ``on_frame(t)`` is called after each frame is written.

    Raises ValueError (one sentence) for an unknown kind or level, a negative seed, an output
    folder that cannot be used or an output that would be the clip; :class:`~geocon_core.media.ClipError`
    for a clip that is no readable video; ValueError when the clip is too small for the level."""
    clip, out_dir = Path(clip), Path(out_dir)
    amplitude_of(kind, level)
    if seed < 0:
        raise ValueError(f"the seed must be 0 or more, got {seed}")
    names = plant_names(clip, kind, level, seed)
    check_out_dir(out_dir, "--out")
    targets = {key: out_dir / name for key, name in names.items()}
    check_apart([("--out", path) for path in targets.values()], [("clip", clip)])

    source = probe_source(clip, frames)
    sample: list[list[np.ndarray]] = []

    def lumas() -> Iterator[np.ndarray]:
        for planes in decode_planes(clip, source.work_format, source.frames):
            if len(sample) < MATCH_FRAMES:
                sample.append(planes)
            yield planes[0]

    planting = plan_planting(kind, level, seed, lumas())
    quality, _ = match_quality(source, sample)
    sample.clear()

    parts = {key: part_path(path) for key, path in targets.items()}
    with parents_made(out_dir):
        try:
            args = (source.encoder, quality, source.work_format, source.width, source.height, source.rate)
            with plane_writer(parts["clean"], *args) as clean, plane_writer(parts["planted"], *args) as planted:
                for t, planes in enumerate(decode_planes(clip, source.work_format, source.frames)):
                    clean.write_planes(planes)
                    planted.write_planes(planting.apply(t, planes, source.subsampling))
                    if on_frame is not None:
                        on_frame(t)
            pixels = source.width * source.height * source.frames
            truth = _truth(
                source, planting, names, quality, parts, 8.0 * clean.bytes / pixels, 8.0 * planted.bytes / pixels
            )
            _write_json(parts["truth"], truth)
            _write_json(parts["planted_meta"], _sidecar(truth, planted=True))
            _write_json(parts["clean_meta"], _sidecar(truth, planted=False))
            with deferred_signals():
                for key, part in parts.items():
                    replace_file(part, targets[key])
        finally:
            for part in parts.values():
                part.unlink(missing_ok=True)
    warnings = () if source.retiming is None else (source.retiming,)
    return PlantResult(truth, targets["planted"], targets["clean"], targets["truth"], planting, warnings)


def write_clean_clip(clip: str | Path, target: str | Path, *, frames: int | None = None) -> dict[str, Any]:
    """Write only the clean clip of :func:`plant_clip` to ``target`` (an ``.mp4`` path): the first
    ``frames`` frames of ``clip`` (all when None) decoded and encoded exactly as :func:`plant_clip`
    encodes its clean twin (the same codec, quantiser match and options), so its bytes equal the
    ``<stem>.clean.mp4`` of any planting of the same clip and frames. Written beside ``target`` and
    renamed into place. Returns what the ground truth's ``source``, ``clean`` and ``encoding``
    entries say of it: ``source_sha256``, ``frames``, ``size`` (w, h), ``codec``, ``encoder``,
    ``quality`` and ``sha256`` and ``bits_per_pixel`` of the clean clip.

    Raises :class:`~geocon_core.media.ClipError` for a clip that is no readable video (a folder of
    frames included)."""
    clip, target = Path(clip), Path(target)
    source = probe_source(clip, frames)
    sample: list[list[np.ndarray]] = []
    for planes in decode_planes(clip, source.work_format, min(source.frames, MATCH_FRAMES)):
        sample.append(planes)
    quality, _ = match_quality(source, sample)
    sample.clear()
    part = part_path(target)
    try:
        args = (source.encoder, quality, source.work_format, source.width, source.height, source.rate)
        with plane_writer(part, *args) as clean:
            for planes in decode_planes(clip, source.work_format, source.frames):
                clean.write_planes(planes)
        summary = {
            "source_sha256": source.sha256,
            "frames": source.frames,
            "size": [source.width, source.height],
            "codec": source.encoder.codec,
            "encoder": source.encoder.library,
            "quality": {"option": source.encoder.quality_option, "value": quality},
            "sha256": file_sha256(part),
            "bits_per_pixel": round(8.0 * clean.bytes / (source.width * source.height * source.frames), 6),
        }
        replace_file(part, target)
    finally:
        part.unlink(missing_ok=True)
    return summary


def _write_json(path: Path, data: Mapping[str, Any]) -> None:
    with open(path, "w", encoding="utf-8") as f:
        f.write(json.dumps(data, indent=1) + "\n")
        f.flush()
        os.fsync(f.fileno())


def _truth(
    source: Any,
    planting: Planting,
    names: Mapping[str, str],
    quality: int,
    parts: Mapping[str, Path],
    clean_bpp: float,
    planted_bpp: float,
) -> dict[str, Any]:
    encoder = source.encoder
    same = encoder.codec == source.codec
    option = encoder.quality_option
    match = (
        f"{option} {quality}: the constant quantiser whose encode of the first {min(source.frames, MATCH_FRAMES)} "
        f"clean frames spends the bits per pixel closest to the source's over them ({source.bits_per_pixel:.4f})"
    )
    return {
        "format": PLANT_FORMAT,
        "clip_id": Path(names["planted"]).stem,
        "scene_id": Path(names["clean"]).stem.removesuffix(".clean"),
        **planting.to_dict(),
        "source": {
            "name": source.name,
            "sha256": source.sha256,
            "codec": source.codec,
            "pix_fmt": source.pix_fmt,
            "size": [source.width, source.height],
            "rate": str(source.rate),
            "frames_used": source.frames,
            "bits_per_pixel": round(source.bits_per_pixel, 6),
            "display_rotation": _rotation_entry(source),
            "timing": source.timing_entry(),
        },
        "planted": {
            "video": names["planted"],
            "sha256": file_sha256(parts["planted"]),
            "bits_per_pixel": round(planted_bpp, 6),
        },
        "clean": {
            "video": names["clean"],
            "sha256": file_sha256(parts["clean"]),
            "bits_per_pixel": round(clean_bpp, 6),
        },
        "encoding": {
            "container": "mp4",
            "codec": encoder.codec,
            "encoder": encoder.library,
            "same_family_as_source": same,
            "quality": {"option": option, "value": quality},
            "options": dict(encoder.options),
            "threads": 1,
            "pix_fmt": source.work_format,
            "rate": str(source.rate),
            "quality_match": match,
            "both": "the planted and the clean clip: the same decoded frames, encoder, quantiser, options, pixel "
            "format, rate",
        },
    }


def _rotation_entry(source: Any) -> dict[str, Any]:
    """What the ground truth's ``source.display_rotation`` says: the counter-clockwise turn (degrees)
    the source's display matrix gives its stored frames, their stored size, and that both clips
    hold the frames upright (``size``) with no display matrix."""
    return {
        "degrees": source.rotation,
        "stored_size": list(source.stored_size),
        "written": "upright, no display matrix" if source.rotation else "as stored (the source has no turn)",
    }


def _sidecar(truth: Mapping[str, Any], *, planted: bool) -> dict[str, Any]:
    """The ``geocon bench`` sidecar of the planted or the clean clip."""
    from ..bench import sanitise_clip_id

    width, height = truth["source"]["size"]
    fps = float(Fraction(truth["source"]["rate"]))
    frames = truth["source"]["frames_used"]
    video = truth["planted"]["video"] if planted else truth["clean"]["video"]
    meta: dict[str, Any] = {
        "clip_id": sanitise_clip_id(Path(video).stem),
        "prompt": None,
        "model": f"geocon-plant/{truth['kind']}" if planted else "geocon-plant/clean",
        "model_version": None,
        "seed": truth["seed"] if planted else None,
        "resolution": [width, height],
        "fps": fps,
        "duration": frames / fps,
        "masks_path": None,
        "category": None,
        "scene_id": truth["scene_id"],
        "video": video,
    }
    if planted:
        meta["ground_truth"] = Path(video).stem + ".gt.json"
        meta["severity"] = truth["severity"]
    return meta


def read_plant_truth(path: str | Path) -> dict[str, Any]:
    """The ground truth of a planted clip (its ``.gt.json``). Raises ValueError when the file is not one."""
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path}: cannot be read as a planted clip's ground truth ({exc})") from None
    if not isinstance(data, dict) or data.get("format") != PLANT_FORMAT:
        raise ValueError(f"{path}: not a planted clip's ground truth (format {PLANT_FORMAT!r} expected)")
    return data


def planted_displacement(truth: Mapping[str, Any] | str | Path, t: int) -> np.ndarray:
    """The exact displacement of frame ``t`` of a planted clip, (h, w, 2) px (``(dx, dy)``; the
    convention of :mod:`.fields`: the flow from the clean frame ``t`` to the planted one), from its
    ground truth (a ``.gt.json`` path or its dict). Zero everywhere for ``redraw``."""
    data = read_plant_truth(truth) if isinstance(truth, (str, Path)) else truth
    return Planting.from_dict(data).displacement(t)
