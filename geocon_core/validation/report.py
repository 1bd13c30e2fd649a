"""A validation run from start to end (:func:`run_validation`) and its written report:
``OUT/validation.md`` (the table, then one line per case) and ``OUT/validation.json`` (the
same, machine-readable)."""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from ..config import ScoreConfig, config_hash
from ..files import commit_together, part_path
from ..intervals import RESAMPLES, SEED
from ..record import RecordError
from ..signals import configured_model
from .cases import Annotation, ValidationPlan, missing_clips, plan_cases, read_annotations, wrong_clips
from .metrics import MetricRow, auc_text, compute_metrics, share_text
from .planted import PlantedSummary, planted_markdown, planted_summary
from .results import CaseResult, case_result
from .runner import Progress, case_folder, named, run_cases

__all__ = [
    "INTERVALS_NOTE",
    "ValidationReport",
    "run_validation",
    "write_report",
    "format_value",
    "metric_cells",
    "REPORT_MD",
    "REPORT_JSON",
]

REPORT_MD = "validation.md"
"""The validation report's Markdown file in the output folder."""
REPORT_JSON = "validation.json"
"""The validation report's JSON file (every metric row) in the output folder."""
INTERVALS_NOTE = (
    f"Brackets hold 95% intervals: for a share, the Wilson score interval; for an AUC, the percentile "
    f"interval of {RESAMPLES} bootstrap resamples of the clips (positives and negatives each drawn with "
    f"replacement, seed {SEED}). Beside the peer, GeoCon - peer is the difference on the same clips, its "
    "interval from the same resamples (paired); where that interval includes 0 the two cannot be told apart "
    "on these clips."
)
"""The sentence under the report's heading that says how its intervals are computed."""


@dataclass(frozen=True)
class ValidationReport:
    """A finished run: the table, one row per case, the preset and its configuration hash, the
    seconds the run took (prepare + score; cases resumed from an earlier run cost nothing), the
    summed scoring seconds of the cases, how many cases the plan has (more than the rows
    when a report is made from an interrupted run), and the planted section (None when the run
    plants nothing, :mod:`.planted`)."""

    metrics: tuple[MetricRow, ...]
    cases: tuple[CaseResult, ...]
    preset: str
    config_hash: str
    seconds: float
    score_seconds: float
    plan: ValidationPlan
    planned: int = 0
    planted: PlantedSummary | None = None
    notes: tuple[str, ...] = ()
    """What the run left out or did again, one sentence each with the count and what to do:
    annotated clips missing from their folder or of other bytes than annotated, cache entries made
    again, cases scored again (or left out) because what was saved for them could not stand for them."""


def format_value(row: MetricRow) -> str:
    """The value cell: a share as a percentage with its 95% Wilson interval and its count, an AUC
    with its 95% bootstrap interval and the clips on each side, an IR difference as a number."""
    if row.value is None:
        return "-"
    if row.metric.startswith("clean IR"):
        return f"{row.value:.3f}"
    if row.metric.startswith("F keeps"):
        return f"{row.value:.2f} ({row.n} clips)"
    if row.metric.startswith("AUC"):
        value = f"{row.value:.2f}" if row.interval is None else auc_text(row.interval)
        return f"{value} ({row.hits} vs {row.n - row.hits})"
    return share_text(row.hits, row.n)


def run_validation(
    plan: ValidationPlan,
    config: ScoreConfig,
    out: str | Path,
    cache: str | Path,
    *,
    jobs: int = 1,
    annotations: dict[str, Annotation] | None = None,
    progress: Progress | None = None,
    score: bool = True,
    peer: bool = True,
) -> ValidationReport:
    """Plan, prepare and score every case of ``plan`` with ``config`` into ``out`` (clips cached
    in ``cache``), compute the table and write the report files. With ``score=False`` the report
    covers only the cases scored by an earlier run (``planned`` says how many there are). With
    ``peer`` every annotated clip is also scored by the peer (:mod:`.peer`) for the AUC rows."""
    start = time.perf_counter()
    out_dir = Path(out)
    configured_model(config.signals)  # the clip model that decides the verdicts, before any work
    cases = plan_cases(plan, annotations)
    notes = _clip_notes(plan, annotations)
    made: set[str] = set()
    scored = run_cases(
        cases,
        plan,
        config,
        out_dir,
        cache,
        jobs=jobs,
        progress=progress,
        score=score,
        peer=peer,
        made=made,
        notes=notes,
    )
    results, unread = [], []
    for c, s in scored:
        try:
            results.append(case_result(s, case_folder(out_dir, c), c))
        except RecordError as exc:  # damaged since it was checked: named, not a traceback
            unread.append(f"{c.case_id}: {str(exc).removesuffix(': score the clip again')}")
    if unread:
        notes.append(
            f"{len(unread)} case(s) are left out of the report, their record unreadable (run again to score them "
            f"anew): {named(unread)}"
        )
    rows = tuple(results)
    report = ValidationReport(
        metrics=tuple(compute_metrics(list(rows))),
        cases=rows,
        preset=config.preset,
        config_hash=config_hash(config),
        seconds=time.perf_counter() - start,
        score_seconds=sum(r.seconds or 0.0 for r in rows),
        plan=plan,
        planned=len(cases),
        planted=planted_summary(rows, cases, plan, Path(cache), made),
        notes=tuple(notes),
    )
    write_report(report, out_dir)
    return report


