"""``geocon bench``: score every clip of a dataset in worker processes, resumably, into a
results folder laid out as :mod:`geocon_core.bench.layout` describes.

A clip is finished when its ``status.json`` exists; a restarted run skips finished clips, so a
killed run loses at most the clips that were in flight and never scores a clip twice. A clip that
fails (unreadable, a crash in scoring, a worker process that dies) is recorded as failed with its
reason and counted, never dropped; ``retry_failed`` scores failed clips again. A finished clip
whose metadata changed since (a category set, a prompt fixed in its sidecar) takes the new
metadata without being scored again, as long as its clip file and masks are the same. A finished
clip whose file was replaced since (same name, other bytes: its fingerprint changed), or whose
status or record was damaged since, is scored again, and said so. The tables hold the dataset's
clips only (a folder of a clip it no longer has is left out, with a note). A full disk or a
read-only folder stops the run instead of failing the clips in flight, and Ctrl-C leaves nothing
of those clips behind.
"""

from __future__ import annotations

import multiprocessing
import os
import socket
import time
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from contextlib import suppress
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Iterable

from ..config import ScoreConfig, config_hash
from ..files import (
    FolderLock,
    LockHeld,
    NotALockFile,
    check_lock_path,
    check_out_dir,
    clear_stale_parts,
    die_with_parent,
    quiet_resource_tracker,
    quiet_tracker_restarts,
)
from ..media import clip_fingerprint
from ..signals import ClipModelError, configured_model
from .clip import (
    MAX_CRASHES,
    BenchError,
    RecordRenderer,
    crashed_status,
    install_clip,
    score_one,
    score_to_folder,
)
from .dataset import MANIFEST_NAMES, ClipEntry, scan_dataset
from .layout import (
    BENCH_FORMAT,
    CLIPS_DIR,
    STATUS_NAME,
    check_output_kind,
    checked_manifest,
    clip_dir,
    clip_folders,
    lock_path,
    manifest_path,
    read_status,
    write_manifest,
    write_status,
)
from .tables import write_tables

if TYPE_CHECKING:
    from .ray import RayOptions

__all__ = [
    "EXECUTORS",
    "BenchError",
    "BenchSummary",
    "RecordRenderer",
    "run_bench",
    "score_to_folder",
]

EXECUTORS = ("pool", "ray")
"""How ``geocon bench`` runs clips: a local process pool, or Ray tasks (one machine or a cluster)."""


@dataclass(frozen=True)
class BenchSummary:
    """What a run did: clips in the dataset, scored now, skipped (finished earlier), failed (in
    total, including earlier runs), and the seconds it took."""

    results: Path
    total: int
    scored: int
    skipped: int
    failed: int
    seconds: float
    tables: tuple[Path, ...] = field(default_factory=tuple)


def _same_dataset(scored: object, dataset: Path, found: Path) -> bool:
    """Whether ``scored`` (the dataset a results folder's ``bench.json`` names) is the dataset given
    now as ``dataset`` (read from ``found``: the folder, or the manifest in it or given), by
    resolved path: a folder and the ``manifest.csv`` in it are one dataset."""
    if not isinstance(scored, str):
        return True  # results that do not say which dataset they hold
    same = {dataset.resolve(), found.resolve()}
    if found.is_file() and found.name in MANIFEST_NAMES:
        same.add(found.resolve().parent)
    return Path(scored) in same


