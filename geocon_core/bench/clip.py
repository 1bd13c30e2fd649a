"""One clip of ``geocon bench``, as a worker scores it: the record and overlays into a folder,
the clip's ``status.json``, and the statuses of clips that failed outside scoring. Shared by both
executors (:mod:`geocon_core.bench`'s process pool and :mod:`geocon_core.bench.ray`)."""

from __future__ import annotations

import errno
import shutil
import time
import traceback
from pathlib import Path
from typing import Any, Callable

from ..config import ScoreConfig, config_hash
from ..record import ClipRecord
from ..scoring import is_flagged
from .dataset import ClipEntry
from .layout import RRD_NAME, STATUS_FORMAT, write_status

__all__ = [
    "MAX_CRASHES",
    "BenchError",
    "RecordRenderer",
    "crashed_status",
    "failed_status",
    "install_clip",
    "score_one",
    "score_to_folder",
]

MAX_CRASHES = 2
"""A clip in flight when a worker process dies this many times is recorded as failed."""
MACHINE_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EFBIG, errno.EMFILE, errno.ENFILE})
"""Errors of the machine, not of a clip (a full disk, a read-only folder, a file-size or open-files
limit): they stop the run instead of being recorded as the clip's failure, which a resumed run
would keep."""


class BenchError(ValueError):
    """A results folder that cannot be used for this run (one sentence): a path that cannot be a
    folder, another configuration, another run writing into it."""


def _flagged(record: ClipRecord, expected_model: str | None) -> bool:
    """Whether a scored clip gets an audit recording (:func:`geocon_core.scoring.verdict.is_flagged`)."""
    return is_flagged(
        consistent=record.background.consistent,
        pose_present=record.gate.pose_present,
        gate_model=record.gate.model,
        expected_model=expected_model,
        finding=record.model_verdict(),
    )


def score_to_folder(
    clip: Path,
    cfg: ScoreConfig,
    out_dir: Path,
    *,
    masks: Path | None = None,
    pose_log: Path | None = None,
    flow_checkpoint: Path | None = None,
    sam2_checkpoint: Path | None = None,
    dust3r_checkpoint: Path | None = None,
    dust3r_path: Path | None = None,
    progress: Callable[[int, int], None] | None = None,
    sinks: list[Callable[[Path], Any]] = (),  # type: ignore[assignment]
    dense: Any = None,
):
    """Score ``clip`` and write its record and overlays into ``out_dir``, all at once
    (:func:`~geocon_core.bench.staging.staged_record`: a failed or killed run leaves the previous record
    in ``out_dir`` as it was). ``dense``: a :class:`~geocon_core.reconstruction.dense.DenseCloudConfig` to
    add the dense point clouds to the record. ``sinks`` are factories called with the first frame's arrival and
    the staging folder; each made sink receives every frame, ``finish(record)`` once the record is
    in place, and ``abort()`` (where it has one) when scoring fails. A sink with a ``commit()``
    (a Rerun recording) is finished before the record is committed and committed with it, as one
    unit (:func:`~geocon_core.bench.staging.staged_record`)."""
    from ..record import OverlayWriter, record_id, write_record
    from ..scoring import score_clip
    from .staging import staged_record

    made: list = []

    def on_frame(fd) -> None:
        if not made:
            made.append(OverlayWriter(stage))
            made.extend(factory(stage) for factory in sinks)
        for sink in made:
            sink(fd)

    commits: list[Callable[[], object]] = []
    try:
        with staged_record(out_dir, then=commits) as stage:
            record = score_clip(
                clip,
                cfg,
                pose_log=pose_log,
                masks=masks,
                flow_checkpoint=flow_checkpoint,
                sam2_checkpoint=sam2_checkpoint,
                dust3r_checkpoint=dust3r_checkpoint,
                dust3r_path=dust3r_path,
                dense=dense,
                on_frame=on_frame,
                progress=progress,
            )
            made[0].close(record_id(record))  # the overlays name the record they belong to
            write_record(record, stage)
            for sink in made[1:]:  # complete every recording before the commit; renamed with the record
                if hasattr(sink, "commit"):
                    sink.finish(record, commit=False)
                    commits.append(sink.commit)
                else:
                    sink.finish(record)
    except BaseException:
        for sink in made[1:]:
            if hasattr(sink, "abort"):
                sink.abort()
        raise
    return record


