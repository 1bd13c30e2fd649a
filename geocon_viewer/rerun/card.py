"""The audit card of a recording (markdown) and the frame a viewer opens at: plain text from the
record, no Rerun needed."""

from __future__ import annotations

from typing import Callable

import rerun as rr

from geocon_core.record import ClipRecord

from ..shared import fmt
from .dense import dense_legend_markdown

__all__ = [
    "audit_card",
    "evidence",
    "reading_tab",
    "rerun_picture",
    "why_lines",
    "worst_frame",
    "PICTURE_ELSEWHERE",
    "RERUN_VERSION",
]

RERUN_VERSION: str = rr.__version__


def worst_frame(record: ClipRecord) -> int:
    """The first frame of the worst gap-1 pair at the largest scale under the chosen family
    (lowest IR; an unjudged pair counts as worst), where an inspector should look first."""
    s, fam = max(record.config.scales), record.background.model
    worst, key = 0, None
    for p in record.pairs:
        if p.gap != 1 or p.scale != s or p.skip is not None:
            continue
        f = p.fit(fam)
        k = -1.0 if f is None or f.ir is None else f.ir
        if key is None or k < key:
            worst, key = p.t0, k
    return worst


def evidence(record: ClipRecord) -> tuple[str | None, int | None]:
    """What a flagged clip opens on: (the reading map the clip score leans on most, the frame where
    that reading is strongest), or (None, the frame of the worst background pair) when the
    background decided; (None, None) for a clip that is not flagged."""
    from geocon_core.signals import leading_picture

    finding = record.finding()
    if finding.verdict != "inconsistent":
        return None, None
    picture = leading_picture(finding.parts)
    a = record.readings.appearance if record.readings is not None else None
    if picture is None or a is None or a.maps is None:
        return None, worst_frame(record)
    field_of = {"failure": "interior", "movers": "movers", "unexplained": "census"}[picture[1]]
    strongest = max(
        (p for p in a.pairs if getattr(p, field_of) is not None), key=lambda p: getattr(p, field_of), default=None
    )
    return picture[1], None if strongest is None else strongest.t0


def reading_tab(name: str) -> str:
    """The title of the recording's tab that shows map ``name`` (:data:`~geocon_core.signals.MAP_VIEWS`)."""
    from geocon_core.signals import MAP_VIEWS

    title = MAP_VIEWS[name].title
    return title[0].upper() + title[1:]


PICTURE_ELSEWHERE: dict[str, str] = {
    "shortfall": "*Frame + background matches*, *Residual map*",
    "unkept": "*Frame + background matches* (red: outliers)",
    "mv_residual": "*Frame + background matches* (multi-view tracks)",
    "object_rigidity": "*Object flow + AdaDFRC cells*",
}
"""The recording's views that show a reading without a map of its own."""


def rerun_picture(name: str) -> str:
    """Where the recording shows reading ``name``: its map's tab, or the view of
    :data:`PICTURE_ELSEWHERE`."""
    from geocon_core.signals import picture_of

    tab = picture_of(name)
    return f"tab *{reading_tab(tab)}*" if tab is not None else PICTURE_ELSEWHERE.get(name, "")


def why_lines(record: ClipRecord, look: Callable[[str], str] | None = rerun_picture) -> list[str]:
    """The "why this score" table: the clip model's contributions in markdown (empty when the score
    is the background's own), each with where to look at it (``look(reading)``; no column when None)."""
    from geocon_core.signals import READING_LABELS

    finding = record.finding()
    if not finding.parts:
        return []
    values = record.reading_values()
    head = "| why this score: reading | value | contribution to the log-odds |"
    rows = [
        f"| {READING_LABELS.get(name, name)} | {fmt(values.get(name), '.3g')} | {part:+.2f} |"
        + ("" if look is None else f" {look(name)} |")
        for name, part in finding.parts
    ]
    if look is None:
        return ["", head, "|---|---|---|", *rows]
    return ["", head + " where to look |", "|---|---|---|---|", *rows]