def _prepare_results(
    results: Path,
    dataset: Path,
    cfg: ScoreConfig,
    found: Path | None = None,
    note: Callable[[str], None] = lambda _msg: None,
) -> None:
    """Start the results folder (its ``bench.json``), or check that the one there was scored with
    ``cfg``, so that this run resumes it. Results of another dataset path (one that moved, was
    copied, or another dataset: ``found`` is where ``dataset`` was read from) name this one from now
    on, and ``note`` says so: a clip is resumed only where its id and file are the same, and the
    tables hold this dataset's clips only."""
    from ..scoring import software_versions

    manifest = manifest_path(results)
    digest = config_hash(cfg)
    if manifest.exists():  # a FIFO or a device in its place is refused by checked_manifest
        try:
            old = checked_manifest(results)
        except ValueError as exc:
            raise BenchError(f"{exc}; choose another --out") from None
        if old.get("config_hash") == digest and not _same_dataset(old.get("dataset"), dataset, found or dataset):
            note(
                f"{results} held the results of the dataset {old['dataset']}; it holds those of {dataset} from now on "
                "(a clip is kept where its id and its file's bytes are the same, the others are scored)"
            )
            write_manifest(results, {**old, "dataset": str(dataset.resolve())})
        if old.get("config_hash") != digest and _other_model_only(old.get("config"), cfg):
            pinned = old["config"]["signals"].get("model_sha256")
            note(
                f"{results} was scored with the clip model {pinned}, and this run's is {cfg.signals.model_sha256} (an "
                "earlier release's model, or one fitted anew): the clips made with it are scored again, and the "
                "results hold this model's from now on"
            )
            write_manifest(results, {**old, "config": cfg.to_dict(), "config_hash": digest})
            return
        if old.get("config_hash") != digest:
            raise BenchError(_another_configuration(results, old))
        return
    results.mkdir(parents=True, exist_ok=True)
    (results / CLIPS_DIR).mkdir(exist_ok=True)
    write_manifest(
        results,
        {
            "format": BENCH_FORMAT,
            "dataset": str(dataset.resolve()),
            "config": cfg.to_dict(),
            "config_hash": digest,
            "versions": software_versions(),
        },
    )


def _other_model_only(before: object, cfg: ScoreConfig) -> bool:
    """Whether the configuration ``before`` (a ``bench.json``'s, as written) differs from ``cfg``
    in the clip model alone (``signals.model`` and ``signals.model_sha256``), with the clip model on
    in both: results of an earlier release, or of a model fitted anew, that this run resumes."""
    import json

    def without_model(d: Any) -> Any:
        d = json.loads(json.dumps(d))  # compared as written: a setting one of them lacks is a difference
        if isinstance(d, dict) and isinstance(d.get("signals"), dict):
            d["signals"] = {k: v for k, v in d["signals"].items() if k not in ("model", "model_sha256")}
        return d

    now = cfg.to_dict()
    on = isinstance(before, dict) and isinstance(before.get("signals"), dict) and before["signals"].get("enabled")
    return bool(on) and cfg.signals.enabled and without_model(before) == without_model(now)