RecordRenderer = Callable[[Path, Path], Any]
"""Renders a saved record: called as ``render(record_dir, output_path)``. Passed to worker
processes, so it must be picklable (a module-level function)."""


def score_one(
    entry: ClipEntry, cfg_dict: dict[str, Any], folder: str, renderer: RecordRenderer | None, threads: int
) -> dict[str, Any]:
    """Worker: score one clip into its folder and write its status (ok or failed)."""
    import cv2

    from .dataset import expected_model

    cv2.setNumThreads(threads)
    cfg = ScoreConfig.from_dict(cfg_dict)
    out = Path(folder)
    shutil.rmtree(out, ignore_errors=True)  # leftovers of a run killed while this clip was in flight
    out.mkdir(parents=True)
    start = time.perf_counter()
    status = _status(entry, cfg)
    try:
        record = score_to_folder(entry.video, cfg, out, masks=entry.masks)
        status["warnings"] = list(record.warnings)
        if renderer is not None and _flagged(record, expected_model(entry.category)):
            renderer(out, out / RRD_NAME)
            status["rrd"] = RRD_NAME
    except OSError as exc:
        if exc.errno in MACHINE_ERRNOS:
            shutil.rmtree(out, ignore_errors=True)  # nothing of this clip is left: a resumed run scores it
            raise
        status.update(status="failed", error=f"{type(exc).__name__}: {exc}", traceback=traceback.format_exc(limit=8))
    except Exception as exc:  # every failure is recorded with its reason, never dropped
        status.update(status="failed", error=f"{type(exc).__name__}: {exc}", traceback=traceback.format_exc(limit=8))
    status["seconds"] = round(time.perf_counter() - start, 3)
    write_status(out, status)
    return status


def _status(entry: ClipEntry, cfg: ScoreConfig, error: str | None = None) -> dict[str, Any]:
    """A clip's ``status.json`` before scoring (``ok``), or of a clip that failed with ``error``;
    ``fingerprint`` tells a resumed run whether the clip file is still the one scored
    (:func:`geocon_core.media.clip_fingerprint`)."""
    from ..media import clip_fingerprint

    return {
        "format": STATUS_FORMAT,
        "clip_id": entry.clip_id,
        "status": "ok" if error is None else "failed",
        "error": error,
        "traceback": None,
        "config_hash": config_hash(cfg),
        "meta": entry.meta,
        "video": str(entry.video),
        "fingerprint": clip_fingerprint(entry.video),
        "rrd": None,
        "warnings": [],
    }


def failed_status(entry: ClipEntry, cfg: ScoreConfig, error: str) -> dict[str, Any]:
    """The status of a clip that failed outside scoring (its worker died, its node cannot read it)."""
    return {**_status(entry, cfg, error), "seconds": None}


def crashed_status(entry: ClipEntry, cfg: ScoreConfig) -> dict[str, Any]:
    """The status of a clip whose worker died :data:`MAX_CRASHES` times."""
    return failed_status(
        entry,
        cfg,
        f"the worker process died {MAX_CRASHES} times while scoring this clip "
        "(out of memory or a crash in a native library)",
    )


def install_clip(folder: Path, status: dict[str, Any], files: dict[str, bytes] | None = None) -> None:
    """Write a clip's ``files`` (relative path -> bytes) into its results folder and its status
    last (the mark of a finished clip), replacing whatever a run killed while this clip was in
    flight left there."""
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True)
    root = folder.resolve()
    for rel, data in (files or {}).items():
        path = folder / rel
        if root not in path.resolve().parents:
            raise ValueError(f"a clip's file lies outside its clip folder: {rel}")
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(data)
    write_status(folder, status)
