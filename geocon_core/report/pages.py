"""``geocon report``: the paper's tables and figures from a benchmark's results.

Reads ``RESULTS/bench.json`` and ``RESULTS/tables/*.parquet`` (written by ``geocon bench``) and
writes into ``RESULTS/report/`` (or ``out``):

- ``figures/<name>.png`` and ``.svg``: every figure, each footed with the config hash and the
  software versions it came from;
- ``tables/<name>.csv``: every table;
- ``report.html``: one self-contained page (figures embedded, no external resources). Its first
  screen answers three questions with one figure each, before any table: which platform is most
  consistent, where the gate is thin, which categories fail. Then the failed clips with their
  reasons, the flagged clips (each with its numbers, a strip of thumbnails: first frame, worst
  pair with its inliers and outliers drawn, last frame; :mod:`geocon_core.results.thumbs`) linked to
  their records and Rerun recordings, the tables (sortable by a click on a header, filtered by the
  box above each, with a few lines of inline script) and the other figures.

Figures that the data cannot support (no objects, one expected class, ...) are skipped and the
reason is listed in the report.

The report folder is written whole: into a temporary sibling folder that replaces the previous report
only once it is complete (:func:`geocon_core.files.paths.replace_dir`), so a failed or killed run leaves a
previous report exactly as it was. A folder holding anything but a report (:data:`REPORT_ENTRIES`) is
never replaced.
"""

from __future__ import annotations

import base64
import html
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np
import pandas as pd

from ..bench import checked_manifest, lock_path, read_tables
from ..config import ScoreConfig
from ..files import check_out_dir, claim, lock_holder, replace_dir
from ..results import ClipThumbs, many_clip_thumbs, thumbs_html
from ..scoring import flag_reasons
from . import stats
from .figures import (
    FigureBuilder,
    fig_calibration,
    fig_dynamic,
    fig_effects,
    fig_margins,
    fig_ridgelines,
    fig_sensitivity,
    fig_summary_failures,
    fig_summary_margins,
    fig_summary_platforms,
    fig_tinf,
)

__all__ = ["REPORT_ENTRIES", "ReportError", "ReportResult", "build_report"]

REPORT_ENTRIES = frozenset({"report.html", "figures", "tables", ".report.html.part"})
"""What a report folder holds (and what an earlier version left there): a folder holding anything else
is not replaced by a new report."""


class ReportError(ValueError):
    """Results that cannot be reported, or a report folder that cannot be written (one sentence)."""


def _config(config: dict[str, Any]) -> ScoreConfig:
    """The benchmark's scoring configuration (the defaults when the manifest holds none)."""
    return ScoreConfig.from_dict(config) if config else ScoreConfig()


def _gate_lines(config: dict[str, Any]) -> tuple[float, float, float]:
    """The gate thresholds (tau_t_low, tau_t, tau_t_high) of the benchmark's configuration, drawn
    as the t_inf lines of the gate figures."""
    cfg = _config(config)
    return (cfg.tau_t_low, cfg.tau_t, cfg.tau_t_high)


@dataclass(frozen=True)
class ReportResult:
    """What :func:`build_report` wrote: the folder, the HTML page and the figures."""

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


_FLAG_TEXT = {
    "model": "the clip model flags it",
    "fails": "fails the report gate",
    "not_judged": "not judged",
    "no_pose": "no pose (gated F)",
}


def _flag_reasons(ok: pd.DataFrame, top: list[dict[str, Any]]) -> dict[str, list[str]]:
    """Why each flagged clip is flagged, by clip id (one phrase per reason)."""
    reasons: dict[str, list[str]] = {}
    for r in ok.itertuples():
        codes = flag_reasons(
            consistent=_flag(r.consistent),
            pose_present=_flag(r.pose_present) is True,
            gate_model=_flag(r.gate_model),
            expected_model=_flag(r.expected_model),
            finding=_flag(getattr(r, "clip_verdict", None)),
        )
        texts = dict(_FLAG_TEXT, gate_mismatch=f"gated {r.gate_model}, {r.category} expects {r.expected_model}")
        score = _flag(getattr(r, "clip_score", None))
        if score is not None:
            texts["model"] += f" (clip score {score:.2f})"
        why = [texts[c] for c in codes]
        if why:
            reasons[r.clip_id] = why
    for t in top[:5]:
        reasons.setdefault(t["clip_id"], []).append(
            f"object {t['object_id']} among the hardest (AdaP90 {t['adap90']:.2f})"
        )
    return reasons


