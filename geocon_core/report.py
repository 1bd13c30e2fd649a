"""``geocon report``: the paper's tables and figures from a benchmark's results.

Reads ``RESULTS/bench.json`` and ``RESULTS/tables/*.parquet`` (written by ``geocon bench``) and
writes into ``RESULTS/report/`` (or ``out``):

- ``figures/<name>.png`` and ``.svg``: every figure, each footed with the config hash and the
  software versions it came from;
- ``tables/<name>.csv``: every table;
- ``report.html``: one self-contained page (figures embedded, no external resources) with the
  tables, the figures, the failed clips with their reasons and the flagged clips linked to their
  records and Rerun recordings.

Figures that the data cannot support (no objects, one expected class, ...) are skipped and the
reason is listed in the report.

The report folder is written whole: into a temporary sibling folder that replaces the previous report
only once it is complete (:func:`geocon_core.paths.replace_dir`), so a failed or killed run leaves a
previous report exactly as it was. A folder holding anything but a report (:data:`REPORT_ENTRIES`) is
never replaced.
"""

from __future__ import annotations

import base64
import html
import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np
import pandas as pd

from . import stats
from .paths import check_out_dir, replace_dir
from .report_figures import (
    FigureBuilder,
    fig_calibration,
    fig_dynamic,
    fig_effects,
    fig_margins,
    fig_ridgelines,
    fig_sensitivity,
    fig_tinf,
)
from .tables import read_tables
from .verdict import flag_reasons

__all__ = ["REPORT_ENTRIES", "ReportError", "ReportResult", "build_report"]

REPORT_ENTRIES = frozenset({"report.html", "figures", "tables", ".report.html.part"})
"""What a report folder holds (and what an earlier version left there): a folder holding anything else
is not replaced by a new report."""


class ReportError(ValueError):
    """Results that cannot be reported, or a report folder that cannot be written (one sentence)."""


def _gate_lines(config: dict[str, Any]) -> tuple[float, float, float]:
    """The gate thresholds (tau_t_low, tau_t, tau_t_high) of the benchmark's configuration, drawn
    as the t_inf lines of the gate figures."""
    from .config import ScoreConfig

    cfg = ScoreConfig.from_dict(config) if config else ScoreConfig()
    return (cfg.tau_t_low, cfg.tau_t, cfg.tau_t_high)


@dataclass(frozen=True)
class ReportResult:
    out: Path
    html: Path
    figures: tuple[Path, ...]
    tables: tuple[Path, ...]
    warnings: tuple[str, ...] = field(default_factory=tuple)


def _html_table(df: pd.DataFrame, floats: str = "{:.4g}") -> str:
    head = "".join(f"<th>{html.escape(str(c))}</th>" for c in df.columns)
    body = []
    for row in df.itertuples(index=False):
        cells = []
        for v in row:
            num = isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))
            if isinstance(v, (float, np.floating)):
                text = "–" if not np.isfinite(v) else floats.format(v)
            elif v is None or v is pd.NA:
                text = "–"
            else:
                text = html.escape(str(v))
            cells.append(f'<td class="n">{text}</td>' if num else f"<td>{text}</td>")
        body.append("<tr>" + "".join(cells) + "</tr>")
    return f"<table><thead><tr>{head}</tr></thead><tbody>{''.join(body)}</tbody></table>"


def _flag(v: Any) -> Any:
    """A nullable table cell as its value, None when missing (``pd.NA`` or NaN); booleans as bool."""
    if v is None or v is pd.NA or (isinstance(v, float) and np.isnan(v)):
        return None
    return bool(v) if isinstance(v, (bool, np.bool_)) else v


_FLAG_TEXT = {"fails": "fails the report gate", "not_judged": "background not judged", "no_pose": "no pose (gated F)"}


