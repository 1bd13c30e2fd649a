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

Nothing in the folder that is not an earlier planting of the same source is replaced: a file of
one of these names that a user put there, or the clean twin of another source with the same stem
(or of the same source cut to other frames), is refused before any frame is encoded. Everything
is written beside its place, every target checked, and the five files are committed together
(:func:`geocon_core.files.commit_together`): a run that fails or is stopped, even midway through
the renames, leaves the folder as it was.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import Any, Callable, Iterator, Mapping

import numpy as np

from ..files import (
    GROUND_TRUTH,
    ReadRefused,
    check_apart,
    check_out_dir,
    check_targets,
    claim,
    commit_together,
    held,
    parents_made,
    part_path,
    read_text,
    replace_file,
)
from .encode import MATCH_FRAMES, decode_planes, file_sha256, match_quality, plane_writer, probe_source
from .fields import Planting, plan_planting
from .kinds import amplitude_of

__all__ = [
    "PLANT_FORMAT",
    "PlantTargetError",
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
    folder that cannot be used, an output that would be the clip or a file in it that is not this
    planting's own (:class:`PlantTargetError`); :class:`~geocon_core.media.ClipError`
    for a clip that is no readable video; ValueError when the clip is too small for the level."""
    clip, out_dir = Path(clip), Path(out_dir)
    amplitude_of(kind, level)
    if seed < 0:
        raise ValueError(f"the seed must be 0 or more, got {seed}")
    names = plant_names(clip, kind, level, seed)
    check_out_dir(out_dir, "--out")
    claim("--out", out_dir, "folder")
    targets = {key: out_dir / name for key, name in names.items()}
    check_apart([("--out", path) for path in targets.values()], [("clip", clip)])
    check_targets([(path, False) for path in targets.values()])

    source = probe_source(clip, frames)
    twins = _check_plant_targets(out_dir, targets, source.sha256, source.frames)
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
            stale = [p for p, sha in twins if sha != truth["clean"]["sha256"]]
            if stale:
                raise PlantTargetError(
                    f"{targets['clean']}: the clean twin this run encodes differs from the one {stale[0].name} names "
                    "(made by another version of GeoCon or FFmpeg?), which it would leave pointing at bytes that are "
                    "gone; plant into another --out"
                )
            _write_json(parts["truth"], truth)
            _write_json(parts["planted_meta"], _sidecar(truth, planted=True))
            _write_json(parts["clean_meta"], _sidecar(truth, planted=False))
            commit_together([(part, targets[key]) for key, part in parts.items()])  # all five, or none
        finally:
            for part in parts.values():
                part.unlink(missing_ok=True)
    warnings = () if source.retiming is None else (source.retiming,)
    return PlantResult(truth, targets["planted"], targets["clean"], targets["truth"], planting, warnings)


class PlantTargetError(ValueError):
    """A file in ``--out`` that a planting would replace and that is not its own (one sentence)."""


def _check_plant_targets(out_dir: Path, targets: Mapping[str, Path], sha: str, frames: int) -> list[tuple[Path, str]]:
    """Refuse (:class:`PlantTargetError`, before any frame is encoded) to write a planting of the
    source of SHA-256 ``sha`` (its first ``frames`` frames) where a file is not its own earlier
    output: the case's files (planted clip, ground truth, sidecar) must be absent or an earlier
    planting of the same source (its ground truth says so); the clean twin ``<stem>.clean.mp4``
    and its sidecar must be absent or the twin the ground truths in ``out_dir`` name (the same
    bytes), each of them made from the same source and the same frames (another source with the
    same stem, or the same source cut to other frames, would leave their ground truths naming a
    SHA-256 the twin no longer has). Returns the other ground truths that name the twin, with the
    SHA-256 each names (the new twin must be those bytes)."""
    own = _check_case(targets, sha)
    twins = _check_twin(out_dir, targets, sha, frames)
    named = {digest for _, digest in twins}
    if own is not None:
        named.add(str(_part(own, "clean").get("sha256")))
    for key in ("clean", "clean_meta"):
        if os.path.lexists(targets[key]) and (not named or (key == "clean" and file_sha256(targets[key]) not in named)):
            raise PlantTargetError(
                f"{targets[key]} exists and is {held(targets[key]).describe()}, not the clean twin an earlier planting "
                "of this clip made (no ground truth in the folder names its bytes); move it away or choose another "
                "--out"
            )
    return twins


def _part(truth: Mapping[str, Any], key: str) -> Mapping[str, Any]:
    """The ``key`` entry of a ground truth (``source``, ``planted``, ``clean``), empty when it is none."""
    value = truth.get(key)
    return value if isinstance(value, dict) else {}


def _other_source(path: Path, truth: Mapping[str, Any], sha: str, what: str) -> PlantTargetError:
    source = _part(truth, "source")
    return PlantTargetError(
        f"{path} is {what} of another clip named {source.get('name')} (its source's SHA-256 is "
        f"{str(source.get('sha256'))[:12]}..., this clip's {sha[:12]}...); plant each source into a folder of its own, "
        "or rename one"
    )


def _check_case(targets: Mapping[str, Path], sha: str) -> dict[str, Any] | None:
    """The case's own earlier ground truth (None when there is none), once it and the case's
    planted clip and sidecar are known to be an earlier planting of the same source."""
    own = held(targets["truth"])
    was = own.data if _is_truth(own) else None
    if own.kind != "nothing" and was is None:
        raise PlantTargetError(
            f"{targets['truth']} exists and is {own.describe()}, not the ground truth of an earlier planting; move it "
            "away or choose another --out"
        )
    if was is not None and _part(was, "source").get("sha256") != sha:
        raise _other_source(targets["truth"], was, sha, "the ground truth of a planting")
    for key in ("planted", "planted_meta"):
        if not os.path.lexists(targets[key]):
            continue
        if was is None or (key == "planted" and file_sha256(targets[key]) != _part(was, "planted").get("sha256")):
            raise PlantTargetError(
                f"{targets[key]} exists and is {held(targets[key]).describe()}, not part of an earlier planting (the "
                f"ground truth {targets['truth'].name} does not name it); move it away or choose another --out"
            )
    return was


def _check_twin(out_dir: Path, targets: Mapping[str, Path], sha: str, frames: int) -> list[tuple[Path, str]]:
    """The other ground truths in ``out_dir`` that name the clean twin, with the SHA-256 each
    names, once each is known to be of the same source and the same frames."""
    clean = targets["clean"]
    twins: list[tuple[Path, str]] = []
    for path in sorted(out_dir.glob("*.gt.json")) if out_dir.is_dir() else []:
        other = held(path)
        data = other.data if _is_truth(other) else None
        if data is None or _part(data, "clean").get("video") != clean.name:
            continue
        if _part(data, "source").get("sha256") != sha:
            raise _other_source(clean, data, sha, f"the clean twin (its ground truth {path.name} says so)")
        used = _part(data, "source").get("frames_used")
        if path != targets["truth"] and used != frames:
            raise PlantTargetError(
                f"{clean} is the clean twin of the first {used} frames of this clip, which {path.name} names, and this "
                f"run uses {frames}; plant with --frames {used}, or into another --out"
            )
        if path != targets["truth"]:
            twins.append((path, str(_part(data, "clean").get("sha256"))))
    return twins


def _is_truth(there: Any) -> bool:
    return there.kind == "json" and (there.format or "").split("/")[0] == PLANT_FORMAT.split("/")[0]


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
        data = json.loads(read_text(path, GROUND_TRUTH))  # a regular file within its bound
    except ReadRefused as exc:
        raise ValueError(f"{path}: cannot be read as a planted clip's ground truth ({exc.why})") from None
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
