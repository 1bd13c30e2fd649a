"""Flat tables of a benchmark's results (clip, pair, object, object-frame and sensitivity level),
written as Parquet for pandas/polars users; columns are documented in ``docs/bench-tables.md``.

Tables are rebuilt from ``RESULTS/clips/*/`` (status + record), sorted by clip id and natural keys,
so an interrupted and resumed run gives the same tables as an uninterrupted one.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Collection

from ..files import PARQUET_TABLE, ReadRefused, regular_file
from ..record import ClipRecord, read_record
from ..scoring import sensitivity_scan, timeline_rows, window_t_inf
from .dataset import expected_model
from .layout import CLIPS_DIR, clip_folders, read_status, tables_dir

__all__ = ["TABLES", "COLUMNS", "collect_rows", "write_tables", "read_tables"]

TABLES = ("clips", "pairs", "objects", "object_frames", "sensitivity")
"""The Parquet tables of a results folder, one file each under ``tables/``."""
_NAN = float("nan")


def _num(v: float | None) -> float:
    return _NAN if v is None else float(v)


def _group(meta: dict[str, Any], clip_id: str, record: ClipRecord | None) -> dict[str, Any]:
    """The columns every table starts with. ``category``: the clip's given category, or where
    none was given the scorer's (such a row has no ``expected_model``)."""
    category = meta.get("category")
    if category is None and record is not None and record.category is not None:
        category = record.category.label
    return {
        "clip_id": clip_id,
        "model": str(meta.get("model")),
        "scene_id": str(meta.get("scene_id")),
        "category": category,
    }


def _clip_row(status: dict[str, Any], record: ClipRecord | None, folder: str) -> dict[str, Any]:
    meta = status.get("meta") or {}
    row: dict[str, Any] = {
        **_group(meta, status["clip_id"], record),
        "model_version": None if meta.get("model_version") is None else str(meta["model_version"]),
        "prompt": meta.get("prompt"),
        "seed": None if meta.get("seed") is None else str(meta["seed"]),
        "expected_model": expected_model(meta.get("category")),
        "status": status["status"],
        "error": status.get("error"),
        "warnings": " | ".join(record.warnings) if record is not None and record.warnings else None,
        "record": folder if record is not None else None,
        "rrd": None if not status.get("rrd") else f"{folder}/{status['rrd']}",
        "config_hash": status.get("config_hash"),
    }
    if record is None:
        row.update({col: _empty("clips", col) for col in COLUMNS["clips"] if col not in row})
        return row
    bg, gate = record.background, record.gate
    fam = {bg.chosen.family: bg.chosen, bg.other.family: bg.other}
    adadfrc = [o.adadfrc for o in record.objects if o.adadfrc is not None]
    adap90 = [o.adap90 for o in record.objects if o.adap90 is not None]
    row.update(
        preset=record.config.preset,
        frames=record.video.num_frames,
        gate_label=gate.label,
        gate_model=gate.model,
        binary_label=gate.binary_label,
        t_inf=_num(gate.t_inf),
        t_window=_num(window_t_inf(timeline_rows(gate.timeline), (0, record.video.num_frames - 1))),
        pose_present=bool(gate.pose_present),
        pose_method=gate.pose.method,
        margin=_num(gate.margin),
        ir=_num(bg.ir),
        ge=_num(bg.ge),
        ir_h=_num(fam["H"].ir),
        ge_h=_num(fam["H"].ge),
        ir_f=_num(fam["F"].ir),
        ge_f=_num(fam["F"].ge),
        ind_h=_num(fam["H"].independent_share),
        ind_f=_num(fam["F"].independent_share),
        valid_pairs=bg.valid_pairs,
        total_pairs=bg.total_pairs,
        consistent=bg.consistent,
        clip_verdict=record.model_verdict(),
        clip_score=_num(record.finding().clip_score),
        tau_f_px=_num(bg.tau_f_px),
        observed_category=None if record.category is None else record.category.label,
        n_objects=len(record.objects),
        shots=len(record.shots),
        adadfrc_max=max(adadfrc) if adadfrc else _NAN,
        adap90_max=max(adap90) if adap90 else _NAN,
        masked_share_mean=float(sum(record.masked_share) / len(record.masked_share)) if record.masked_share else _NAN,
        **_multiview_cols(record),
    )
    return row


def _multiview_cols(record: ClipRecord) -> dict[str, Any]:
    """The multi-view check's columns (NaN / None where the record has no reconstruction)."""
    mv = record.multiview
    if mv is None:
        return {"mv_ir": _NAN, "mv_ge": _NAN, "mv_floor_px": _NAN, "mv_drift_px": _NAN, "mv_finding": None}
    layer = mv.layers[0] if mv.layers else None
    return {
        "mv_ir": _num(mv.mv_ir),
        "mv_ge": _num(mv.mv_ge),
        "mv_floor_px": _num(mv.floor_px),
        "mv_drift_px": layer.drift_px if layer is not None else (_NAN if mv.reason else 0.0),
        "mv_finding": layer.describe() if layer is not None else (f"cannot judge: {mv.reason}" if mv.reason else None),
    }