def run_bench(
    dataset: str | Path,
    results: str | Path,
    config: ScoreConfig | None = None,
    *,
    workers: int = 1,
    rrd_renderer: RecordRenderer | None = None,
    retry_failed: bool = False,
    on_clip: Callable[[dict[str, Any], int, int, int], None] | None = None,
    on_start: Callable[[int, int], None] | None = None,
    tables: bool = True,
    executor: str = "pool",
    ray: "RayOptions | None" = None,
    on_note: Callable[[str], None] | None = None,
    roots: Iterable[str | Path] = (),
) -> BenchSummary:
    """Score every clip of ``dataset`` (a folder or a manifest file, read by
    :func:`~geocon_core.bench.dataset.scan_dataset`) into ``results`` with ``workers`` processes
    (``executor="pool"``), or as Ray tasks (``executor="ray"``, :mod:`geocon_core.bench.ray`;
    ``ray`` says where, and a local instance gets ``workers`` CPUs). Both leave the same results
    folder, so a run started with one can be resumed with the other.

    ``rrd_renderer`` (a module-level function, called as ``f(record_dir, rrd_path)``) writes a Rerun
    recording for flagged clips (:func:`geocon_core.scoring.verdict.is_flagged`). ``on_start(to_score, skipped)``
    is called once; ``on_clip(status, done, total, failed)`` after each clip. Raises
    :class:`~geocon_core.bench.dataset.DatasetError` or :class:`BenchError` before scoring anything:
    ``results`` is checked (:func:`geocon_core.files.paths.check_out_dir`; not a record folder,
    :func:`~geocon_core.bench.layout.check_output_kind`) before the dataset is read, and
    held with a lock file (:func:`geocon_core.bench.layout.lock_path`) for the whole run, so a second run
    into the same folder is refused naming the first one's PID (a lock of a dead run is taken over).
    The worker processes exit when this process dies (:func:`geocon_core.files.procs.die_with_parent`).
    ``on_note(sentence)`` hears the defaults the dataset took (a plain folder, a manifest) and what
    the executor has to say (where it runs, a clip scored again). ``roots``: folders besides the
    dataset's own that its clip and masks paths may lie in (:func:`~geocon_core.bench.dataset.scan_dataset`)."""
    cfg = config or ScoreConfig()
    if workers < 1:
        raise BenchError(f"--workers must be at least 1, got {workers}")
    if executor not in EXECUTORS:
        raise BenchError(f"--executor must be one of {', '.join(EXECUTORS)}, got {executor!r}")
    note = on_note or (lambda _msg: None)
    data, out = Path(dataset), Path(results)
    try:
        configured_model(cfg.signals)  # the clip model that decides the verdicts, before anything is read
    except ClipModelError as exc:
        raise BenchError(str(exc)) from None
    _check_out(out, cfg)
    dataset_read = scan_dataset(data, roots=roots)
    entries = list(dataset_read.entries)
    for sentence in dataset_read.notes:
        note(sentence)
    if executor == "ray":
        from .ray import RayOptions, preflight

        ray = ray or RayOptions(local_cpus=workers)
        preflight(ray)  # Ray installed, the cluster answers: refused before the results folder is made
    created = not out.exists()
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise BenchError(f"--out {out} cannot be created ({exc.strerror})") from None
    lock = FolderLock(lock_path(out))
    try:
        lock.acquire()
    except LockHeld as held:
        raise BenchError(_busy(out, held)) from None
    except NotALockFile as exc:
        _remove_if_empty(out, created)
        raise BenchError(str(exc)) from None
    except BaseException:
        _remove_if_empty(out, created)
        raise
    try:
        _prepare_results(out, data, cfg, dataset_read.root, note)
        start = time.perf_counter()
        todo, failed_before = _unfinished(entries, out, retry_failed, note, cfg)
        skipped = len(entries) - len(todo)
        if on_start is not None:
            on_start(len(todo), skipped)
        done, failed = skipped, failed_before

        def finished(status: dict[str, Any]) -> None:
            nonlocal done, failed
            done += 1
            failed += status["status"] == "failed"
            if on_clip is not None:
                on_clip(status, done, len(entries), failed)

        if executor == "ray" and todo:
            from .ray import score_all_ray

            assert ray is not None
            score_all_ray(todo, out, cfg, rrd_renderer, finished, ray, note)
        else:
            _score_all(todo, out, cfg, workers, rrd_renderer, finished, note)
        paths: tuple[Path, ...] = ()
        if tables:
            paths = _write_tables(out, entries, note)
    finally:
        lock.release()
        _remove_if_empty(out, created)
    return BenchSummary(
        results=out,
        total=len(entries),
        scored=len(todo),
        skipped=skipped,
        failed=failed,
        seconds=time.perf_counter() - start,
        tables=paths,
    )


def _write_tables(out: Path, entries: list[ClipEntry], note: Callable[[str], None]) -> tuple[Path, ...]:
    """The tables of the dataset's clips (:func:`~geocon_core.bench.tables.write_tables`); clip
    folders of clips the dataset no longer has (removed, or renamed: their id changed) are left
    out, and ``note`` says so. A record that cannot be read is one sentence (:class:`BenchError`)."""
    from ..record import RecordError

    ids = {e.clip_id for e in entries}
    gone = [f.name for f in clip_folders(out) if f.name not in ids and read_status(f) is not None]
    if gone:
        note(
            f"{len(gone)} clip folder(s) in {out / CLIPS_DIR} hold clips the dataset no longer has (removed or renamed "
            f"since they were scored: {_named(gone)}); they are left out of the tables, and their folders are kept"
        )
    try:
        return write_tables(out, clip_ids=ids)
    except RecordError as exc:
        said = str(exc).removesuffix(": score the clip again")
        raise BenchError(
            f"the tables cannot be written: {said}; remove that clip's folder and run the same command again, which "
            "scores it anew"
        ) from None


