"""The layout of a ``geocon bench`` results folder: its formats, paths, the per-clip status and the
manifest. :mod:`geocon_core.bench` writes it; :mod:`geocon_core.bench.tables` and
:mod:`geocon_core.results` read it. See ``docs/bench-tables.md``::

    RESULTS/bench.json                 dataset, full config, config hash, versions (the manifest)
    RESULTS/clips/<clip_id>/           record.json, matches.npz, overlays/, audit.rrd (flagged clips),
                                       status.json (written last: ok or failed, with the reason)
    RESULTS/tables/*.parquet           flat tables, rebuilt from clips/ at the end of every run
    RESULTS/bench.lock                 while a run is writing: its PID and host (removed at its end)

A clip is finished when its ``status.json`` exists.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, Literal

from ..files import BENCH_MANIFEST, STATUS, ReadRefused, read_bytes, read_text

__all__ = [
    "BENCH_FORMAT",
    "STATUS_FORMAT",
    "CLIPS_DIR",
    "TABLES_DIR",
    "MANIFEST_NAME",
    "STATUS_NAME",
    "RRD_NAME",
    "LOCK_NAME",
    "clip_dir",
    "clip_folders",
    "tables_dir",
    "manifest_path",
    "lock_path",
    "read_status",
    "write_status",
    "read_manifest",
    "checked_manifest",
    "write_manifest",
    "write_json",
    "RECORD_NAME",
    "OutputKind",
    "output_kind",
    "check_output_kind",
]

BENCH_FORMAT = "geocon-bench/1"
"""Format of ``bench.json``."""
STATUS_FORMAT = "geocon-bench-clip/1"
"""Format of a clip's ``status.json``."""
CLIPS_DIR = "clips"
"""Sub-folder of the per-clip folders."""
TABLES_DIR = "tables"
"""Sub-folder of the Parquet tables."""
MANIFEST_NAME = "bench.json"
"""The run's manifest in the results folder: the format, the configuration and its hash, every clip."""
STATUS_NAME = "status.json"
"""A clip folder's status file: scored, failed (with the reason) or refused."""
RRD_NAME = "audit.rrd"
"""Name of a flagged clip's Rerun recording inside its folder."""
LOCK_NAME = "bench.lock"
"""The lock file of a run writing into the results folder (:class:`geocon_core.files.lockfile.FolderLock`)."""
RECORD_NAME = "record.json"
"""The file that makes a folder the record of one clip (``geocon score --out``)."""

OutputKind = Literal["results", "record"]
"""What an output folder of GeoCon is: the results of ``geocon bench``, or one clip's record."""
_WRITTEN_BY = {
    "results": f"the results folder of a `geocon bench` run (it holds {MANIFEST_NAME})",
    "record": f"a record folder of `geocon score` (it holds {RECORD_NAME})",
}
_NEVER = {
    "record": "a record never goes among benchmark results",
    "results": "benchmark results never go into a record folder",
}


def output_kind(folder: Path) -> OutputKind | None:
    """What ``folder`` holds: the results of ``geocon bench`` (``"results"``: its ``bench.json``,
    written before anything else), one clip's record (``"record"``: its ``record.json``), or
    neither (None, also for a folder that does not exist); told as every writer tells it
    (:func:`geocon_core.files.folder_kind`)."""
    from ..files import folder_kind

    kind = folder_kind(folder)
    return "results" if kind == "results" else ("record" if kind == "record" else None)


def check_output_kind(folder: Path, kind: OutputKind, option: str = "--out") -> None:
    """Refuse to write a ``kind`` output (``"results"`` or ``"record"``) into ``folder`` when it is,
    or lies inside, a folder of the other kind (:func:`output_kind`): a record written into a
    results folder, or results written into a record folder, would mix with files of another
    layout that every reader of either then misreads. Raises ``ValueError`` with one sentence
    naming ``option``; nothing is created."""
    other: OutputKind = "record" if kind == "results" else "results"
    full = Path(os.path.realpath(folder))
    for at in (full, *full.parents):
        if output_kind(at) == other:
            where = "is" if at == full else f"lies inside {at}, which is"
            raise ValueError(
                f"{option} {folder} {where} {_WRITTEN_BY[other]}, and {_NEVER[kind]}; choose another {option}"
            )


def clip_dir(results: Path, clip_id: str) -> Path:
    """The folder of one clip."""
    return results / CLIPS_DIR / clip_id