def _num(v: Any, fmt: str = "{:.4g}") -> str:
    v = _flag(v)
    return "–" if v is None or not np.isfinite(float(v)) else fmt.format(float(v))


def _flagged(
    ok: pd.DataFrame, top: list[dict[str, Any]], rel: str, thumbs: Mapping[str, ClipThumbs] | None = None
) -> str:
    """The flagged clips' table (:func:`_flag_reasons`): each clip's numbers and reasons next to its
    thumbnails (``thumbs``, by clip id), linked to its record and recording (``rel``: the results
    folder relative to the report)."""
    reasons = _flag_reasons(ok, top)
    thumbs = thumbs or {}
    rows = []
    index = ok.set_index("clip_id")
    for cid, why in sorted(reasons.items()):
        r = index.loc[cid]
        rec = f"{rel}/{r['record']}/record.json"
        if isinstance(r["rrd"], str):
            rrd = f'<a href="{html.escape(rel + "/" + r["rrd"])}">audit.rrd</a>'
        else:
            rrd = f"<code>geocon view {html.escape(str(r['record']))}</code>"
        strip = thumbs_html(thumbs[cid]) if cid in thumbs else ""
        gate = f"{_flag(r.get('gate_model')) or '–'} ({_num(r.get('t_inf'), '{:.3g}')})"
        rows.append(
            f"<tr><td>{html.escape(cid)}</td><td>{html.escape(str(r['model']))}</td>"
            f"<td>{html.escape(str(r['category']))}</td>"
            f'<td class="n">{_num(r.get("ir"))}</td><td class="n">{_num(r.get("ge"))}</td><td>{html.escape(gate)}</td>'
            f'<td>{html.escape("; ".join(why))}</td><td class="strip">{strip}</td>'
            f'<td><a href="{html.escape(rec)}">record</a></td><td>{rrd}</td></tr>'
        )
    if not rows:
        return "<p>No clip is flagged.</p>"
    return (
        "<p>Thumbnails: the first frame, the pair the clip scores worst on (lowest IR) with its inlier matches "
        "in green and its outliers in red (a dot where a match lies, a line to where it went), the last frame.</p>"
        '<table class="flagged"><thead><tr><th>clip</th><th>platform</th><th>category</th><th>IR</th>'
        "<th>GE (px)</th><th>gate (t_inf)</th><th>why</th><th>frames</th><th>record</th><th>recording</th>"
        f"</tr></thead><tbody>{''.join(rows)}</tbody></table>"
    )


_CSS = """body{font-family:system-ui,-apple-system,Segoe UI,sans-serif;max-width:1560px;margin:1em auto;padding:0 1em;
color:#222}
h1{margin:0}h2{border-bottom:1px solid #ddd;padding-bottom:.2em;margin-top:2em}
.meta{color:#555;font-size:.9em;margin:.2em 0}
p.counts{margin:.2em 0 .6em}
.summary{display:grid;grid-template-columns:repeat(3,minmax(0,1fr));gap:1em;margin:0 0 .6em}
.summary figure{margin:0}.summary h3{margin:.1em 0 .3em;font-size:1.05em}
.summary img{width:100%;height:auto}.summary figcaption{font-size:.8em}
.summary .none{color:#777;border:1px dashed #ccc;padding:1em}
table{border-collapse:collapse;font-size:.85em;margin:.2em 0 .8em}
th,td{border:1px solid #ddd;padding:3px 7px;text-align:left;vertical-align:top}
td.n{text-align:right}
th{background:#f4f4f4}figure{margin:1em 0}figure img{max-width:100%;border:1px solid #eee}
table.sortable th{cursor:pointer;user-select:none}table.sortable th:hover{background:#e8eef7}
th[aria-sort=ascending]::after{content:" \\25B2";font-size:.75em}
th[aria-sort=descending]::after{content:" \\25BC";font-size:.75em}
input.filter{display:block;margin:.6em 0 0;padding:2px 6px;font:inherit;font-size:.85em;width:16em}
.thumbs{display:flex;gap:4px}.thumbs figure{margin:0}.thumbs img{display:block;border:1px solid #ccc}
.thumbs figcaption{font-size:.75em;color:#555;max-width:200px}p.nothumbs{margin:0;color:#a33;font-size:.85em}
figcaption{color:#444;font-size:.9em}.warn{color:#a33}nav{margin:.4em 0}nav a{margin-right:1em}
code{background:#f4f4f4;padding:0 3px;font-size:.9em}"""

