"""Running validation cases: prepare every clip (render, encode, cut) into the cache, then score
each case into ``OUT/cases/<case id>/`` (``record.json`` + ``matches.npz`` as ``geocon score``
writes them, and ``case.json`` with the case, its status and timing).

Both phases run in ``jobs`` worker processes (inline when ``jobs`` is 1). A case whose
``case.json`` says it was scored from the same clip with the same configuration is not scored
again, so an interrupted run resumes; one scored with a configuration that differs only in its
readings' settings (``signals``: a refitted clip model) gets its readings and keeps its background
fit (:func:`_refresh_readings`); a case that fails is recorded with its reason, never dropped.
"""

from __future__ import annotations

import json
import multiprocessing
import os
import shutil
import time
import traceback
from collections.abc import Callable, Iterable
from concurrent.futures import Future, ProcessPoolExecutor, as_completed
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from ..config import ScoreConfig, config_hash
from ..files import RECORD_JSON, SMALL_STATE, ReadRefused, read_text
from .cases import CaseSpec, ValidationPlan
from .prepare import clip_for, code_digest, prepare_case

__all__ = ["CASES_DIR", "CASE_FILE", "LABELS_FILE", "Progress", "run_cases", "case_folder"]

CASES_DIR = "cases"
CASE_FILE = "case.json"
LABELS_FILE = "labels.npz"
"""Object ids per frame (T, H, W) of a synthetic case scored with masks, kept so the tracks can
be checked against the scene's true masks (:func:`~.results.track_coverage`)."""

Progress = Callable[[str, int, int], None]
"""``progress(phase, done, total)``: phase is ``prepare``, ``score`` or ``peer``."""


def case_folder(out: Path, case: CaseSpec) -> Path:
    return out / CASES_DIR / case.case_id


def _prepare_one(case: CaseSpec, plan: ValidationPlan, cache: str, code: str) -> tuple[str, bool, list[str]]:
    """Worker: prepare one cache entry; returns its folder, whether this call made it (False: it
    was in the cache) and what was wrong with an entry it made again (:func:`~.prepare.entry_problem`)."""
    import cv2

    from .prepare import prepare_key

    cv2.setNumThreads(1)
    made = not (Path(cache) / prepare_key(case, plan, code) / "done.json").is_file()
    remade: list[str] = []
    folder = prepare_case(case, plan, Path(cache), code, plan.codecs, remade)
    return str(folder), made or bool(remade), remade


def _score_one(case: CaseSpec, cache_folder: str, cfg_dict: dict[str, Any], folder: str, threads: int) -> dict:
    """Worker: score one case into ``folder`` and write its ``case.json``."""
    import cv2

    from ..media import clip_fingerprint
    from ..record import write_record
    from ..scoring import score_clip

    cv2.setNumThreads(threads)
    cfg = ScoreConfig.from_dict(cfg_dict)
    out = Path(folder)
    try:
        refreshed = _refresh_readings(out, cfg, str(clip_for(case, Path(cache_folder)).clip))
    except Exception:  # noqa: BLE001 - anything amiss with the old record: score the case again
        refreshed = None
    if refreshed is not None:
        return refreshed
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True)
    status: dict[str, Any] = {"case": asdict(case), "status": "ok", "error": None, "config_hash": config_hash(cfg)}
    start = time.perf_counter()
    try:
        prepared = clip_for(case, Path(cache_folder))
        status.update(clip=str(prepared.clip), truth=None if prepared.truth is None else str(prepared.truth))
        if case.source is not None:  # the bytes it was made from: a replaced source is seen (case_problem)
            status["source_fingerprint"] = clip_fingerprint(Path(case.source))
        labels: list[np.ndarray | None] = []
        keep = (
            None
            if prepared.truth is None or case.kind != "synthetic"
            else (lambda d: labels.append(None if d.labels is None else d.labels.copy()))
        )
        record = score_clip(prepared.clip, cfg, workers=threads, on_frame=keep)
        write_record(record, out)
        kept = [lab for lab in labels if lab is not None]
        saved = bool(kept) and len(kept) == len(labels)
        if saved:  # object ids per frame, for identity checks
            np.savez_compressed(out / LABELS_FILE, labels=np.stack(kept))
        status["labels"] = saved
    except Exception as exc:  # every failure is recorded with its reason
        status.update(status="failed", error=f"{type(exc).__name__}: {exc}", traceback=traceback.format_exc(limit=6))
    status["seconds"] = round(time.perf_counter() - start, 3)
    (out / CASE_FILE).write_text(json.dumps(status, indent=1) + "\n")
    return status