def audit_card(record: ClipRecord) -> str:
    """The clip's audit card in markdown: verdict, gate rationale with its inputs, thresholds,
    coverage, objects, configuration and versions."""
    g, bg, cfg = record.gate, record.background, record.config
    verdict = {True: "consistent", False: "INCONSISTENT", None: "not judged"}[bg.consistent]
    v = record.video
    reasons = ", ".join(f"{k}: {n}" for k, n in bg.chosen.invalid_reasons.items()) or "none"
    category = record.category.label if record.category else "n/a"
    th = g.thresholds
    finding = record.finding()
    lines = [
        f"# {record.clip.rsplit('/', 1)[-1]}",
        "",
        f"**Finding: {finding.verdict}** (clip score {fmt(finding.clip_score, '.2f')}, 0 sound .. 1 broken): "
        f"{finding.reason}",
        *([] if record.model_note() is None else ["", f"⚠ This record was {record.model_note()}."]),
        *why_lines(record),
        "",
        f"**Verdict: background {verdict}** — model {bg.model}, IR {fmt(bg.ir, '.3f')} (gate >= {cfg.ir_gate:g}), "
        f"GE {fmt(bg.ge, '.2f', ' px')} (gate <= {cfg.ge_gate:g} px); category **{category}**.",
        "",
        "## Translation gate",
        f"- label **{g.label}** (binary {g.binary_label}), model used **{g.model}**, backend `{g.backend}`",
        f"- t_inf {fmt(g.t_inf, '.4f')}, margin {fmt(g.margin, '+.4f')}; thresholds: low {th['low']:g} / "
        f"high {th['high']:g} (binary {th['tau_t']:g})",
        f"- pose: method {g.pose.method}, {g.pose.n_inliers} of {g.pose.n_matches} matches, rotation "
        f"{fmt(g.pose.rotation_deg, '.2f', ' deg')}, parallax {fmt(g.pose.parallax_px, '.2f', ' px')}"
        + ("" if g.pose_present else f"; no pose ({g.pose.reason}): fail -> F"),
        f"- {bg.choice_note}",
        "",
        "## Background",
        f"- residual rules: H symmetric transfer error <= {cfg.tau_h:g} px; F normalised Sampson <= {cfg.tau_f:g} "
        f"(~{fmt(bg.tau_f_px, '.2f', ' px')} at the largest scale)",
        f"- valid pairs {bg.valid_pairs} of {bg.total_pairs}; invalid: {reasons}",
        f"- other family {bg.other.family}: IR {fmt(bg.other.ir, '.3f')}, GE {fmt(bg.other.ge, '.2f', ' px')}",
        "",
        "| gap | IR | GE (px) | valid |",
        "|---|---|---|---|",
        *[
            f"| {gs.gap} | {fmt(gs.ir, '.3f')} | {fmt(gs.ge, '.2f')} | {gs.valid_pairs}/{gs.total_pairs} |"
            for gs in bg.chosen.per_gap
        ],
        "",
        "## Coverage",
        f"- {v.num_frames} frames at {v.fps} fps, working size {list(v.working_size)}, "
        f"content box {list(v.content_box)}",
        f"- duplicated frames {len(v.duplicates)}, hard cuts {len(v.cuts)}; masks: {record.masks_source}",
    ]
    lines += dense_legend_markdown(record)
    if record.objects:
        lines += [
            "",
            "## Objects",
            "",
            "| id | frames | AdaDFRC (px^2) | W2 | AdaP90 | masked share |",
            "|---|---|---|---|---|---|",
        ]
        lines += [
            f"| {o.object_id} | {o.frames} | {fmt(o.adadfrc, '.3g')} | {fmt(o.adadfrc_w2, '.3g')} | "
            f"{fmt(o.adap90, '.3g')} | {o.masked_share:.3f} |"
            for o in record.objects
        ]
    if record.warnings:
        lines += ["", "## Warnings", *[f"- {w}" for w in record.warnings]]
    versions = ", ".join(f"{k} {val}" for k, val in record.versions.items())
    lines += [
        "",
        "## Configuration",
        f"- preset `{cfg.preset}`, config hash `{record.config_hash}`, scales {list(cfg.scales)}, "
        f"gaps {list(cfg.gaps)}, matcher {cfg.matcher}",
        f"- versions: {versions}; rerun {RERUN_VERSION}",
        f"- this recording was written with Rerun {RERUN_VERSION}: open it with a viewer of the same version "
        f"(`pip install rerun-sdk=={RERUN_VERSION}`, then `rerun FILE.rrd`).",
    ]
    return "\n".join(lines) + "\n"