def clip_folders(results: Path) -> list[Path]:
    """Every clip folder of a results folder (finished or not), sorted by clip id; hidden folders
    (a record being written, ``.<clip id>.part-<pid>``) are not clip folders."""
    base = results / CLIPS_DIR
    if not base.is_dir():
        return []
    return sorted((p for p in base.iterdir() if p.is_dir() and not p.name.startswith(".")), key=lambda p: p.name)


def tables_dir(results: Path) -> Path:
    """The folder of the Parquet tables."""
    return results / TABLES_DIR


def manifest_path(results: Path) -> Path:
    """The ``bench.json`` of a results folder."""
    return results / MANIFEST_NAME


def lock_path(results: Path) -> Path:
    """The ``bench.lock`` of a results folder."""
    return results / LOCK_NAME


def write_json(path: Path, payload: dict[str, Any]) -> None:
    """Write ``payload`` as indented JSON, atomically (a temporary file, then a rename); a failed
    write (a full disk) leaves no temporary file."""
    text = json.dumps(payload, indent=1, allow_nan=False) + "\n"
    tmp = path.with_name(f".{path.name}.part")
    try:
        tmp.write_text(text)
        tmp.replace(path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def read_status(folder: Path) -> dict[str, Any] | None:
    """The ``status.json`` of a clip folder, or None when the clip is not finished: none, or one
    that is damaged (not UTF-8 JSON, not an object of :data:`STATUS_FORMAT` saying ``ok`` or
    ``failed``) or another clip's (its ``clip_id`` is not its folder's name)."""
    path = folder / STATUS_NAME
    if not path.is_file():
        return None
    try:
        status = json.loads(read_bytes(path, STATUS))
    except (OSError, ValueError):  # not JSON, not UTF-8, not a regular file, past its bound
        return None
    whole = (
        isinstance(status, dict)
        and status.get("format") == STATUS_FORMAT
        and status.get("clip_id") == folder.name
        and status.get("status") in ("ok", "failed")
        and isinstance(status.get("meta") or {}, dict)
    )
    return status if whole else None


def write_status(folder: Path, status: dict[str, Any]) -> None:
    """Write a clip's ``status.json`` (the last file of a finished clip); ``status`` carries
    :data:`STATUS_FORMAT` under ``"format"``."""
    write_json(folder / STATUS_NAME, status)


def read_manifest(results: Path) -> dict[str, Any]:
    """The parsed ``bench.json``. Raises ``json.JSONDecodeError`` when it is not JSON,
    ``FileNotFoundError`` when it is missing and :class:`~geocon_core.files.ReadRefused` when it is
    not a regular file or past :data:`~geocon_core.files.bounded.BENCH_MANIFEST`'s bound; the caller
    checks ``"format"``."""
    path = manifest_path(results)
    if not path.exists():
        raise FileNotFoundError(2, "No such file or directory", str(path))
    parsed: dict[str, Any] = json.loads(read_text(path, BENCH_MANIFEST))
    return parsed


def checked_manifest(results: Path) -> dict[str, Any]:
    """The ``bench.json`` of a results folder, checked. Raises ``FileNotFoundError`` when it is
    missing and ``ValueError`` (one sentence naming it, for the caller to add what to do) when it is
    not a GeoCon benchmark manifest: not UTF-8 JSON, not an object, or of another format."""
    path = manifest_path(results)
    if not path.exists():
        raise FileNotFoundError(2, "No such file or directory", str(path))
    try:
        parsed = json.loads(read_bytes(path, BENCH_MANIFEST))
    except ReadRefused as exc:  # a FIFO, a device, past the bound
        why = exc.why
    except UnicodeDecodeError:
        why = "not UTF-8 text"
    except json.JSONDecodeError as exc:
        why = f"invalid JSON: {exc.msg} at line {exc.lineno}"
    else:
        if not isinstance(parsed, dict):
            kind = {list: "an array", str: "a string", bool: "true or false", type(None): "null"}.get(type(parsed))
            why = f"{kind or 'a number'}, not a JSON object"
        elif parsed.get("format") != BENCH_FORMAT:
            why = f"its format is {parsed.get('format')!r}, not {BENCH_FORMAT}"
        else:
            return parsed
    raise ValueError(f"{path} is not the manifest of GeoCon benchmark results ({why})")


def write_manifest(results: Path, manifest: dict[str, Any]) -> None:
    """Write ``bench.json`` (``manifest`` carries :data:`BENCH_FORMAT` under ``"format"``)."""
    write_json(manifest_path(results), manifest)