def _refresh_readings(out: Path, cfg: ScoreConfig, clip: str) -> dict | None:
    """A case scored earlier from ``clip`` with a configuration that differs from ``cfg`` in its
    ``signals`` alone (a new clip model, other readings' settings) is not scored again: its record
    gets the readings ``cfg`` makes (read from the clip again, maps included) and ``cfg`` itself;
    the background fit, which ``signals`` does not touch, is kept. Returns the case's new status,
    or None when the case must be scored."""
    from dataclasses import replace

    from ..record import read_record, write_record
    from ..scoring import read_readings

    status = _saved_status(out, clip)
    if status is None:
        return None
    digest = config_hash(cfg)
    head = json.loads(read_text(out / "record.json", RECORD_JSON))
    if head.get("config_hash") != status.get("config_hash"):
        return None

    def beyond_signals(d: dict[str, Any]) -> dict[str, Any]:
        # compared as written: a setting the earlier record lacks (a newer one) is a difference
        return {k: v for k, v in json.loads(json.dumps(d)).items() if k != "signals"}

    if beyond_signals(head["config"]) != beyond_signals(cfg.to_dict()):
        return None
    start = time.perf_counter()
    rec = read_record(out)
    readings = read_readings(rec, out, cfg).readings if cfg.signals.enabled else None
    write_record(replace(rec, config=cfg, config_hash=digest, readings=readings), out)
    status.update(config_hash=digest, readings_seconds=round(time.perf_counter() - start, 3))
    tmp = out / (CASE_FILE + ".part")
    tmp.write_text(json.dumps(status, indent=1) + "\n")
    os.replace(tmp, out / CASE_FILE)
    return status


def _peer_one(clip: str, folder: str, max_frames: int) -> dict:
    """Worker: the peers (:mod:`.peer`: the GVGC keep rate and Epipolar-DPO's Sampson distance) on a
    scored case's clip, saved as ``peer.json`` beside its record. A clip a peer cannot read is saved
    with its error (its score None), never dropped."""
    import cv2

    from .peer import PEER_FILE, PEER_VERSION, epipolar_score, peer_keep_rate

    cv2.setNumThreads(1)
    try:
        saved: dict[str, Any] = peer_keep_rate(clip, max_frames).to_dict()
    except Exception as exc:  # recorded, as a failed case is
        saved = {"keep_rate": None, "version": PEER_VERSION, "error": f"{type(exc).__name__}: {exc}"}
    try:
        saved["epipolar"] = epipolar_score(clip, max_frames).to_dict()
    except Exception as exc:  # the second peer's failure is recorded beside the first's
        saved["epipolar"] = {"sampson": None, "error": f"{type(exc).__name__}: {exc}"}
    saved["clip"] = clip
    tmp = Path(folder) / (PEER_FILE + ".part")
    tmp.write_text(json.dumps(saved, indent=1) + "\n")
    os.replace(tmp, Path(folder) / PEER_FILE)
    return saved


def _peer_done(folder: Path, clip: str) -> bool:
    from .peer import read_peer

    saved = read_peer(folder)
    return saved is not None and saved.get("clip") == clip


def _finished(folder: Path, digest: str, clip: Path | None) -> dict | None:
    """The saved status of a case scored earlier from ``clip`` (any clip when None) with the same
    configuration."""
    status = _saved_status(folder, clip)
    return status if status is not None and status.get("config_hash") == digest else None


def _saved_status(folder: Path, clip: Path | str | None) -> dict | None:
    """The saved status of a case scored earlier from ``clip`` (any clip when None), whatever its
    configuration. A clip prepared again into another cache folder is the same clip when its bytes
    are (:func:`~geocon_core.media.clip_fingerprint` of both, the earlier one still there)."""
    try:
        status = json.loads(read_text(folder / CASE_FILE, SMALL_STATE))
    except (OSError, ValueError):  # not JSON, not a regular file, past its bound
        return None
    if status.get("status") != "ok":
        return None
    if clip is not None and status.get("clip") != str(clip) and not _same_clip(status.get("clip"), Path(clip)):
        return None
    if status.get("truth") is not None and "labels" not in status:  # scored before labels were kept
        return None
    return status if (folder / "record.json").is_file() else None