def _check_out(out: Path, cfg: ScoreConfig) -> None:
    """Refuse, before the dataset is read, a results folder that cannot be one
    (:func:`~geocon_core.files.paths.check_out_dir`), is a record folder or lies in one, or holds
    a ``bench.json`` that is damaged, of another format or of another configuration than ``cfg``
    (other than its clip model: :func:`_other_model_only`) (:class:`BenchError`)."""
    try:
        check_out_dir(out)
        check_output_kind(out, "results")
        check_lock_path(lock_path(out))
    except ValueError as exc:
        raise BenchError(str(exc)) from None
    if manifest_path(out).exists():
        try:
            old = checked_manifest(out)
        except ValueError as exc:
            raise BenchError(f"{exc}; choose another --out") from None
        if old.get("config_hash") != config_hash(cfg) and not _other_model_only(old.get("config"), cfg):
            raise BenchError(_another_configuration(out, old))


def _another_configuration(results: Path, old: dict[str, Any]) -> str:
    """The sentence for results scored with another configuration."""
    return (
        f"{results} was scored with another configuration (hash {old.get('config_hash')}, preset "
        f"{old.get('config', {}).get('preset')}); rerun with the same settings to resume, or choose another --out"
    )


def _remove_if_empty(out: Path, created: bool) -> None:
    """Remove the results folder this run ``created`` when it stopped before writing anything in
    it (a full disk at its first file): an empty ``clips/`` and the folder itself."""
    if not created or manifest_path(out).exists():
        return
    for folder in (out / CLIPS_DIR, out):
        with suppress(OSError):
            folder.rmdir()  # only when empty


def _busy(out: Path, held: LockHeld) -> str:
    """The sentence for a results folder that another run holds."""
    who = "another process" if held.pid is None else f"PID {held.pid}"
    if held.host is not None and held.host != socket.gethostname():
        who += f" on {held.host}"
    return f"--out {out} is in use by another `geocon bench` run ({who}); wait for it to finish or choose another --out"


def _unfinished(
    entries: list[ClipEntry], out: Path, retry_failed: bool, note: Callable[[str], None], cfg: ScoreConfig
) -> tuple[list[ClipEntry], int]:
    """The clips still to score (unfinished, failed when ``retry_failed``, finished on a clip file
    that was replaced since: its fingerprint changed, or made with another clip model than
    ``cfg``'s: :func:`_other_model`) and how many failed clips are kept as they are. A finished
    clip whose metadata changed takes the dataset's (its ``status.json`` rewritten) when its clip
    file and ``masks_path`` are those it was scored from; otherwise it keeps its earlier metadata
    and scores, and ``note`` says so."""
    todo, failed_before = [], 0
    refreshed, stale, replaced, damaged = 0, [], [], []
    other_model: dict[str, list[str]] = {}  # digest -> the clips made with it
    for entry in entries:
        folder = clip_dir(out, entry.clip_id)
        status = read_status(folder)
        if status is None and (folder / STATUS_NAME).exists():
            damaged.append(entry.clip_id)
        if status is None or (retry_failed and status["status"] == "failed"):
            todo.append(entry)
            continue
        if status["status"] == "ok" and not _record_whole(folder):
            todo.append(entry)
            damaged.append(entry.clip_id)
            continue
        pinned = _other_model(folder, cfg) if status["status"] == "ok" else None
        if pinned is not None:
            todo.append(entry)
            other_model.setdefault(pinned, []).append(entry.clip_id)
            continue
        scored_on = _scored_fingerprint(folder, status)
        if scored_on is not None and clip_fingerprint(entry.video) != scored_on:
            todo.append(entry)
            replaced.append(entry.clip_id)
            continue
        failed_before += status["status"] == "failed"
        meta = status.get("meta") or {}
        if meta == entry.meta:
            continue
        if status.get("video") == str(entry.video) and meta.get("masks_path") == entry.meta.get("masks_path"):
            write_status(folder, {**status, "meta": entry.meta})
            refreshed += 1
        else:
            stale.append(entry.clip_id)
    if refreshed:
        note(f"{refreshed} finished clip(s) took the dataset's new metadata (their scores are unchanged)")
    if stale:
        note(
            f"{len(stale)} finished clip(s) now name another clip file or masks and keep their earlier scores (e.g. "
            f"{stale[0]}); remove their folders from {out / CLIPS_DIR} to score them again"
        )
    if replaced:
        shown = ", ".join(replaced[:REPLACED_NAMED]) + (
            f" and {len(replaced) - REPLACED_NAMED} more" if len(replaced) > REPLACED_NAMED else ""
        )
        note(
            f"{len(replaced)} clip file(s) changed since they were scored (other bytes under the same name) and are "
            f"scored again: {shown}"
        )
    for pinned, ids in other_model.items():
        note(
            f"{len(ids)} finished clip(s) were made with the clip model {pinned}, not this run's "
            f"{cfg.signals.model_sha256}, and are scored again: {_named(ids, REPLACED_NAMED)}"
        )
    if damaged:
        note(
            f"{len(damaged)} finished clip(s) have a damaged status.json, or a record.json or matches.npz that is "
            f"missing or damaged, and are scored again: {_named(damaged, REPLACED_NAMED)}"
        )
    return todo, failed_before