def _fit_cols(prefix: str, fit) -> dict[str, Any]:
    if fit is None:
        return {f"{prefix}_valid": False, f"{prefix}_ir": _NAN, f"{prefix}_ge": _NAN, f"{prefix}_inliers": 0}
    return {
        f"{prefix}_valid": bool(fit.valid),
        f"{prefix}_ir": _num(fit.ir),
        f"{prefix}_ge": _num(fit.ge),
        f"{prefix}_inliers": int(fit.n_inliers),
    }


def collect_rows(results: str | Path, clip_ids: Collection[str] | None = None) -> dict[str, list[dict[str, Any]]]:
    """The rows of every table, from the finished clips of a results folder (of those in
    ``clip_ids`` only, when given: the clips of the dataset scored)."""
    base = Path(results)
    rows: dict[str, list[dict[str, Any]]] = {name: [] for name in TABLES}
    for folder in clip_folders(base):
        status = read_status(folder)
        if status is None or (clip_ids is not None and folder.name not in clip_ids):
            continue
        rel = f"{CLIPS_DIR}/{folder.name}"
        record = read_record(folder) if status["status"] == "ok" else None
        rows["clips"].append(_clip_row(status, record, rel))
        if record is None:
            continue
        group = _group(status.get("meta") or {}, status["clip_id"], record)
        chosen = record.background.model
        for p in record.pairs:
            rows["pairs"].append(
                {
                    **group,
                    "pair_index": p.index,
                    "t0": p.t0,
                    "t1": p.t1,
                    "gap": p.gap,
                    "scale": p.scale,
                    "n_matches": p.n_matches,
                    "n_gross": p.n_gross,
                    "skip": p.skip,
                    **_fit_cols("h", p.h),
                    **_fit_cols("f", p.f),
                    "chosen": chosen,
                }
            )
        for o in record.objects:
            rows["objects"].append(
                {
                    **group,
                    "object_id": o.object_id,
                    "frames": o.frames,
                    "first_frame": o.first_frame,
                    "last_frame": o.last_frame,
                    "masked_share": float(o.masked_share),
                    "adadfrc": _num(o.adadfrc),
                    "adadfrc_w2": _num(o.adadfrc_w2),
                    "adap90": _num(o.adap90),
                }
            )
        top = max(record.config.scales)
        for e in sorted(record.object_entries, key=lambda e: (e.object_id, e.t0, e.t1)):
            if e.scale != top:
                continue
            rows["object_frames"].append(
                {
                    **group,
                    "object_id": e.object_id,
                    "t0": e.t0,
                    "t1": e.t1,
                    "valid": bool(e.valid),
                    "reason": e.reason,
                    "d_t": _num(e.d_t),
                    "w2": _num(e.w2),
                    "n_pixels": int(e.n_pixels),
                }
            )
        recorded = {"H": record.config.tau_h, "F": record.config.tau_f}
        for r in sensitivity_scan(record):
            rows["sensitivity"].append(
                {
                    **group,
                    "family": r.family,
                    "tau": r.tau,
                    "ir": _num(r.ir),
                    "ge": _num(r.ge),
                    "valid_pairs": r.valid_pairs,
                    "chosen": r.family == chosen,
                    "is_default": math.isclose(r.tau, recorded[r.family], rel_tol=0, abs_tol=1e-12),
                }
            )
    return rows