_WHERE_TO_PUT = {
    "data": "copy them into --data, or give the --data folder that holds them",
    "real2": "copy them into --real2",
    "footage": "fill the footage cache with `geocon footage fill --from DIR` (`geocon footage status` lists them)",
}
"""What to do about annotated clips missing from each root (:data:`~.cases.ROOTS`)."""
_ROOT_WORDS = {"data": "--data", "real2": "--real2", "footage": "the footage cache"}
"""How a sentence names each root."""


def _clip_notes(plan: ValidationPlan, annotations: dict[str, Annotation] | None) -> list[str]:
    """The sentences naming the annotated clips a run cannot score: missing from their root
    (:func:`~.cases.missing_clips`) or of other bytes than annotated (:func:`~.cases.wrong_clips`)."""
    given = {"data": plan.data, "real2": plan.real2, "footage": plan.footage}
    roots = {root: path for root, path in given.items() if path is not None}
    if not roots or not (plan.real or plan.planted):
        return []
    notes_in = annotations if annotations is not None else read_annotations()
    said = []
    missing = missing_clips(plan, notes_in)
    for root in sorted({a.root for a in missing}):
        gone = [a.clip for a in missing if a.root == root]
        said.append(
            f"{len(gone)} annotated clip(s) are not scored: not found in {_ROOT_WORDS[root]} {roots[root]}; "
            f"{_WHERE_TO_PUT[root]}: {named(gone)}"
        )
    wrong = wrong_clips(plan, notes_in)
    if wrong:
        said.append(
            f"{len(wrong)} annotated clip(s) are not scored: their bytes do not hash to the annotated SHA-256, so "
            "they are not the clips the annotations describe; put the annotated files back (`geocon footage "
            f"status` checks the footage cache): {named([str(roots[a.root] / a.clip) for a in wrong])}"
        )
    return said


def _fmt(value: Any, spec: str) -> str:
    return "-" if value is None else format(value, spec)


_CASE_COLUMNS = (
    "case",
    "truth",
    "verdict",
    "clip score",
    "peer",
    "IR",
    "GE",
    "gate",
    "t_inf",
    "pose",
    "objects",
    "max AdaDFRC",
    "category",
)


def _case_cells(r: CaseResult) -> list[str]:
    truth = "/".join(
        x
        for x in (
            r.truth_gate or "gray",
            r.truth_category or "",
            "" if r.truth_movers is None else f"{r.truth_movers} movers",
            f"{r.failure} {r.level}" if r.failure else "",
        )
        if x
    )
    pose = "-" if r.pose_present is None else ("yes" if r.pose_present else "no")
    return [
        r.case_id,
        truth,
        r.verdict if r.error is None else f"failed: {r.error}",
        _fmt(r.clip_score, ".2f"),
        _fmt(r.peer_score, ".2f"),
        _fmt(r.ir, ".3f"),
        _fmt(r.ge, ".2f"),
        r.gate or "-",
        _fmt(r.t_inf, ".4f"),
        pose,
        _fmt(r.objects, "d"),
        _fmt(r.max_adadfrc, ".3f"),
        r.category or "-",
    ]