_SCRIPT = """(function(){
function key(td){var t=td.textContent.trim();if(t===''||t==='\\u2013')return null;
var n=Number(t);return isFinite(n)?n:t.toLowerCase()}
function cmp(a,b){if(typeof a===typeof b)return a<b?-1:a>b?1:0;return typeof a==='number'?-1:1}
document.querySelectorAll('table.sortable').forEach(function(t){var hs=t.tHead.rows[0].cells;
Array.prototype.forEach.call(hs,function(th,i){th.title='sort by '+th.textContent;
th.addEventListener('click',function(){var asc=th.getAttribute('aria-sort')!=='ascending';
Array.prototype.forEach.call(hs,function(h){h.removeAttribute('aria-sort')});
th.setAttribute('aria-sort',asc?'ascending':'descending');var body=t.tBodies[0];
var rows=Array.prototype.slice.call(body.rows).map(function(r,j){return [key(r.cells[i]),j,r]});
rows.sort(function(a,b){if(a[0]===null||b[0]===null)return a[0]===b[0]?a[1]-b[1]:a[0]===null?1:-1;
return (asc?1:-1)*cmp(a[0],b[0])||a[1]-b[1]});rows.forEach(function(r){body.appendChild(r[2])})})})});
document.querySelectorAll('input.filter').forEach(function(box){var t=document.getElementById(box.dataset.table);
box.addEventListener('input',function(){var q=box.value.trim().toLowerCase();
Array.prototype.forEach.call(t.tBodies[0].rows,function(r){
r.style.display=!q||r.textContent.toLowerCase().indexOf(q)>=0?'':'none'})})})})();"""
"""Sorting (a click on a header; again to reverse; numbers as numbers, missing values last) and
filtering (rows holding the text typed in the box above the table) of the page's tables."""


def _interactive_tables(body: str) -> str:
    """Every table of ``body`` made sortable and given its own filter box (ids t0, t1, ...)."""
    count = iter(range(1 << 30))

    def wire(m: re.Match[str]) -> str:
        i = next(count)
        cls = m.group(1)
        classes = f"{cls} sortable" if cls else "sortable"
        return (
            f'<input type="search" class="filter" data-table="t{i}" placeholder="filter rows…" '
            f'aria-label="filter the rows of the table below"><table id="t{i}" class="{classes}">'
        )

    return re.sub(r'<table(?: class="([^"]*)")?>', wire, body)


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
    Raises :class:`ReportError` (or :class:`~geocon_core.files.paths.OutPathError`, both ``ValueError``)
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
    if not manifest.exists():  # a FIFO or a device in its place is refused by checked_manifest, naming it
        raise ReportError(f"{base}: no bench.json; not a results folder written by `geocon bench`")
    check_out_dir(target, option)
    if target.is_dir():
        other = sorted(p.name for p in target.iterdir() if p.name not in REPORT_ENTRIES)
        if other:
            raise ReportError(
                f"{option} {target} holds files that are not part of a report ({', '.join(other[:3])}"
                f"{', ...' if len(other) > 3 else ''}), so it is not replaced; choose a new or empty folder"
            )
    claim(option, target, "report", own=[base])  # never into another output, nor over a user's own report.html
    try:
        bench = checked_manifest(base)
    except (OSError, ValueError) as exc:
        raise ReportError(f"{exc}: the results folder is damaged; score the dataset into a new one") from None
    running = lock_holder(lock_path(base))
    if running is not None:
        who = "" if running.pid is None else f" (PID {running.pid})"
        raise ReportError(
            f"{base} is being written by a running `geocon bench`{who}, which writes its tables when it ends; "
            "run `geocon report` once it has finished"
        )
    try:
        tables = read_tables(base)
    except FileNotFoundError as exc:
        raise ReportError(str(exc)) from None
    return bench, tables


