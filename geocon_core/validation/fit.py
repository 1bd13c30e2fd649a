"""``geocon validate --fit``: the clip model fitted on the tune half of the annotated clips.

The records of a validation's annotated real-camera and generated clips (its ``cases`` folder)
hold the background fit; the readings the clip model also reads (:mod:`geocon_core.signals`) are
read from each clip again where a record lacks them (kept beside it as ``readings.json``, keyed by
the record and the readings' settings), so a fit needs no new scoring. The model is fitted on the
tune half only (:func:`~geocon_core.signals.fit_clip_model`): clips with a geometric artifact
against clean-looking generated clips and real-camera clips; clips with only other artifacts
(watermarks, flicker) are left out. Both halves are then reported: the AUC of the fitted score
against the peer's on the same clips (paired), and the flag rates at the model's threshold.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..config import ScoreConfig
from ..files import ANNOTATIONS, SMALL_STATE, ReadRefused, read_bytes, read_text
from ..intervals import Interval, auc_interval, paired_auc_difference, wilson_interval
from ..record import ClipFinding, model_finding
from ..signals import READING_LABELS, ClipModel, fit_clip_model
from .cases import ANNOTATIONS_PATH, Annotation
from .results import peer_score

if TYPE_CHECKING:
    from ..record import ClipRecord
    from ..signals import ClipReadings

__all__ = [
    "FIT_TERMS",
    "FITTED_GROUPS",
    "READINGS_FILE",
    "FitCase",
    "FitRow",
    "FitReport",
    "fit_cases",
    "fit_model",
    "fit_markdown",
    "model_json",
    "case_readings",
    "stored_readings",
]

FITTED_GROUPS: tuple[str, ...] = ("artifact", "clean", "real")
"""The kinds of clips the model is fitted on (planted cases and their re-encodes are reported only)."""

READINGS_FILE = "readings.json"
"""A case's readings read again from its clip (:func:`case_readings`)."""

FIT_TERMS: tuple[str, ...] = (
    "shortfall",
    "unkept",
    "flow_failure",
    "interior_failure",
    "unexplained_appearance",
    "mover_share",
    "mv_residual",
    "object_rigidity",
)
"""The readings a fit may weigh (:data:`~geocon_core.signals.READING_LABELS`); the monotone fit
leaves a reading that does not help at weight 0."""


@dataclass(frozen=True)
class FitCase:
    """One annotated clip of the fit: its readings, its half, what it is (``broken``: a geometric
    artifact; ``real``: a real-camera clip; else clean-looking generated) and the peer's score."""

    case_id: str
    split: str
    broken: bool
    real: bool
    values: dict[str, float | None]
    peer: float | None
    before: float | None
    """The background's own clip score (the clip score before the clip model)."""
    group: str = ""
    """``artifact``, ``clean`` (clean-looking generated), ``real``, ``planted:KIND`` or ``reencode``
    (a planted case's clean re-encode)."""
    drift: str | None = None
    """The multi-view check's drifting layer where it found one (the record's
    :meth:`~geocon_core.record.ClipRecord.drift_finding`), else None."""


@dataclass(frozen=True)
class FitRow:
    """One half's figures for the fitted model: AUC (geometric artifact vs clean-looking generated)
    of the model, of the record's previous score and of the peer, the paired difference to the
    peer, and the flag rates at the model's threshold."""

    split: str
    auc: Interval | None
    before: Interval | None
    peer: Interval | None
    difference: Interval | None
    broken_flagged: tuple[int, int]
    clean_flagged: tuple[int, int]
    real_flagged: tuple[int, int]
    planted: tuple[tuple[str, tuple[int, int], Interval | None], ...] = ()
    """Per planted kind: planted clips flagged, and the AUC of planted against clean re-encodes."""
    reencode_flagged: tuple[int, int] = (0, 0)
    """The planted cases' clean re-encodes flagged."""


@dataclass(frozen=True)
class FitReport:
    """A fitted clip model with its figures on the tune and the check half, over ``cases`` clips."""

    model: ClipModel
    rows: tuple[FitRow, ...]
    cases: int