def _flagged(ok: pd.DataFrame, top: list[dict[str, Any]], rel: str) -> str:
    reasons: dict[str, list[str]] = {}
    for r in ok.itertuples():
        codes = flag_reasons(
            consistent=_flag(r.consistent),
            pose_present=_flag(r.pose_present) is True,
            gate_model=_flag(r.gate_model),
            expected_model=_flag(r.expected_model),
        )
        why = [
            f"gated {r.gate_model}, {r.category} expects {r.expected_model}" if c == "gate_mismatch" else _FLAG_TEXT[c]
            for c in codes
        ]
        if why:
            reasons[r.clip_id] = why
    for t in top[:5]:
        reasons.setdefault(t["clip_id"], []).append(
            f"object {t['object_id']} among the hardest (AdaP90 {t['adap90']:.2f})"
        )
    rows = []
    index = ok.set_index("clip_id")
    for cid, why in sorted(reasons.items()):
        r = index.loc[cid]
        rec = f"{rel}/{r['record']}/record.json"
        if isinstance(r["rrd"], str):
            rrd = f'<a href="{html.escape(rel + "/" + r["rrd"])}">audit.rrd</a>'
        else:
            rrd = f"<code>geocon view {html.escape(str(r['record']))}</code>"
        rows.append(
            f"<tr><td>{html.escape(cid)}</td><td>{html.escape(str(r['model']))}</td><td>{html.escape(str(r['category']))}</td>"
            f'<td>{html.escape("; ".join(why))}</td><td><a href="{html.escape(rec)}">record</a></td><td>{rrd}</td></tr>'
        )
    if not rows:
        return "<p>No clip is flagged.</p>"
    return (
        "<table><thead><tr><th>clip</th><th>platform</th><th>category</th><th>why</th><th>record</th><th>recording</th></tr></thead>"
        f"<tbody>{''.join(rows)}</tbody></table>"
    )


_CSS = """body{font-family:system-ui,-apple-system,Segoe UI,sans-serif;max-width:1180px;margin:2em auto;padding:0 1em;
color:#222}
h1{margin-bottom:0}h2{border-bottom:1px solid #ddd;padding-bottom:.2em;margin-top:2em}.meta{color:#555;font-size:.9em}
table{border-collapse:collapse;font-size:.85em;margin:.5em 0}
th,td{border:1px solid #ddd;padding:3px 7px;text-align:left}
td.n{text-align:right}
th{background:#f4f4f4}figure{margin:1em 0}figure img{max-width:100%;border:1px solid #eee}
figcaption{color:#444;font-size:.9em}.warn{color:#a33}nav a{margin-right:1em}
code{background:#f4f4f4;padding:0 3px;font-size:.9em}"""


def build_report(
    results: str | Path,
    out: str | Path | None = None,
    *,
    seed: int = 0,
    bootstrap: int = 10_000,
    formats: Sequence[str] = ("png", "svg"),
    progress: Callable[[str], None] | None = None,
) -> ReportResult:
    """Write the report of the results folder ``results`` into ``out`` (default
    ``RESULTS/report``), replacing a previous report there only once the new one is complete.
    Raises :class:`ReportError` (or :class:`~geocon_core.paths.OutPathError`, both ``ValueError``)
    before any work when the folder holds no benchmark results or ``out`` cannot be written."""
    base = Path(results)
    target = Path(out) if out is not None else base / "report"
    option = "--out" if out is not None else "the report folder"
    bench, tables = _read_results(base, target, option)
    say = progress or (lambda _what: None)
    with replace_dir(target) as stage:
        b, warnings = _write_report(stage, target, base, bench, tables, seed, bootstrap, formats, say)
    final = [target / p.relative_to(stage) for p in (*b.paths, *b.tables)]
    return ReportResult(
        out=target,
        html=target / "report.html",
        figures=tuple(final[: len(b.paths)]),
        tables=tuple(final[len(b.paths) :]),
        warnings=tuple(warnings),
    )


