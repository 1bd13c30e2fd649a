"""The clips of a results folder as recorded: one :class:`ResultClip` per clip, from its status, its
sidecar metadata and either ``tables/clips.parquet`` (when it is up to date) or its ``record.json``."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..bench import RRD_NAME, STATUS_NAME, clip_folders, expected_model, read_status, tables_dir
from ..geometry import family_spec
from ..reconstruction import DriftLayer
from ..record import read_record_json
from ..scoring import timeline_rows, window_t_inf

__all__ = ["ResultClip", "clip_from_record_json", "read_bench_clips"]


@dataclass(frozen=True)
class ResultClip:
    """One clip of a results folder as recorded: its sidecar metadata, where its files are, and the
    numbers needed to re-gate it (both families' IR/GE and the gate statistic). A clip that failed
    to score keeps the defaults: no numbers, no pose, no objects. ``category`` is the dataset's, or
    the scorer's where the dataset gives none (as in the tables); ``expected_model`` is then None."""

    clip_id: str
    platform: str
    category: str | None
    expected_model: str | None
    status: str
    error: str | None
    folder: Path | None
    rrd: Path | None
    prompt: str | None
    t_inf: float | None = None
    t_window: float | None = None
    pose_present: bool = False
    ir_h: float | None = None
    ge_h: float | None = None
    ir_f: float | None = None
    ge_f: float | None = None
    ind_h: float = 0.0
    ind_f: float = 0.0
    adap90_max: float | None = None
    n_objects: int = 0
    shots: int = 0
    """Shots judged on their own (0: one shot); such a clip is re-gated shot by shot."""
    drift: str | None = None
    """What the multi-view check found when it failed the background (it does not depend on the
    thresholds re-gating moves), else None."""
    finding: str | None = None
    """The clip model's verdict where it decides the clip
    (:meth:`~geocon_core.record.ClipRecord.model_verdict`; it does not depend on the thresholds
    re-gating moves: the flag follows it), else None."""
    clip_score: float | None = None
    """The clip model's score where it decides the clip (with :attr:`finding`), else None."""

    def scores(self, family: str) -> tuple[float | None, float | None]:
        """The recorded ``(IR, GE)`` of background ``family``."""
        attr = family_spec(family).attr
        return getattr(self, f"ir_{attr}"), getattr(self, f"ge_{attr}")

    def moved(self, family: str) -> float:
        """The share of background ``family``'s matches that moved on their own (median over pairs)."""
        return float(getattr(self, f"ind_{family_spec(family).attr}"))


def _num(v: Any) -> float | None:
    if v is None:
        return None
    f = float(v)
    return None if math.isnan(f) else f


def _sidecar(clip_id: str, status: dict[str, Any], folder: Path) -> dict[str, Any]:
    """The :class:`ResultClip` fields every clip takes from its status and sidecar metadata."""
    meta = status.get("meta") or {}
    return {
        "clip_id": clip_id,
        "platform": str(meta.get("model", "-")),
        "category": meta.get("category"),
        "expected_model": expected_model(meta.get("category")),
        "folder": folder,
        "prompt": meta.get("prompt"),
    }


def clip_from_record_json(
    clip_id: str, status: dict[str, Any], folder: Path, d: dict[str, Any] | None = None
) -> ResultClip:
    """A clip's triage numbers from its ``record.json`` (no arrays read; ``d`` when already parsed
    by :func:`~geocon_core.record.clip.read_record_json`, which checks the record format)."""
    if d is None:
        _, d = read_record_json(folder)
    bg, gate = d["background"], d["gate"]
    fam = {bg["chosen"]["family"]: bg["chosen"], bg["other"]["family"]: bg["other"]}
    adap90 = [o["adap90"] for o in d.get("objects", []) if o.get("adap90") is not None]
    rrd = (
        folder / status["rrd"] if status.get("rrd") else (folder / RRD_NAME if (folder / RRD_NAME).is_file() else None)
    )
    given = _sidecar(clip_id, status, folder)
    if given["category"] is None and d.get("category"):  # as the tables: the scorer's stands in
        given["category"] = d["category"].get("label")
    finding = finding_of_json(d)
    return ResultClip(
        **given,
        status="ok",
        error=None,
        rrd=rrd,
        t_inf=gate["t_inf"],
        t_window=window_t_inf(timeline_rows(gate.get("timeline", [])), (0, int(d["video"]["num_frames"]) - 1)),
        pose_present=bool(gate["pose_present"]),
        ir_h=fam["H"]["ir"],
        ge_h=fam["H"]["ge"],
        ir_f=fam["F"]["ir"],
        ge_f=fam["F"]["ge"],
        ind_h=float(fam["H"].get("independent_share", 0.0)),
        ind_f=float(fam["F"].get("independent_share", 0.0)),
        adap90_max=max(adap90) if adap90 else None,
        n_objects=len(d.get("objects", [])),
        shots=len(d.get("shots", [])),
        drift=drift_of_json(d),
        finding=finding,
        clip_score=None if finding is None else _num(d.get("summary", {}).get("clip_score")),
    )


def finding_of_json(d: dict[str, Any]) -> str | None:
    """The clip model's verdict of a parsed ``record.json`` where it decides the clip (as
    :meth:`~geocon_core.record.ClipRecord.model_verdict`), else None."""
    if d.get("readings") is None or not (d.get("config", {}).get("signals") or {}).get("enabled"):
        return None
    verdict = (d.get("summary", {}).get("verdict") or {}).get("verdict")
    return str(verdict) if verdict is not None else None


def drift_of_json(d: dict[str, Any]) -> str | None:
    """The multi-view check's finding of a parsed ``record.json`` when it failed the background
    (as :meth:`~geocon_core.record.ClipRecord.drift_finding`), else None."""
    mv = d.get("multiview") or {}
    layers = mv.get("layers") or []
    if not layers or mv.get("reason") or not (d.get("config", {}).get("multiview") or {}).get("enabled"):
        return None
    return DriftLayer.from_dict(layers[0]).describe()


def _failed_clip(clip_id: str, status: dict[str, Any], folder: Path) -> ResultClip:
    return ResultClip(
        **_sidecar(clip_id, status, folder),
        status="failed",
        error=status.get("error") or "unknown error",
        rrd=None,
    )


def _table_rows(results: Path, newest_status: float) -> dict[str, dict[str, Any]]:
    """Rows of ``tables/clips.parquet`` by clip id when the table is newer than every clip status
    (else empty: the records are read instead)."""
    path = tables_dir(results) / "clips.parquet"
    try:
        if not path.is_file() or path.stat().st_mtime < newest_status:
            return {}
        import pyarrow.parquet as pq
    except (ImportError, OSError):
        return {}
    cols = ["clip_id", "category", "status", "t_inf", "pose_present", "ir_h", "ge_h", "ir_f", "ge_f"]
    cols += ["adap90_max", "n_objects"]
    schema = pq.read_schema(path)
    if not {"shots", "t_window", "ind_h", "ind_f"} <= set(schema.names):  # tables of an earlier version
        return {}
    cols += ["shots", "t_window", "ind_h", "ind_f"]
    if "mv_finding" in schema.names:
        cols += ["mv_finding", "mv_drift_px"]
    if "clip_verdict" in schema.names:
        cols += ["clip_verdict", "clip_score"]
    table = pq.read_table(path, columns=cols).to_pydict()
    return {cid: {c: table[c][i] for c in cols} for i, cid in enumerate(table["clip_id"])}


def _drift_of_row(row: dict[str, Any]) -> str | None:
    """The multi-view finding of a ``clips`` table row when it failed the background, else None."""
    finding, drift = row.get("mv_finding"), _num(row.get("mv_drift_px"))
    return finding if finding and drift is not None and drift > 0 else None


def read_bench_clips(root: Path) -> list[ResultClip]:
    """Every clip of the ``geocon bench`` results folder ``root`` with a status (clips in flight or
    never started are left out), in folder order."""
    statuses = []
    newest = 0.0
    for folder in clip_folders(root):
        status = read_status(folder)
        if status is None:
            continue  # in flight or never started
        newest = max(newest, (folder / STATUS_NAME).stat().st_mtime)
        statuses.append((folder, status))
    table = _table_rows(root, newest)
    clips = []
    for folder, status in statuses:
        cid = status["clip_id"]
        if status["status"] != "ok":
            clips.append(_failed_clip(cid, status, folder))
            continue
        row = table.get(cid)
        if row is None or row["status"] != "ok":
            clips.append(clip_from_record_json(cid, status, folder))
            continue
        given = _sidecar(cid, status, folder)
        given["category"] = given["category"] or row["category"]  # the table's: given, or the scorer's
        clips.append(
            ResultClip(
                **given,
                status="ok",
                error=None,
                rrd=folder / status["rrd"] if status.get("rrd") else None,
                t_inf=_num(row["t_inf"]),
                t_window=_num(row["t_window"]),
                pose_present=bool(row["pose_present"]),
                ir_h=_num(row["ir_h"]),
                ge_h=_num(row["ge_h"]),
                ir_f=_num(row["ir_f"]),
                ge_f=_num(row["ge_f"]),
                ind_h=_num(row["ind_h"]) or 0.0,
                ind_f=_num(row["ind_f"]) or 0.0,
                adap90_max=_num(row["adap90_max"]),
                n_objects=int(row["n_objects"]),
                shots=int(row["shots"]),
                drift=_drift_of_row(row),
                finding=row.get("clip_verdict"),
                clip_score=None if row.get("clip_verdict") is None else _num(row.get("clip_score")),
            )
        )
    return clips