_NOT_READINGS = ("enabled", "model", "model_sha256", "decisive_shortfall", "drift_fails_with_background")
"""Settings of ``signals`` that change no reading (the verdict's, not the readings')."""


def _signals_key(cfg: ScoreConfig) -> str:
    d = {k: v for k, v in asdict(cfg.signals).items() if k not in _NOT_READINGS}
    return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()[:12]


def stored_readings(folder: Path, rec: ClipRecord, cfg: ScoreConfig) -> ClipReadings:
    """The readings ``cfg.signals`` makes of the record ``rec`` stored in ``folder``: its own when it
    has them, else read from its clip again (:func:`~geocon_core.scoring.read_readings`) and kept in
    :data:`READINGS_FILE`, keyed by the record and the readings' settings, so that the next call
    reads the file."""
    from ..files import part_path, replace_file
    from ..scoring import read_readings
    from ..signals import ClipReadings

    if rec.readings is not None:
        return rec.readings
    key = {"record_id": rec.record_id, "signals": _signals_key(cfg)}
    saved = folder / READINGS_FILE
    try:
        data = json.loads(read_text(saved, SMALL_STATE))
        if data.get("key") == key:
            return ClipReadings.from_json_dict(data["readings"])
    except (OSError, ValueError, KeyError, TypeError):
        pass
    readings = read_readings(rec, folder, cfg).readings
    assert readings is not None
    part = part_path(saved)
    part.write_text(json.dumps({"key": key, "readings": readings.to_json_dict()}, indent=1) + "\n")
    replace_file(part, saved)
    return readings


def case_readings(folder: Path, cfg: ScoreConfig) -> tuple[dict[str, float | None], float | None, str | None]:
    """The readings of the case in ``folder`` (:meth:`~geocon_core.record.ClipRecord.reading_values`,
    :func:`stored_readings`), the record's own background clip score and its drifting layer."""
    from dataclasses import replace

    from ..record import read_record

    rec = read_record(folder)
    before = rec.background_finding().clip_score
    return replace(rec, readings=stored_readings(folder, rec, cfg)).reading_values(), before, rec.drift_finding()


def _source_note(case: dict[str, Any], by_clip: dict[tuple[str, str], Annotation]) -> Annotation | None:
    """The annotation of a case's clip (of its source, for a planted case)."""
    ann = case.get("annotation")
    if not isinstance(ann, dict):
        return None
    return by_clip.get((str(ann.get("root", "")), str(ann.get("clip", ""))))


def _case_status(folder: Path, problems: list[str]) -> dict[str, Any] | None:
    """The ``case.json`` of a case folder, with its case (a JSON object naming the folder's case);
    None when there is none (not scored) or, with a line in ``problems``, when it is damaged or
    another case's."""
    try:
        status = json.loads(read_text(folder / "case.json", SMALL_STATE))  # a regular file within its bound
    except ReadRefused as exc:
        if exc.reason == "missing":
            return None
        problems.append(f"{folder.name}: its case.json cannot be read ({exc.why})")
        return None
    except (OSError, ValueError) as exc:
        problems.append(f"{folder.name}: its case.json cannot be read ({type(exc).__name__})")
        return None
    case = status.get("case") if isinstance(status, dict) else None
    named_id = case.get("case_id") if isinstance(case, dict) else None
    if named_id != folder.name:
        problems.append(f"{folder.name}: its case.json is not this case's (it names {named_id!r})")
        return None
    return status