def _read_results(base: Path, target: Path, option: str) -> tuple[dict[str, Any], dict[str, Any]]:
    """The manifest and tables of the results folder ``base``, once ``target`` (named ``option``) is
    known to be a folder the report may be written to (or replace)."""
    if not base.exists():
        raise ReportError(f"results folder {base} does not exist; pass the --out folder of a `geocon bench` run")
    if not base.is_dir():
        raise ReportError(f"{base} is a file, not a results folder written by `geocon bench`")
    manifest = base / "bench.json"
    if not manifest.is_file():
        raise ReportError(f"{base}: no bench.json; not a results folder written by `geocon bench`")
    check_out_dir(target, option)
    if target.is_dir():
        other = sorted(p.name for p in target.iterdir() if p.name not in REPORT_ENTRIES)
        if other:
            raise ReportError(
                f"{option} {target} holds files that are not part of a report ({', '.join(other[:3])}"
                f"{', ...' if len(other) > 3 else ''}), so it is not replaced; choose a new or empty folder"
            )
    try:
        bench = json.loads(manifest.read_text())
    except (OSError, ValueError) as exc:
        raise ReportError(f"{manifest} cannot be read ({exc}); run `geocon bench` again") from None
    try:
        tables = read_tables(base)
    except FileNotFoundError as exc:
        raise ReportError(str(exc)) from None
    return bench, tables