_QUESTIONS = (
    ("summary_platforms", "Which platform is most consistent?"),
    ("summary_margins", "Where is the gate thin?"),
    ("summary_failures", "Which categories fail?"),
)
_SKIP_TITLES = {
    "summary_platforms": "Platform consistency",
    "summary_margins": "Gate margins (first screen)",
    "summary_failures": "Failures per category",
}
"""The titles the first-screen figures are skipped under (:meth:`FigureBuilder.skip`)."""


def _img(f: Any) -> str:
    return f'<img alt="{html.escape(f.title)}" src="data:image/png;base64,{base64.b64encode(f.png).decode()}">'


def _figure_html(f: Any) -> str:
    return (
        f'<figure id="{f.name}"><h3>{html.escape(f.title)}</h3>{_img(f)}'
        f"<figcaption>{html.escape(f.caption)}</figcaption></figure>"
    )


def _summary_html(b: FigureBuilder) -> str:
    """The first screen: one figure per question, side by side (a note where the data cannot
    answer it)."""
    made = {f.name: f for f in b.figures}
    cells = []
    for name, question in _QUESTIONS:
        f = made.get(name)
        if f is None:
            why = next((s.split(": ", 1)[-1] for s in b.skipped if s.startswith(_SKIP_TITLES[name])), "no data")
            shown = f'<p class="none">Not drawn: {html.escape(why)}.</p>'
        else:
            shown = f"{_img(f)}<figcaption>{html.escape(f.caption)}</figcaption>"
        cells.append(f'<figure id="{name}"><h3>{question}</h3>{shown}</figure>')
    return f'<section class="summary">{"".join(cells)}</section>'


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
    order = fig_summary_platforms(b, sb[0], _config(bench.get("config", {})).ir_gate, bootstrap)
    fig_summary_margins(b, ok, order)
    fig_summary_failures(b, ok, order)
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

    say("thumbnails")
    reasons = _flag_reasons(ok, top)
    records = ok.set_index("clip_id")["record"]
    thumbs = many_clip_thumbs({cid: base / str(records[cid]) for cid in reasons})
    missing = [t for t in thumbs.values() if not t.thumbs]
    if missing:
        warnings.append(f"{len(missing)} flagged clip(s) shown without thumbnails (e.g. {missing[0].note})")

    say("html")
    failed = clips[clips["status"] == "failed"]
    rel_s = Path(os.path.relpath(base.resolve(), target.resolve())).as_posix()
    if failed.empty:
        fail_html = "<p>No clip failed.</p>"
    else:
        fail_html = _html_table(failed[["clip_id", "model", "category", "error"]])
        warnings.append(f"{len(failed)} clip(s) failed; they are counted and listed in the report")
    for f in b.figures:
        if f.overlaps:
            o = f.overlaps[0]
            warnings.append(
                f"figure {f.name}: {len(f.overlaps)} pair(s) of tick labels overlap ({o.first}, {o.second})"
            )
    figs = "".join(_figure_html(f) for f in b.figures if not f.name.startswith("summary_"))
    skipped = "".join(f"<li>{html.escape(s)}</li>" for s in b.skipped)
    warnings.extend(f"skipped figure: {s}" for s in b.skipped)
    sections = [
        ("Clips that failed", fail_html),
        ("Flagged clips", _flagged(ok, top, rel_s, thumbs)),
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
        f'<p class="counts">{len(clips)} clips: {len(ok)} scored, <span class="warn">{len(failed)} failed</span>, '
        f"{len(reasons)} flagged; "
        f"{ok['model'].nunique()} platforms, {ok['scene_id'].nunique()} scenes.</p>"
        f"{_summary_html(b)}<nav>{nav}</nav>{_interactive_tables(body)}<script>{_SCRIPT}</script></body></html>"
    )
    (stage / "report.html").write_text(page)
    return b, warnings