def fit_cases(
    cases_dir: Path,
    annotations: dict[str, Annotation],
    cfg: ScoreConfig,
    progress: Callable[[int, int], None] | None = None,
    *,
    level: str = "middle",
) -> tuple[list[FitCase], list[str]]:
    """The annotated clips and the planted cases (at severity ``level``, with their clean
    re-encodes) scored in ``cases_dir`` (one folder per case, as ``geocon validate`` writes them)
    with their readings, and one line per case that could not be read."""
    by_clip = {(a.root, a.clip): a for a in annotations.values()}
    folders: list[tuple[Path, Annotation, str]] = []
    problems: list[str] = []
    for folder in sorted(p for p in cases_dir.iterdir() if p.is_dir()):
        status = _case_status(folder, problems)
        case = {} if status is None else status["case"]
        if status is None or status.get("status") != "ok" or case.get("kind") not in ("real", "planted"):
            continue
        note = _source_note(case, by_clip)
        if note is None or note.exclude:
            continue
        if case["kind"] == "planted":
            if case.get("level") not in (None, level):
                continue
            group = f"planted:{case['failure']}" if case.get("failure") else "reencode"
        elif note.source != "generated":
            group = "real"
        elif note.geometric_artifact:
            group = "artifact"
        elif not note.visible_artifact:
            group = "clean"
        else:
            continue  # only non-geometric artifacts: neither broken nor clean
        folders.append((folder, note, group))
    out: list[FitCase] = []
    for i, (folder, note, group) in enumerate(folders):
        try:
            values, before, drift = case_readings(folder, cfg)
        except (OSError, ValueError) as exc:
            problems.append(f"{folder.name}: {exc}")
        else:
            broken = group == "artifact" or group.startswith("planted:")
            real = group in ("real", "reencode") or group.startswith("planted:")
            case = FitCase(folder.name, note.split, broken, real, values, peer_score(folder), before, group, drift)
            out.append(case)
        if progress is not None:
            progress(i + 1, len(folders))
    return out, problems


def _half(model: ClipModel, cases: list[FitCase], split: str, decisive: float, with_drift: bool) -> FitRow:
    rows = [c for c in cases if c.split == split]
    group = {name: [c for c in rows if c.group == name] for name in ("artifact", "clean", "real", "reencode")}
    broken, clean = group["artifact"], group["clean"]

    def finding(c: FitCase) -> float | None:
        """The clip score the record's verdict reads (:func:`~geocon_core.record.finding.model_finding`:
        the model's, the background's where it fails decisively), None when the clip cannot be judged."""
        background = ClipFinding("cannot judge" if c.before is None else "judged", "", c.before)
        return model_finding(background, c.values, model, decisive, c.drift if with_drift else None).clip_score

    def nz(v: float | None) -> float:
        return 0.5 if v is None else v

    def score(c: FitCase) -> float:
        """The clip score, a clip that cannot be judged at 0.5 (as the validation report counts it)."""
        return nz(finding(c))

    auc = before = peer = diff = None
    if broken and clean:
        ours = ([score(c) for c in broken], [score(c) for c in clean])
        theirs = ([nz(c.peer) for c in broken], [nz(c.peer) for c in clean])
        auc = auc_interval(*ours)
        before = auc_interval([nz(c.before) for c in broken], [nz(c.before) for c in clean])
        peer = auc_interval(*theirs)
        diff = paired_auc_difference(*ours, *theirs)

    def flagged(members: list[FitCase]) -> tuple[int, int]:
        scores = [finding(c) for c in members]
        return sum(v is not None and v >= model.threshold for v in scores), len(members)

    planted = []
    for kind in sorted({c.group.split(":", 1)[1] for c in rows if c.group.startswith("planted:")}):
        members = [c for c in rows if c.group == f"planted:{kind}"]
        auc_kind = None
        if group["reencode"]:
            auc_kind = auc_interval([score(c) for c in members], [score(c) for c in group["reencode"]])
        planted.append((kind, flagged(members), auc_kind))
    return FitRow(
        split,
        auc,
        before,
        peer,
        diff,
        flagged(broken),
        flagged(clean),
        flagged(group["real"]),
        tuple(planted),
        flagged(group["reencode"]),
    )