def _exceptions(cases: tuple[CaseResult, ...]) -> list[str]:
    """Sections listing the clips that should pass and did not (clean synthetic, real camera, the
    clean re-encodes of the planted family), each with the pair where its background fits worst,
    so every exception can be explained;
    then the real-camera clips that could not be judged, with why; then the most confident flags
    of clean-looking generated clips."""
    lines: list[str] = []
    rows = [
        r
        for r in cases
        if (r.clean and r.flagged)
        or (r.kind == "real" and r.source == "real" and r.false_flag)
        or (r.reencode and r.false_flag)
    ]
    if rows:
        lines += ["## Exceptions: clean or real-camera clips called inconsistent", ""]
        lines += _md_table(
            ["case", "set", "verdict", "IR", "GE", "worst pair"],
            [
                [r.case_id, r.group, r.verdict, _fmt(r.ir, ".3f"), _fmt(r.ge, ".2f"), r.worst_pair or r.error or "-"]
                for r in rows
            ],
        )
        lines.append("")
    unjudged = [r for r in cases if r.kind == "real" and r.source == "real" and r.verdict == "not judged"]
    if unjudged:
        lines += ["## Real-camera clips that could not be judged", ""]
        lines += _md_table(["case", "set", "why"], [[r.case_id, r.group, r.verdict_note or "-"] for r in unjudged])
        lines.append("")
    clean_flags = [r for r in cases if r.source == "generated" and not r.artifact and r.verdict == "inconsistent"]
    if clean_flags:
        top = sorted(clean_flags, key=lambda r: r.report_margin if r.report_margin is not None else 0.0)[:5]
        lines += ["## The five most confident flags of clean-looking generated clips", ""]
        lines += _md_table(
            ["case", "set", "margin", "IR", "GE", "gate", "worst pair"],
            [
                [
                    r.case_id,
                    r.group,
                    _fmt(r.report_margin, ".2f"),
                    _fmt(r.ir, ".3f"),
                    _fmt(r.ge, ".2f"),
                    r.gate or "-",
                    r.worst_pair or "-",
                ]
                for r in top
            ],
        )
        lines.append("")
    return lines


def _md_table(header: tuple[str, ...] | list[str], rows: list[list[str]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(c.replace("|", "/") for c in row) + " |" for row in rows]
    return lines


def metric_cells(row: MetricRow) -> list[str]:
    """The cells of one metric row in the report's Markdown table."""
    ok = "-" if row.ok is None else ("yes" if row.ok else "NO")
    return [row.metric, row.subset, format_value(row), row.target, ok, row.detail]


def write_report(report: ValidationReport, out: Path) -> tuple[Path, Path]:
    """Write ``validation.md`` and ``validation.json`` into ``out``, committed together (a failure
    leaves the earlier pair as it was)."""
    out.mkdir(parents=True, exist_ok=True)
    p = report.plan
    planted = (
        f"Planted into the real-camera clips: {', '.join(p.plant_kinds)} at {', '.join(p.plant_levels)}, "
        f"seed {p.seed}. "
        if p.planted
        else ""
    )
    lines = [
        "# GeoCon validation report",
        "",
        f"Preset `{report.preset}` (config {report.config_hash}); synthetic heights {list(p.heights)}, codecs "
        f"{list(p.codecs)}, {p.frames} frames per clip, scene seed {p.seed}; real clips cut to {p.max_frames} frames. "
        f"{planted}{len(report.cases)} of {report.planned} planned cases in {report.seconds:.0f} s "
        f"(scoring {report.score_seconds:.0f} s summed over the cases).",
        "",
        INTERVALS_NOTE,
        "",
        *_md_table(["measure", "set", "value", "target", "met", "detail"], [metric_cells(m) for m in report.metrics]),
        "",
        *(planted_markdown(report.planted) if report.planted is not None else []),
        *_exceptions(report.cases),
        *(["## Left out or done again", "", *[f"- {n}" for n in report.notes], ""] if report.notes else []),
        "## Cases",
        "",
        *_md_table(_CASE_COLUMNS, [_case_cells(r) for r in report.cases]),
        "",
    ]
    md, js = out / REPORT_MD, out / REPORT_JSON
    md_part, js_part = part_path(md), part_path(js)
    plan = {k: (str(v) if isinstance(v, Path) else v) for k, v in asdict(p).items()}
    doc = {
        "format": "geocon-validation/1",
        "preset": report.preset,
        "config_hash": report.config_hash,
        "seconds": round(report.seconds, 1),
        "score_seconds": round(report.score_seconds, 1),
        "planned": report.planned,
        "plan": plan,
        "metrics": [asdict(m) for m in report.metrics],
        "planted": None if report.planted is None else asdict(report.planted),
        "cases": [asdict(r) for r in report.cases],
        "notes": list(report.notes),
    }
    try:
        md_part.write_text("\n".join(lines))
        js_part.write_text(json.dumps(doc, indent=1) + "\n")
    except BaseException:
        md_part.unlink(missing_ok=True)
        js_part.unlink(missing_ok=True)
        raise
    commit_together([(md_part, md), (js_part, js)])  # the table and its data: both or neither
    return md, js