def _record_whole(folder: Path) -> bool:
    """Whether the record of a finished clip is there to be read (the tables read it):
    :func:`~geocon_core.record.record_problem` finds nothing amiss."""
    from ..record import record_problem

    return record_problem(folder) is None


def _other_model(folder: Path, cfg: ScoreConfig) -> str | None:
    """The digest of the clip model a finished clip's record was made with, when the clip model
    decided it and that is not the model ``cfg`` pins (:func:`~geocon_core.record.pinned_model`);
    else None."""
    from ..record import RecordError, pinned_model, read_record_json

    if not cfg.signals.enabled:
        return None
    try:
        pinned = pinned_model(read_record_json(folder)[1])
    except RecordError:
        return None
    return pinned if pinned is not None and pinned != cfg.signals.model_sha256 else None


REPLACED_NAMED = 10
"""Clips whose file changed since they were scored are named up to this many."""


def _scored_fingerprint(folder: Path, status: dict[str, Any]) -> str | None:
    """The fingerprint of the clip file a finished clip was scored on: in its ``status.json``, or
    (results written before statuses held one) in its ``record.json``; None when neither says."""
    if isinstance(status.get("fingerprint"), str):
        return str(status["fingerprint"])
    if status.get("status") != "ok":
        return None
    from ..record import RecordError, read_record_json

    try:
        video = read_record_json(folder)[1].get("video")
    except RecordError:
        return None
    found = video.get("fingerprint") if isinstance(video, dict) else None
    return found if isinstance(found, str) else None