def fit_model(
    cases: list[FitCase],
    *,
    l2: float = 1.0,
    real_false_flags: float = 0.05,
    decisive_shortfall: float = math.inf,
    drift_fails_with_background: bool = False,
    version: str,
    annotations_path: Path = ANNOTATIONS_PATH,
    terms: Iterable[str] = FIT_TERMS,
) -> FitReport:
    """The clip model fitted on the tune half of ``cases``, reported on both halves with the
    verdict's rules (a background failing by more than ``decisive_shortfall`` fails the clip; with
    ``drift_fails_with_background``, so does a drifting layer beside a failing background)."""
    # planted cases are reported, not fitted: no reading sees the planted morph, redraw or slide
    # (AUC about 0.5 against their clean re-encodes), and fitted beside the annotated clips they
    # only add noise to the broken class (measured: tune AUC 0.72 -> 0.68, artifacts flagged 64% -> 22%)
    tune = [c for c in cases if c.split == "tune" and c.group in FITTED_GROUPS]
    digest = hashlib.sha256(
        read_bytes(annotations_path, ANNOTATIONS, f"annotation file {annotations_path}")
    ).hexdigest()[:12]
    model = fit_clip_model(
        [c.values for c in tune],
        [c.broken for c in tune],
        [c.group for c in tune],
        [c.group == "real" for c in tune],
        [(t, READING_LABELS[t]) for t in terms],
        l2=l2,
        real_false_flags=real_false_flags,
        version=version,
        fitted={"split": "tune", "annotations_sha256": digest},
    )
    rows = tuple(
        _half(model, cases, half, decisive_shortfall, drift_fails_with_background) for half in ("tune", "check")
    )
    return FitReport(model, rows, len(cases))


def _iv(iv: Interval | None, signed: bool = False) -> str:
    if iv is None:
        return "-"
    f = "{:+.2f}" if signed else "{:.2f}"
    return f"{f.format(iv.estimate)} [{f.format(iv.low)}, {f.format(iv.high)}]"


def _rate(hits: tuple[int, int]) -> str:
    k, n = hits
    if not n:
        return "-"
    iv = wilson_interval(k, n)
    return f"{k}/{n} = {k / n:.0%} [{iv.low:.0%}, {iv.high:.0%}]"


def fit_markdown(report: FitReport) -> str:
    """The fit as a markdown page: the model's terms and both halves' figures."""
    m = report.model
    lines = [
        f"# Clip model {m.version} (fitted on the tune half)",
        "",
        f"Intercept {m.intercept:+.3f}; verdict threshold {m.threshold:.3f} (at most "
        f"{m.fitted.get('real_false_flags', 0.05):.0%} of the tune half's real-camera clips at or above it); "
        f"digest {m.digest()}.",
        "",
        "| reading | center | scale | weight |",
        "| --- | ---: | ---: | ---: |",
        *[f"| {t.label} (`{t.name}`) | {t.center:.4g} | {t.scale:.4g} | {t.weight:.3f} |" for t in m.terms],
        "",
        "| half | AUC, geometric artifact vs clean-looking | before | peer | difference to the peer | "
        "artifacts flagged | clean-looking flagged | real cameras flagged |",
        "| --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for r in report.rows:
        lines.append(
            f"| {r.split} | {_iv(r.auc)} | {_iv(r.before)} | {_iv(r.peer)} | {_iv(r.difference, True)} | "
            f"{_rate(r.broken_flagged)} | {_rate(r.clean_flagged)} | {_rate(r.real_flagged)} |"
        )
    planted = [(r.split, kind, hits, iv) for r in report.rows for kind, hits, iv in r.planted]
    if planted:
        lines += [
            "",
            "| half | planted kind | flagged | AUC against the clean re-encodes | clean re-encodes flagged |",
            "| --- | --- | --- | --- | --- |",
        ]
        again = {r.split: r.reencode_flagged for r in report.rows}
        lines += [f"| {h} | {k} | {_rate(n)} | {_iv(iv)} | {_rate(again[h])} |" for h, k, n, iv in planted]
    lines += [
        "",
        "AUC intervals: seeded stratified bootstrap over clips; the difference is paired (the same clips "
        "and resamples); rates: Wilson 95% intervals. Rules were chosen on the tune half only.",
    ]
    return "\n".join(lines) + "\n"


def model_json(model: ClipModel) -> str:
    """The model file's text (``clip_model.json``)."""
    return json.dumps(model.to_dict(), indent=1) + "\n"