def case_problem(folder: Path, case: CaseSpec, clip: Path | None) -> str | None:
    """Why what is saved in a case's folder cannot stand for ``case``, in one sentence: its
    ``case.json`` damaged or another case's, its record damaged or another record's
    (:func:`~geocon_core.record.record_problem`), its source clip replaced since (its
    ``source_fingerprint``), or scored from other bytes than ``clip`` (the same path) holds now.
    None when it can, or when nothing finished is saved (no ``case.json``, a failed case: scored
    again as any unfinished case is)."""
    from ..media import clip_fingerprint
    from ..record import read_record_json, record_problem

    file = folder / CASE_FILE
    if not file.exists():
        return None
    try:
        status = json.loads(read_text(file, SMALL_STATE))  # a regular file within its bound
    except ReadRefused as exc:
        return f"{file} is damaged ({exc.why})"
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        return f"{file} is damaged ({type(exc).__name__})"
    if not isinstance(status, dict):
        return f"{file} is damaged (not a JSON object)"
    if status.get("status") != "ok":
        return None
    saved_case = status.get("case")
    other = saved_case.get("case_id") if isinstance(saved_case, dict) else None
    if other != case.case_id:
        return f"{file} is that of {'the case ' + repr(other) if other else 'no case'}, not of {case.case_id}"
    problem = record_problem(folder)
    if problem is not None:
        return problem.removesuffix(": score the clip again")
    source = status.get("source_fingerprint")
    if case.source is not None and isinstance(source, str) and clip_fingerprint(Path(case.source)) != source:
        return f"its clip {case.source} changed since it was scored (other bytes under the same name)"
    if clip is None or status.get("clip") != str(clip):  # another clip path: prepared anew, not replaced
        return None
    video = read_record_json(folder)[1].get("video")
    saved = video.get("fingerprint") if isinstance(video, dict) else None
    now = clip_fingerprint(Path(clip))
    if isinstance(saved, str) and now is not None and saved != now:
        return f"{folder / 'record.json'} was scored from other bytes than {clip} holds now"
    return None


def _same_clip(before: Any, clip: Path) -> bool:
    """Whether the clip at ``before`` (a path, or nothing) is still there and holds the bytes of ``clip``."""
    from ..media import clip_fingerprint

    if not isinstance(before, str) or not Path(before).exists():
        return False
    saved = clip_fingerprint(Path(before))
    return saved is not None and saved == clip_fingerprint(clip)


def _map(fn: Callable[..., Any], jobs: int, argsets: list[tuple], on_done: Callable[[int, Any], None]) -> None:
    """Call ``fn(*args)`` for each argument tuple (in ``jobs`` processes when ``jobs > 1``) and
    ``on_done(index, result)`` as each finishes."""
    if jobs <= 1 or len(argsets) <= 1:
        for i, args in enumerate(argsets):
            on_done(i, fn(*args))
        return
    from ..files import die_with_parent

    with ProcessPoolExecutor(
        max_workers=min(jobs, len(argsets)),
        mp_context=multiprocessing.get_context("spawn"),
        initializer=die_with_parent,  # workers exit when this process dies (an interrupt, kill -9)
        initargs=(os.getpid(),),
    ) as pool:
        futures: dict[Future, int] = {pool.submit(fn, *args): i for i, args in enumerate(argsets)}
        try:
            for fut in as_completed(futures):
                on_done(futures[fut], fut.result())
        except BaseException:
            for fut in futures:
                fut.cancel()
            raise


def _run_peer(
    cases: list[CaseSpec],
    statuses: list[dict[str, Any] | None],
    out_dir: Path,
    max_frames: int,
    jobs: int,
    progress: Progress | None,
) -> None:
    """The peer on every scored annotated (real-footage) case and every planted case that has no
    current ``peer.json``."""
    todo = [
        (str(s["clip"]), str(case_folder(out_dir, c)), max_frames)
        for c, s in zip(cases, statuses, strict=True)
        if c.kind in ("real", "planted")
        and s is not None
        and s.get("status") == "ok"
        and s.get("clip")
        and not _peer_done(case_folder(out_dir, c), str(s["clip"]))
    ]
    done = 0

    def ran(_: int, __: Any) -> None:
        nonlocal done
        done += 1
        if progress is not None:
            progress("peer", done, len(todo))

    if progress is not None and todo:
        progress("peer", 0, len(todo))
    _map(_peer_one, jobs, todo, ran)


def _unique_prepares(cases: Iterable[CaseSpec], plan: ValidationPlan, code: str) -> dict[str, CaseSpec]:
    from .prepare import prepare_key

    keys: dict[str, CaseSpec] = {}
    for case in cases:
        keys.setdefault(prepare_key(case, plan, code), case)
    return keys


def _saved(
    case: CaseSpec, cache_entry: str | None, folder: Path, digest: str, score: bool, unfit: list[tuple[str, str]]
) -> dict[str, Any] | None:
    """The saved status of ``case`` when it was scored earlier with the configuration ``digest``
    from the clip its cache entry holds now (any clip when the entry is not there and nothing is
    scored), else None (it is to be scored). What was saved but cannot stand for the case
    (:func:`case_problem`) goes to ``unfit``, and when scoring, its ``case.json`` goes, so the case
    is scored from its clip and nothing of it is read again."""
    clip = None
    if cache_entry is not None:
        try:
            clip = clip_for(case, Path(cache_entry)).clip
        except ValueError:  # not planted: scored (as failed, with the reason) again
            clip = None
    problem = case_problem(folder, case, clip)
    if problem is not None:
        unfit.append((case.case_id, problem))
        if score:
            (folder / CASE_FILE).unlink()
        return None
    if cache_entry is not None:
        return None if clip is None else _finished(folder, digest, clip)
    if not score:  # a report of what was scored: the record counts whichever clip cache made it
        return _finished(folder, digest, None)
    return None


