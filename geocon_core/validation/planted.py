"""The planted failures of a validation run (``geocon validate --planted``): failures planted into
real-camera clips (:mod:`geocon_core.plant`) beside a clean re-encode of each source made the same
way, so the planted damage is the only difference between the two.

Per kind, severity and set (``../shared/data``, the tune half, the check half, all of them):

- **detection**: the share of planted clips called inconsistent (as for the synthetic failures,
  :func:`~.metrics.detected`), with its Wilson interval;
- **false flags of the clean re-encodes** of the same sources: called inconsistent or not scored
  (as for real-camera clips, :attr:`~.results.CaseResult.false_flag`), with its Wilson interval;
- **AUC**: how well the clip score ranks the planted clips above the clean re-encodes of the same
  sources (higher = more broken), with its stratified bootstrap interval, the peer's on the same
  clips and the paired difference GeoCon - peer (the same resamples, read as the generated clips'
  AUC rows are);
  the detail adds the pairing by scene: how many planted clips score above their own re-encode.

Per set, the clean re-encodes' false flags beside those of the originals (the real clips scored as
they are), on the sources where both were scored, with the paired difference.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

from ..files import SMALL_STATE, read_text
from ..intervals import Interval, paired_rate_difference, wilson_interval
from .cases import PLANT_LEVELS, CaseSpec, ValidationPlan
from .metrics import MIN_COMPARE, _auc_row, auc_text, difference_text, share_text
from .results import CaseResult

__all__ = [
    "PLANTED_SETS",
    "PlantedRow",
    "ReencodeRow",
    "PlantedCache",
    "PlantedSummary",
    "planted_rows",
    "reencode_rows",
    "planted_cache",
    "planted_summary",
    "planted_cells",
    "PLANTED_COLUMNS",
    "planted_markdown",
    "cache_line",
    "PLANTED_NOTE",
]

PLANTED_SETS: tuple[tuple[str, str], ...] = (
    ("data", "../shared/data"),
    ("tune", "tune half"),
    ("check", "check half"),
    ("all", "all sets"),
)
"""The sets the planted rows are reported in: each set of the real clips (a planted clip is in its
source's set, :data:`~.metrics.REAL_GROUPS`), then all of them together (only when more than one
set has planted clips)."""

PLANTED_COLUMNS: tuple[str, ...] = (
    "kind",
    "severity",
    "set",
    "detection, GeoCon",
    "false flags, clean re-encodes",
    "AUC clip score",
    "AUC peer",
    "detail",
)
"""The columns of the planted table (:func:`planted_cells`); the detail opens with GeoCon - peer,
the paired difference of the two AUCs with its interval, in words."""


@dataclass(frozen=True)
class PlantedRow:
    """One kind at one severity in one set. ``n`` planted clips, ``detected`` of them called
    inconsistent (``detection``: the share with its Wilson interval); ``clean_n`` clean re-encodes
    of the same sources, ``clean_flags`` of them false flags (``false_flags``); ``auc`` the clip
    score's AUC of the planted clips against those re-encodes (bootstrap interval), ``peer_auc``
    the peer's and ``difference`` GeoCon - peer on the same resamples (None without a peer score
    or a side); ``own_pairs`` planted clips whose own re-encode was scored, ``above_own`` and
    ``peer_above_own`` how many of them score above it (GeoCon, the peer); ``detail`` in words."""

    kind: str
    level: str
    amplitude: float | None
    group: str
    subset: str
    n: int
    detected: int
    detection: Interval | None
    clean_n: int
    clean_flags: int
    false_flags: Interval | None
    auc: Interval | None
    peer_auc: Interval | None
    difference: Interval | None
    own_pairs: int
    above_own: int
    peer_above_own: int | None
    detail: str = ""


@dataclass(frozen=True)
class ReencodeRow:
    """One set: the ``n`` sources whose clean re-encode and original were both scored,
    ``reencode_flags`` and ``original_flags`` false flags among them (each with its Wilson
    interval), and the paired difference re-encode - original (bootstrap over the sources)."""

    group: str
    subset: str
    n: int
    reencode_flags: int
    original_flags: int
    reencode: Interval
    original: Interval
    difference: Interval
    detail: str


@dataclass(frozen=True)
class PlantedCache:
    """How the planted clips of a run were made: rendered by this run (with the seconds it took,
    summed over them) or reused from the cache, for the planted clips and the clean re-encodes."""

    rendered: int = 0
    reused: int = 0
    clean_rendered: int = 0
    clean_reused: int = 0
    render_seconds: float = 0.0


@dataclass(frozen=True)
class PlantedSummary:
    """The planted section of a report: the rows per kind, severity and set, the re-encode lines
    per set, and how the clips were made."""

    rows: tuple[PlantedRow, ...]
    reencodes: tuple[ReencodeRow, ...]
    cache: PlantedCache


def _in(group: str) -> Callable[[CaseResult], bool]:
    return lambda r: group == "all" or r.group == group


def _sets(rows: list[CaseResult]) -> list[tuple[str, str]]:
    """The sets of :data:`PLANTED_SETS` that ``rows`` fall in, with ``all`` when there are several."""
    present = [(g, name) for g, name in PLANTED_SETS if g != "all" and any(r.group == g for r in rows)]
    return present + [PLANTED_SETS[-1]] if len(present) > 1 else present


def _score(v: float | None) -> float:
    return 0.5 if v is None else v


def _above_own(planted: list[CaseResult], own: dict[str | None, CaseResult], field: str) -> int:
    return sum(_score(getattr(r, field)) > _score(getattr(own[r.scene], field)) for r in planted if r.scene in own)


def planted_rows(rows: Iterable[CaseResult]) -> list[PlantedRow]:
    """The planted table: one row per kind, severity and set (:data:`PLANTED_SETS`) with planted
    clips, in kind, severity and set order."""
    rows = list(rows)
    planted = [r for r in rows if r.planted]
    reencodes = [r for r in rows if r.reencode]
    kinds = list(dict.fromkeys(r.failure for r in planted))
    levels = list(dict.fromkeys(r.level for r in planted))
    out = []
    for kind in kinds:
        for level in sorted(levels, key=lambda v: PLANT_LEVELS.index(str(v))):
            for group, name in _sets(planted):
                these = [r for r in planted if r.failure == kind and r.level == level and _in(group)(r)]
                if not these:
                    continue
                out.append(_planted_row(str(kind), str(level), group, name, these, reencodes))
    return out


def _planted_row(
    kind: str, level: str, group: str, name: str, planted: list[CaseResult], reencodes: list[CaseResult]
) -> PlantedRow:
    scenes = {r.scene for r in planted}
    clean = [r for r in reencodes if r.scene in scenes]
    hits = sum(r.verdict == "inconsistent" for r in planted)
    flags = sum(r.false_flag for r in clean)
    pos = [r for r in planted if r.verdict != "failed"]
    neg = [r for r in clean if r.verdict != "failed"]
    auc = _auc_row("planted vs clean re-encode", group, name, pos, neg)
    own = {r.scene: r for r in neg}
    paired = [r for r in pos if r.scene in own]
    with_peer = auc.peer is not None
    above = _above_own(paired, own, "clip_score")
    peer_above = _above_own(paired, own, "peer_score") if with_peer else None
    notes = []
    if auc.difference is not None:
        few = f"{len(pos)} vs {len(neg)}" if min(len(pos), len(neg)) < MIN_COMPARE else None
        notes.append(difference_text(auc.difference, points=False, more="separates these clips better", few=few))
        missing = sum(r.peer_score is None for r in pos + neg)
        notes += [f"{missing} clips without a peer score counted at 0.5"] if missing else []
    elif pos and neg:
        notes.append("no peer score")
    if auc.second_peer is not None and auc.second_difference is not None:
        notes.append(f"Epipolar-DPO {auc_text(auc.second_peer)}")
        better = "separates these clips better"
        notes.append(difference_text(auc.second_difference, points=False, more=better, peer="Epipolar-DPO"))
    judged = sum(r.clip_score is None for r in pos + neg)
    notes += [f"{judged} not judged counted at 0.5"] if judged else []
    if paired:
        mine = f"planted clip scored above its own clean re-encode: GeoCon {above}/{len(paired)}"
        mine += f", peer {peer_above}/{len(paired)}" if peer_above is not None else ""
        if auc.second_peer is not None:
            mine += f", Epipolar-DPO {_above_own(paired, own, 'epipolar_score')}/{len(paired)}"
        notes.append(mine)
    failed = sum(r.verdict == "failed" for r in planted + clean)
    notes += [f"{failed} not scored (listed under Cases)"] if failed else []
    return PlantedRow(
        kind=kind,
        level=level,
        amplitude=planted[0].severity,
        group=group,
        subset=name,
        n=len(planted),
        detected=hits,
        detection=wilson_interval(hits, len(planted)),
        clean_n=len(clean),
        clean_flags=flags,
        false_flags=wilson_interval(flags, len(clean)) if clean else None,
        auc=auc.interval,
        peer_auc=auc.peer,
        difference=auc.difference,
        own_pairs=len(paired),
        above_own=above,
        peer_above_own=peer_above,
        detail="; ".join(notes),
    )


def _points(v: float) -> str:
    return f"{int(round(100 * v)):+d}"


def reencode_rows(rows: Iterable[CaseResult]) -> list[ReencodeRow]:
    """Per set (:data:`PLANTED_SETS`), the clean re-encodes' false flags beside the originals'
    (the real clips as they are), over the sources where both were scored."""
    rows = list(rows)
    originals: dict[str | None, CaseResult] = {
        r.scene: r for r in rows if r.kind == "real" and r.scene is not None and r.verdict != "failed"
    }
    reencodes = [r for r in rows if r.reencode and r.verdict != "failed" and r.scene in originals]
    out = []
    for group, name in _sets(reencodes):
        these = [r for r in reencodes if _in(group)(r)]
        if not these:
            continue
        ours = [r.false_flag for r in these]
        theirs = [originals[r.scene].false_flag for r in these]
        diff = paired_rate_difference(ours, theirs)
        head = (
            f"clean re-encodes {share_text(sum(ours), len(ours))}, originals {share_text(sum(theirs), len(theirs))}; "
            f"re-encode - original {_points(diff.estimate)} points [{_points(diff.low)}, {_points(diff.high)}]"
        )
        if len(these) < MIN_COMPARE:
            tail = f"too few clips ({len(these)}) to tell the two apart"
        elif diff.low <= 0.0 <= diff.high:
            tail = "the interval includes 0, so the two cannot be told apart on these clips"
        else:
            more = "more" if diff.low > 0.0 else "less"
            tail = f"the interval excludes 0, the clean re-encodes are flagged {more} often than the originals"
        out.append(
            ReencodeRow(
                group,
                name,
                len(these),
                sum(ours),
                sum(theirs),
                wilson_interval(sum(ours), len(ours)),
                wilson_interval(sum(theirs), len(theirs)),
                diff,
                f"{head}: {tail}",
            )
        )
    return out


def planted_cache(cases: Iterable[CaseSpec], plan: ValidationPlan, cache: Path, made: set[str]) -> PlantedCache:
    """How the planted clips (and the clean re-encodes) of ``cases`` were made: rendered by this
    run (their cache keys are in ``made``, :func:`~.runner.run_cases`) or found in ``cache``."""
    from .prepare import prepare_key

    keys: dict[bool, set[str]] = {True: set(), False: set()}
    for case in cases:
        if case.kind == "planted":  # a planted key does not read the renderer's code digest
            keys[case.failure is None].add(prepare_key(case, plan, ""))
    counts: dict[str, int] = {}
    seconds = 0.0
    for clean, name in ((False, ""), (True, "clean_")):
        rendered = keys[clean] & made
        counts[f"{name}rendered"] = len(rendered)
        counts[f"{name}reused"] = sum((cache / k / "done.json").is_file() for k in keys[clean] - made)
        for key in rendered:
            try:
                seconds += float(json.loads(read_text(cache / key / "done.json", SMALL_STATE)).get("seconds", 0.0))
            except (OSError, ValueError):
                pass
    return PlantedCache(render_seconds=seconds, **counts)


def planted_summary(
    rows: Iterable[CaseResult], cases: Iterable[CaseSpec], plan: ValidationPlan, cache: Path, made: set[str]
) -> PlantedSummary | None:
    """The planted section of a run (None when it planned no planted case)."""
    cases = list(cases)
    if not any(c.kind == "planted" for c in cases):
        return None
    rows = list(rows)
    return PlantedSummary(
        tuple(planted_rows(rows)), tuple(reencode_rows(rows)), planted_cache(cases, plan, cache, made)
    )


def _severity(row: PlantedRow) -> str:
    if row.amplitude is None:
        return row.level
    unit = "weight " if row.kind == "redraw" else ""
    return f"{row.level} ({unit}{row.amplitude:g}{'' if unit else ' px'})"


def planted_cells(row: PlantedRow) -> list[str]:
    """The cells of one planted row (:data:`PLANTED_COLUMNS`)."""
    return [
        row.kind,
        _severity(row),
        row.subset,
        share_text(row.detected, row.n),
        share_text(row.clean_flags, row.clean_n),
        "-" if row.auc is None else f"{auc_text(row.auc)} ({row.n} vs {row.clean_n})",
        "-" if row.peer_auc is None else auc_text(row.peer_auc),
        row.detail,
    ]


def cache_line(cache: PlantedCache) -> str:
    """The planted clips rendered and reused, in words."""
    seconds = (
        f" ({cache.render_seconds:.0f} s of rendering, summed over the clips rendered)"
        if cache.rendered + cache.clean_rendered
        else ""
    )
    return (
        f"Planted clips: {cache.rendered} rendered in this run, {cache.reused} reused from the cache; clean "
        f"re-encodes: {cache.clean_rendered} rendered, {cache.clean_reused} reused{seconds}."
    )


PLANTED_NOTE = (
    "Detection: planted clips called inconsistent. False flags: the clean re-encodes of the same sources "
    "called inconsistent or not scored. AUC: the clip score (and the peer's 1 - keep rate) of the planted clips "
    "against the clean re-encodes of the same sources, planted above clean = 1; a clip that cannot be judged counts "
    "0.5. GeoCon - peer (the detail): the paired difference of the two AUCs on the same resamples."
)
"""How to read the planted table, under its heading."""


def planted_markdown(summary: PlantedSummary) -> list[str]:
    """The report's "Planted failures" section, as Markdown lines."""
    lines = ["## Planted failures", "", cache_line(summary.cache), "", PLANTED_NOTE, ""]
    if summary.rows:
        lines.append("| " + " | ".join(PLANTED_COLUMNS) + " |")
        lines.append("|" + "|".join("---" for _ in PLANTED_COLUMNS) + "|")
        lines += ["| " + " | ".join(c.replace("|", "/") for c in planted_cells(r)) + " |" for r in summary.rows]
        lines.append("")
    if summary.reencodes:
        lines += ["Clean re-encodes against the originals (false flags, sources where both were scored):", ""]
        lines += [f"- {r.subset}: {r.detail}" for r in summary.reencodes]
        lines.append("")
    return lines