_GROUP = ["clip_id", "model", "scene_id", "category"]
_CLIP_SCORES = ["ir", "ge", "ir_h", "ge_h", "ir_f", "ge_f", "ind_h", "ind_f"]
"""The clip's IR and GE: of the chosen model, of H, of F; and the share of H's and F's matches
that moved on their own (float columns)."""
COLUMNS: dict[str, list[str]] = {
    "clips": _GROUP
    + [
        "model_version",
        "prompt",
        "seed",
        "expected_model",
        "status",
        "error",
        "warnings",
        "record",
        "rrd",
        "config_hash",
        "preset",
        "frames",
        "gate_label",
        "gate_model",
        "binary_label",
        "t_inf",
        "t_window",
        "pose_present",
        "pose_method",
        "margin",
        *_CLIP_SCORES,
        "valid_pairs",
        "total_pairs",
        "consistent",
        "clip_verdict",
        "clip_score",
        "tau_f_px",
        "observed_category",
        "n_objects",
        "shots",
        "adadfrc_max",
        "adap90_max",
        "masked_share_mean",
        "mv_ir",
        "mv_ge",
        "mv_floor_px",
        "mv_drift_px",
        "mv_finding",
    ],
    "pairs": _GROUP
    + [
        "pair_index",
        "t0",
        "t1",
        "gap",
        "scale",
        "n_matches",
        "n_gross",
        "skip",
        "h_valid",
        "h_ir",
        "h_ge",
        "h_inliers",
        "f_valid",
        "f_ir",
        "f_ge",
        "f_inliers",
        "chosen",
    ],
    "objects": _GROUP
    + ["object_id", "frames", "first_frame", "last_frame", "masked_share", "adadfrc", "adadfrc_w2", "adap90"],
    "object_frames": _GROUP + ["object_id", "t0", "t1", "valid", "reason", "d_t", "w2", "n_pixels"],
    "sensitivity": _GROUP + ["family", "tau", "ir", "ge", "valid_pairs", "chosen", "is_default"],
}
"""Column order of every table (see ``docs/bench-tables.md``)."""
_DTYPES: dict[str, dict[str, str]] = {
    "clips": {
        "pose_present": "boolean",
        "consistent": "boolean",
        "frames": "int64",
        "valid_pairs": "int64",
        "total_pairs": "int64",
        "n_objects": "int64",
        "shots": "int64",
    },
}
_FLOAT = {
    "t_inf",
    "t_window",
    "margin",
    *_CLIP_SCORES,
    "tau_f_px",
    "clip_score",
    "adadfrc_max",
    "adap90_max",
    "masked_share_mean",
    "mv_ir",
    "mv_ge",
    "mv_floor_px",
    "mv_drift_px",
    "scale",
    "h_ir",
    "h_ge",
    "f_ir",
    "f_ge",
    "masked_share",
    "adadfrc",
    "adadfrc_w2",
    "adap90",
    "d_t",
    "w2",
    "tau",
}


def _empty(table: str, column: str) -> Any:
    """The value of ``column`` of ``table`` in a row with nothing to report: NaN in a float
    column, 0 in a count, None otherwise."""
    if column in _FLOAT:
        return _NAN
    return 0 if _DTYPES.get(table, {}).get(column) == "int64" else None


def _frame(name: str, rows: list[dict[str, Any]]):
    import pandas as pd

    df = pd.DataFrame(rows, columns=COLUMNS[name])
    for col in df.columns:
        if col in _FLOAT:
            df[col] = df[col].astype("float64")
    for col, dtype in _DTYPES.get(name, {}).items():
        df[col] = df[col].astype(dtype)
    return df


def write_tables(results: str | Path, clip_ids: Collection[str] | None = None) -> tuple[Path, ...]:
    """Write ``RESULTS/tables/<name>.parquet`` for every table (each atomically; a failed write,
    a full disk, leaves no temporary file), of the clips ``clip_ids`` when given (:func:`collect_rows`)."""
    try:
        import pyarrow  # noqa: F401
    except ImportError:
        raise ImportError(
            "writing Parquet tables needs the bench extra: pip install 'geocon[bench]' (or bash scripts/bootstrap.sh "
            "bench)"
        ) from None
    base = Path(results)
    folder = tables_dir(base)
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for name, rows in collect_rows(base, clip_ids).items():
        path = folder / f"{name}.parquet"
        tmp = folder / f".{name}.parquet.part"
        try:
            _frame(name, rows).to_parquet(tmp, index=False)
            tmp.replace(path)
        except BaseException:
            tmp.unlink(missing_ok=True)
            raise
        paths.append(path)
    return tuple(paths)


def read_tables(results: str | Path) -> dict[str, Any]:
    """Every table of a results folder as a pandas DataFrame, by name."""
    import pandas as pd

    folder = tables_dir(Path(results))
    missing = [n for n in TABLES if not (folder / f"{n}.parquet").exists()]
    if missing:
        raise FileNotFoundError(
            f"{folder}: missing {', '.join(f'{n}.parquet' for n in missing)}; run `geocon bench` first"
        )
    tables = {}
    for name in TABLES:
        path = folder / f"{name}.parquet"
        try:
            regular_file(path, PARQUET_TABLE)  # a FIFO or a device is never opened
        except ReadRefused as exc:
            raise ValueError(
                f"{path} is {exc.why}; run the same `geocon bench` command again, which writes the tables anew"
            ) from None
        try:
            tables[name] = pd.read_parquet(path)
        except (OSError, ValueError) as exc:  # pyarrow's errors of a damaged file are both
            why = str(exc).split(". ")[0].split(":")[-1].strip()
            raise ValueError(
                f"{path} cannot be read as a Parquet table ({why}); run the same `geocon bench` command again, "
                "which writes the tables anew"
            ) from None
    return tables