NAMED = 5
"""A note of the run names up to this many cases or clips (and counts the rest)."""


def named(items: list[str], most: int = NAMED) -> str:
    """``items`` joined for a sentence, the first ``most`` of them and how many more."""
    more = len(items) - most
    return "; ".join(items[:most]) + (f"; and {more} more" if more > 0 else "")


def _run_notes(remade: list[str], unfit: list[tuple[str, str]], cache: Path, score: bool) -> list[str]:
    """The sentences of :func:`run_cases`'s ``notes``."""
    said = []
    if remade:
        said.append(
            f"{len(remade)} clip(s) in the cache {cache} were not as they were made, and were made again (nothing to "
            f"do): {named(remade)}"
        )
    if unfit and score:
        said.append(
            f"{len(unfit)} case(s) were scored again, as what was saved for them could not stand for them: "
            + named([f"{case_id}: {why}" for case_id, why in unfit])
        )
    elif unfit:
        said.append(
            f"{len(unfit)} case(s) are left out of this report, as what was saved for them cannot stand for them "
            f"(run without --report-only to score them again): " + named([f"{c}: {why}" for c, why in unfit])
        )
    return said


def run_cases(
    cases: list[CaseSpec],
    plan: ValidationPlan,
    config: ScoreConfig,
    out: str | Path,
    cache: str | Path,
    *,
    jobs: int = 1,
    progress: Progress | None = None,
    score: bool = True,
    peer: bool = True,
    made: set[str] | None = None,
    notes: list[str] | None = None,
) -> list[tuple[CaseSpec, dict[str, Any]]]:
    """Prepare and score ``cases``; returns each case with its status (``case.json``), in case
    order. With ``score=False`` nothing is prepared or scored: only the cases finished earlier
    are returned (the report of an interrupted run). With ``peer`` (and ``score``), every scored
    annotated clip and planted case also gets the peer's keep rate (``peer.json``, phase
    ``peer``), once per clip. ``made``, when given, receives the cache keys (:func:`~.prepare.prepare_key`)
    this call rendered; the others were reused from the cache. ``notes``, when given, hears in one
    sentence each what the run did not take as it found it: cache entries made again
    (:func:`~.prepare.entry_problem`), cases scored again, or (``score=False``) left out, because
    what was saved for them cannot stand for them (:func:`case_problem`)."""
    out_dir, cache_dir = Path(out), Path(cache)
    code = code_digest()
    from .prepare import prepare_key

    unique = _unique_prepares(cases, plan, code)
    keys = list(unique)
    folders: dict[str, str] = {}
    remade: list[str] = []

    def prepared(i: int, result: tuple[str, bool, list[str]]) -> None:
        folders[keys[i]] = result[0]
        remade.extend(result[2])
        if result[1] and made is not None:
            made.add(keys[i])
        if progress is not None:
            progress("prepare", len(folders), len(keys))

    if score:
        if progress is not None:
            progress("prepare", 0, len(keys))
        _map(_prepare_one, jobs, [(unique[k], plan, str(cache_dir), code) for k in keys], prepared)
    else:
        folders = {k: str(cache_dir / k) for k in keys if (cache_dir / k / "done.json").is_file()}

    digest = config_hash(config)
    unfit: list[tuple[str, str]] = []  # (case id, why its saved record cannot stand for it)
    statuses = [
        _saved(case, folders.get(prepare_key(case, plan, code)), case_folder(out_dir, case), digest, score, unfit)
        for case in cases
    ]
    todo = [i for i, status in enumerate(statuses) if status is None] if score else []
    if notes is not None:
        notes += _run_notes(remade, unfit, cache_dir, score)
    done = len(cases) - len(todo)
    threads = max(1, (os.cpu_count() or 1) // max(1, jobs))

    def scored(j: int, status: dict[str, Any]) -> None:
        nonlocal done
        statuses[todo[j]] = status
        done += 1
        if progress is not None:
            progress("score", done, len(cases))

    if progress is not None:
        progress("score", done, len(cases))
    argsets = [
        (
            cases[i],
            folders[prepare_key(cases[i], plan, code)],
            config.to_dict(),
            str(case_folder(out_dir, cases[i])),
            threads,
        )
        for i in todo
    ]
    _map(_score_one, jobs, argsets, scored)
    if peer and score:
        _run_peer(cases, statuses, out_dir, plan.max_frames, jobs, progress)
    return [(c, s) for c, s in zip(cases, statuses, strict=True) if s is not None]