def _write_report(
    stage: Path,
    target: Path,
    base: Path,
    bench: dict[str, Any],
    tables: dict[str, Any],
    seed: int,
    bootstrap: int,
    formats: Sequence[str],
    say: Callable[[str], None],
) -> tuple[FigureBuilder, list[str]]:
    """Write the report's files into ``stage`` (links relative to its final place ``target``)."""
    versions = bench.get("versions", {})
    clips = tables["clips"]
    ok = clips[clips["status"] == "ok"].copy()
    footer = (
        f"config {bench.get('config_hash')} · geocon {versions.get('geocon', '?')} · opencv "
        f"{versions.get('opencv', '?')} · "
        f"n = {len(ok)} clips"
    )
    b = FigureBuilder(stage, footer, formats, _gate_lines(bench.get("config", {})))
    warnings: list[str] = []
    sections: list[tuple[str, str]] = []

    say("tables")
    sb = []
    for metric, label in (("ir", "IR"), ("ge", "GE (px)"), ("adadfrc_max", "AdaDFRC max (px²)")):
        t = stats.scene_balanced_table(ok, metric, by=("model",), B=bootstrap, seed=seed).assign(metric=label)
        sb.append(t)
    sbt = pd.concat(sb, ignore_index=True)[["metric", "model", "median", "low", "high", "n_scenes", "n_clips"]]
    b.table(sbt, "scene_balanced")
    sections.append(
        (
            "Scene-balanced medians per platform",
            f"<p>Each scene counts once; 95% bootstrap CIs over scenes (B = {bootstrap}).</p>" + _html_table(sbt),
        )
    )
    per_cat = pd.concat(
        [stats.scene_balanced_table(ok, m, B=bootstrap, seed=seed).assign(metric=m.upper()) for m in ("ir", "ge")],
        ignore_index=True,
    )
    per_cat = per_cat[["metric", "model", "category", "median", "low", "high", "n_scenes", "n_clips"]]
    b.table(per_cat, "per_category")
    cover = stats.coverage_table(ok)
    b.table(cover, "coverage")
    sections.append(
        (
            "Coverage: verdicts and pose evidence per platform",
            "<p>Not judged: too few valid pair-scales for the coverage rule. Pose: from the first-last "
            "pair, from a chain of short hops (the first-last pair had too few matches), from a pose log, "
            "or none (gated F by the fail→F convention).</p>"
            + _html_table(cover[[c for c in cover.columns if not c.endswith(("_low", "_high"))]]),
        )
    )
    rates = stats.gate_rates(ok)
    b.table(rates, "gate_rates")
    cons = stats.consensus(ok)
    b.table(cons, "consensus")
    margins = stats.margin_summary(ok)
    aligned = stats.percentile_aligned(ok)
    b.table(aligned, "percentile_aligned")
    sections.append(
        (
            "Per category",
            _html_table(per_cat)
            + "<h3>F-rates and anomaly rates (expected rule C1/C2/C4 → H, C3/C5/C6 → F)</h3>"
            + "<p>Present-only: clips with a pose and a decided gate; fail→F: every clip, no pose counted as F.</p>"
            + _html_table(rates[[c for c in rates.columns if not c.endswith(("_low", "_high"))]])
            + f"<p>Cross-platform consensus: {cons.attrs['n_unanimous']} of {cons.attrs['n_tuples']} "
            "(scene, category) tuples "
            f"with at least two decided platforms are unanimous ({cons.attrs['consensus_rate']:.1%}).</p>"
            + "<h3>Gate margins</h3>"
            + _html_table(margins)
            + "<h3>Percentile-aligned GE (at matched IR percentiles)</h3>"
            + _html_table(aligned),
        )
    )

    say("figures")
    fig_tinf(b, ok)
    fig_margins(b, ok)
    calib = fig_calibration(b, ok, seed)
    if calib is not None:
        sections.append(
            (
                "Gate calibration",
                f"<p>Bootstrap-optimal tau_t on the grid {calib['grid']}: <b>{calib['best_tau']:g}</b> "
                f"(argmax counts {calib['argmax_counts']}).</p>",
            )
        )
    fig_ridgelines(b, ok)
    fig_effects(b, ok, bootstrap, seed)
    top = fig_dynamic(b, tables["objects"], tables["object_frames"])
    fig_sensitivity(b, tables["sensitivity"], bench.get("config", {}))

    say("html")
    failed = clips[clips["status"] == "failed"]
    rel_s = Path(os.path.relpath(base.resolve(), target.resolve())).as_posix()
    if failed.empty:
        fail_html = "<p>No clip failed.</p>"
    else:
        fail_html = _html_table(failed[["clip_id", "model", "category", "error"]])
        warnings.append(f"{len(failed)} clip(s) failed; they are counted and listed in the report")
    figs = "".join(
        f'<figure id="{f.name}"><h3>{html.escape(f.title)}</h3><img alt="{html.escape(f.title)}" '
        f'src="data:image/png;base64,{base64.b64encode(f.png).decode()}"><figcaption>{html.escape(f.caption)}</figcaption></figure>'
        for f in b.figures
    )
    skipped = "".join(f"<li>{html.escape(s)}</li>" for s in b.skipped)
    warnings.extend(f"skipped figure: {s}" for s in b.skipped)
    sections = [
        ("Clips that failed", fail_html),
        ("Flagged clips", _flagged(ok, top, rel_s)),
        *sections,
        ("Figures", figs + (f"<p>Skipped:</p><ul>{skipped}</ul>" if skipped else "")),
    ]
    nav = "".join(f'<a href="#s{i}">{html.escape(t)}</a>' for i, (t, _) in enumerate(sections))
    body = "".join(f'<h2 id="s{i}">{html.escape(t)}</h2>{content}' for i, (t, content) in enumerate(sections))
    ver = ", ".join(f"{html.escape(k)} {html.escape(str(v))}" for k, v in sorted(versions.items()))
    page = (
        '<!doctype html><html lang="en"><head><meta charset="utf-8"><title>GeoCon benchmark report</title>'
        f"<style>{_CSS}</style></head><body>"
        f'<h1>GeoCon benchmark report</h1><p class="meta">dataset {html.escape(str(bench.get("dataset")))} · config '
        f"<b>{html.escape(str(bench.get('config_hash')))}</b> (preset "
        f"{html.escape(str(bench.get('config', {}).get('preset')))}) · {ver}</p>"
        f'<p>{len(clips)} clips: {len(ok)} scored, <span class="warn">{len(failed)} failed</span>; '
        f"{ok['model'].nunique()} platforms, {ok['scene_id'].nunique()} scenes.</p><nav>{nav}</nav>{body}</body></html>"
    )
    (stage / "report.html").write_text(page)
    return b, warnings
