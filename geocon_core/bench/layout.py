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
from pathlib import Path
from typing import Any

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
    "write_manifest",
    "write_json",
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
    """Write ``payload`` as indented JSON, atomically (a temporary file, then a rename)."""
    tmp = path.with_name(f".{path.name}.part")
    tmp.write_text(json.dumps(payload, indent=1, allow_nan=False) + "\n")
    tmp.replace(path)


def read_status(folder: Path) -> dict[str, Any] | None:
    """The ``status.json`` of a clip folder, or None when the clip is not finished."""
    path = folder / STATUS_NAME
    if not path.is_file():
        return None
    try:
        status = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError):
        return None
    return status if status.get("format") == STATUS_FORMAT else None


def write_status(folder: Path, status: dict[str, Any]) -> None:
    """Write a clip's ``status.json`` (the last file of a finished clip); ``status`` carries
    :data:`STATUS_FORMAT` under ``"format"``."""
    write_json(folder / STATUS_NAME, status)


def read_manifest(results: Path) -> dict[str, Any]:
    """The parsed ``bench.json``. Raises ``json.JSONDecodeError`` when it is not JSON and
    ``FileNotFoundError`` when it is missing; the caller checks ``"format"``."""
    parsed: dict[str, Any] = json.loads(manifest_path(results).read_text())
    return parsed


def write_manifest(results: Path, manifest: dict[str, Any]) -> None:
    """Write ``bench.json`` (``manifest`` carries :data:`BENCH_FORMAT` under ``"format"``)."""
    write_json(manifest_path(results), manifest)
