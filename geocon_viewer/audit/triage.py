"""The texts of the audit app's side panel: the triage summary and table, the thresholds note and
the recording note. Markdown from the results index; no viser needed."""

from __future__ import annotations

import math
from pathlib import Path

from geocon_core.results import BROKEN, TriageRow
from geocon_core.scoring import Thresholds

from ..shared import EMPTY, fmt

__all__ = ["LIST_ROWS", "THRESHOLD_LABELS", "triage_summary", "triage_table", "thresholds_text", "rrd_text"]

LIST_ROWS = 12
"""Rows of the triage table shown at once (the clip picker holds all of them)."""
STATE_MARK = {"fails": "FAIL", "not judged": "n/j", "error": "ERROR", "passes": "ok"}
THRESHOLD_LABELS = {
    "tau_h": ("tau_H (px)", 0.05, "Symmetric transfer error threshold of the homography."),
    "tau_f": ("tau_F", 0.005, "Normalised Sampson threshold of the fundamental matrix."),
    "ir_gate": ("IR gate", 0.005, "Report gate: a clip passes when IR >= this ..."),
    "ge_gate": ("GE gate (px)", 0.1, "... and GE <= this (px)."),
    "tau_t_low": ("gate low", 0.005, "Hysteresis gate: H when t_inf <= this."),
    "tau_t_high": ("gate high", 0.005, "Hysteresis gate: F when t_inf >= this; U in between."),
    "tau_t_window": (
        "gate window",
        0.005,
        "An H clip whose gate window reads t_inf above this is in the gray zone (0: off).",
    ),
    "untrusted_share": (
        "untrusted share",
        0.05,
        "A failing background with at least this share of matches moving on their own is not judged (0: off).",
    ),
}
"""Per threshold: its label, the step of its input and its hint."""


def triage_summary(rows: list[TriageRow], counts: dict[str, int], total: int) -> str:
    """How many clips are listed, by verdict."""
    parts = ", ".join(f"{k} {v}" for k, v in counts.items() if v)
    shown = f"{len(rows)} of {total} clips" if len(rows) != total else f"{total} clips"
    return f"{shown} — {parts or 'none'}"


def triage_table(rows: list[TriageRow], page_value: int, selected: str | None) -> str:
    """Page ``page_value`` of the triage list as a markdown table (``selected`` in bold)."""
    pages = max(1, math.ceil(len(rows) / LIST_ROWS))
    page = min(max(1, page_value), pages)
    start = (page - 1) * LIST_ROWS
    lines = ["| # | clip | plat. | cat | gate | IR | GE | |", "|---|---|---|---|---|---|---|---|"]
    for i, r in enumerate(rows[start : start + LIST_ROWS], start=start + 1):
        v = r.verdict
        gate = EMPTY if v is None else f"{v.label}→{v.model}" + ("≠" if r.gate_mismatch else "")
        name = r.clip_id if len(r.clip_id) <= 28 else r.clip_id[:12] + "…" + r.clip_id[-14:]
        if r.clip_id == selected:
            name = f"**{name}**"
        ir = fmt(None if v is None else v.ir)
        ge = fmt(None if v is None else v.ge, ".2f")
        category = r.clip.category or EMPTY
        mark = "BROKEN" if r.clip.status == BROKEN else STATE_MARK[r.state]  # a record that cannot be read
        lines.append(f"| {i} | {name} | {r.clip.platform} | {category} | {gate} | {ir} | {ge} | {mark} |")
    if not rows:
        lines.append("| | no clip matches the filters | | | | | | |")
    return "\n".join(lines) + f"\n\npage {page} of {pages} · ≠: gate differs from the category's expected model"


def thresholds_text(thresholds: Thresholds, recorded: Thresholds, config_hash: str | None) -> str:
    """Whether the thresholds differ from the recorded ones, and which."""
    changed = thresholds.changed(recorded)
    if not changed:
        return "All thresholds as recorded" + (f" (config `{config_hash}`)." if config_hash else ".")
    text = "**Differs from the recorded config:** " + ", ".join(
        f"{THRESHOLD_LABELS[k][0]} {now:g} (recorded {old:g})" for k, (old, now) in changed.items()
    )
    return text + ". Scores are re-gated from the stored residuals (models not re-fitted)."


def rrd_text(folder: Path) -> str:
    """The note about the clip's Rerun recording beside its record."""
    rrd = folder / "audit.rrd"
    if rrd.is_file():
        return f"recording: `{rrd}` ({rrd.stat().st_size / 1e6:.1f} MB); open it with `rerun {rrd.name}`"
    return "no recording yet"