def _score_all(
    todo: list[ClipEntry],
    out: Path,
    cfg: ScoreConfig,
    workers: int,
    rrd_renderer: RecordRenderer | None,
    finished: Callable[[dict[str, Any]], None],
    note: Callable[[str], None] = lambda _msg: None,
) -> None:
    """Score ``todo`` in worker processes, calling ``finished(status)`` per clip. A clip in flight
    when a worker dies is retried alone, and recorded as failed after :data:`MAX_CRASHES` deaths;
    ``note`` hears of each death in one sentence (and of a resource tracker killed with the
    workers, which is started again without the tracebacks multiprocessing would print)."""
    threads = max(1, (os.cpu_count() or 1) // workers)
    crashes: dict[str, int] = {}
    queue = list(todo)
    ctx = multiprocessing.get_context("spawn")
    while queue:
        limit = 1 if crashes else workers  # after a worker died, suspects run alone
        _tracker_checked(note)
        pool = ProcessPoolExecutor(
            max_workers=min(limit, len(queue)),
            mp_context=ctx,
            initializer=die_with_parent,  # workers exit when this process dies, kill -9 included
            initargs=(os.getpid(),),
        )
        inflight: dict[Future[dict[str, Any]], ClipEntry] = {}
        broken = False
        try:
            while queue or inflight:
                while queue and len(inflight) < limit and not broken:
                    entry = queue.pop(0)
                    fut = pool.submit(
                        score_one, entry, cfg.to_dict(), str(clip_dir(out, entry.clip_id)), rrd_renderer, threads
                    )
                    inflight[fut] = entry
                if not inflight:
                    break
                done, _ = wait(inflight, return_when=FIRST_COMPLETED)
                lost = [inflight[fut].clip_id for fut in done if _died(fut)]
                if lost and not broken:
                    lost += [e.clip_id for f, e in inflight.items() if f not in done]  # the pool is gone with it
                    note(_death_sentence(lost, workers, crashes))
                for fut in done:
                    entry = inflight.pop(fut)
                    try:
                        status = fut.result()
                    except BrokenProcessPool:
                        broken = True
                        crashes[entry.clip_id] = crashes.get(entry.clip_id, 0) + 1
                        if crashes[entry.clip_id] < MAX_CRASHES:
                            queue.insert(0, entry)
                            continue
                        status = crashed_status(entry, cfg)
                        install_clip(clip_dir(out, entry.clip_id), status)
                    finished(status)
                if broken and not inflight:
                    break
        except BaseException:  # Ctrl-C: finished clips are kept, clips in flight are scored again on resume
            procs = list(getattr(pool, "_processes", {}).values())
            for proc in procs:
                proc.terminate()
            for proc in procs:
                proc.join(timeout=TERMINATE_WAIT_S)
            for entry in inflight.values():  # what the killed workers were writing
                _clear_unfinished(clip_dir(out, entry.clip_id))
            _tracker_checked(note)
            pool.shutdown(wait=False, cancel_futures=True)
            raise
        _tracker_checked(note)  # before the pool's semaphores are forgotten by a tracker started anew
        with quiet_tracker_restarts() as restarted:  # the semaphores are forgotten here: a tracker killed since
            pool.shutdown(wait=True)  # the check is started again quietly
        if restarted:
            note(TRACKER_RESTARTED)


TERMINATE_WAIT_S = 5.0
"""After Ctrl-C or ``kill``, seconds to wait for each worker process to end before its unfinished
clip folder is removed."""


def _clear_unfinished(folder: Path) -> None:
    """Remove what a killed worker left of a clip: its staging folder (``.<clip_id>.part-<pid>``,
    its process gone) and the clip folder when it holds no ``status.json`` (scored again on resume)."""
    import shutil

    clear_stale_parts(folder)
    if folder.is_dir() and not (folder / STATUS_NAME).exists():
        shutil.rmtree(folder, ignore_errors=True)


def _died(fut: Future[dict[str, Any]]) -> bool:
    """Whether ``fut`` failed because its worker process died (the pool broke)."""
    return fut.exception() is not None and isinstance(fut.exception(), BrokenProcessPool)


def _death_sentence(lost: list[str], workers: int, crashes: dict[str, int]) -> str:
    """What a run says when a worker process died with the clips ``lost`` in flight."""
    given_up = [c for c in lost if crashes.get(c, 0) + 1 >= MAX_CRASHES]
    done = "scoring it again" if len(lost) == 1 else "scoring them again"
    if given_up:
        done = f"recording {_named(given_up)} as failed (a worker died {MAX_CRASHES} times on it)"
        if len(given_up) < len(lost):
            done += ", scoring the others again"
    if workers > 1 and not crashes:
        done += ", one clip at a time from now on"
    return (
        f"a worker process died (killed, out of memory or a crash in a native library) while scoring "
        f"{_named(lost)}; {done}"
    )


def _named(clip_ids: list[str], most: int = 5) -> str:
    shown = ", ".join(clip_ids[:most])
    return shown + (f" and {len(clip_ids) - most} more" if len(clip_ids) > most else "")


TRACKER_RESTARTED = "the worker pool's resource tracker process had died; a new one was started"
"""What a run says when it found multiprocessing's resource tracker killed and started it again."""


def _tracker_checked(note: Callable[[str], None]) -> None:
    """Start multiprocessing's resource tracker again, quietly, if it was killed; ``note`` says so."""
    if quiet_resource_tracker():
        note(TRACKER_RESTARTED)
