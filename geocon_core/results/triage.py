"""A results folder as a triage list: every clip with the numbers an inspector sorts and filters
by, re-gated live at other thresholds, and ordered by severity.

Reads what ``geocon bench`` writes (``RESULTS/bench.json``, ``clips/*/status.json``, and
``tables/clips.parquet`` when it is up to date, for speed) or a single ``geocon score --out`` folder
(one ``record.json``). Nothing is re-scored: at other thresholds the clips are re-gated from their
stored residuals (:func:`geocon_core.scoring.regate.regate_clip`), which are loaded on first need and kept.

>>> index = ResultsIndex.open("results")                    # doctest: +SKIP
>>> th = index.recorded.__class__(**{**index.recorded.__dict__, "tau_h": 3.0})  # doctest: +SKIP
>>> [c.clip_id for c in index.triage(th)[:5]]                # doctest: +SKIP
"""

from __future__ import annotations

import json
import math
import shlex
import threading
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable, Iterable

from ..bench import BENCH_FORMAT, MANIFEST_NAME, clip_folders, read_manifest, read_status
from ..config import ScoreConfig
from ..files import ReadRefused
from ..geometry import family_spec
from ..record import RecordError, read_record_json
from ..scoring import (
    ClipVerdict,
    Residuals,
    Scores,
    Thresholds,
    family_verdict,
    is_flagged,
    load_residuals,
    regate_clip,
    regate_family,
    with_drift,
)
from .clips import ResultClip, _failed_clip, clip_from_record_json, read_bench_clips

__all__ = ["ResultClip", "TriageRow", "ResultsIndex", "ResultsError", "VERDICTS", "BROKEN", "severity_key"]

VERDICTS = ("fails", "not judged", "error", "passes")
"""Verdict names of the triage list, most severe first."""


BROKEN = "broken"
"""The status of a clip that was scored but whose saved record (``record.json`` or ``matches.npz``)
cannot be read; its ``error`` says why. Listed like a clip that failed to score (verdict None)."""


class ResultsError(ValueError):
    """A folder that is neither benchmark results nor a record, or a clip whose record cannot be
    read (one sentence)."""


_RECORD_FAULTS = (RecordError, KeyError, TypeError, ValueError, IndexError, AttributeError)
"""What reading a record that is corrupt, truncated or lacks fields raises (see :func:`_unreadable`)."""


def _unreadable(folder: Path, exc: BaseException) -> str:
    """The sentence for a record in ``folder`` that could not be read (``exc`` one of
    :data:`_RECORD_FAULTS`)."""
    if isinstance(exc, RecordError):
        return str(exc)
    return f"{folder / 'record.json'} is not a readable GeoCon record ({type(exc).__name__}: {exc})"


def _read_clips_listing_broken(root: Path) -> list[ResultClip]:
    """Every clip of a bench results folder as :func:`read_bench_clips` lists it, each record read
    on its own, so that one that cannot be read is listed as :data:`BROKEN` with the reason
    instead of failing the whole list."""
    clips = []
    for folder in clip_folders(root):
        status = read_status(folder)
        if status is None:
            continue  # in flight or never started
        cid = status["clip_id"]
        if status["status"] != "ok":
            clips.append(_failed_clip(cid, status, folder))
            continue
        try:
            clips.append(clip_from_record_json(cid, status, folder))
        except _RECORD_FAULTS as exc:
            clips.append(replace(_failed_clip(cid, status, folder), status=BROKEN, error=_unreadable(folder, exc)))
    return clips


@dataclass(frozen=True)
class TriageRow:
    """A clip with its verdict under the thresholds of the moment (None for a clip that failed to
    score) and its severity verdict name (see :data:`VERDICTS`)."""

    clip: ResultClip
    verdict: ClipVerdict | None

    @property
    def clip_id(self) -> str:
        return self.clip.clip_id

    @property
    def state(self) -> str:
        """The severity verdict (:data:`VERDICTS`): the clip model's where it decides the clip
        (:attr:`ResultClip.finding`), else the report gate's at the thresholds of the moment."""
        if self.verdict is None:
            return "error"
        if self.clip.finding is not None:
            return {"consistent": "passes", "inconsistent": "fails"}.get(self.clip.finding, "not judged")
        return {True: "passes", False: "fails", None: "not judged"}[self.verdict.consistent]

    @property
    def gate_mismatch(self) -> bool:
        """The gate chose another family than the clip's expected one (sidecar category)."""
        return (
            self.verdict is not None
            and self.clip.expected_model is not None
            and self.verdict.model != self.clip.expected_model
        )

    @property
    def flagged(self) -> bool:
        """Worth an audit under the thresholds of the moment (:func:`~geocon_core.scoring.verdict.is_flagged`;
        a clip that failed to score is flagged)."""
        v = self.verdict
        return is_flagged(
            consistent=None if v is None else v.consistent,
            pose_present=self.clip.pose_present,
            gate_model=None if v is None else v.model,
            expected_model=self.clip.expected_model,
            finding=self.clip.finding,
        )


def _none_last(v: float | None, *, descending: bool = False) -> float:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return math.inf
    return -v if descending else v


def severity_key(row: TriageRow) -> tuple:
    """Most severe first: clips failing the report gate (deepest below it first), then unjudged and
    unscorable clips, then passing clips (least headroom first); where the clip model decides, its
    verdict ranks and its clip score orders (highest first); ties by the translation gate's margin
    (no pose first, then closest to its threshold), then by the worst object's AdaP90 (largest
    first), then by clip id."""
    v = row.verdict
    rank = VERDICTS.index(row.state)
    if v is None:
        return (rank, 0.0, 0.0, 0.0, row.clip_id)
    margin = -math.inf if v.margin is None else v.margin
    depth = _none_last(v.report_margin)
    if row.clip.finding is not None:
        depth = _none_last(row.clip.clip_score, descending=True)
    return (rank, depth, margin, _none_last(row.clip.adap90_max, descending=True), row.clip_id)


class ResultsIndex:
    """Every clip of a results folder, the thresholds it was scored with (``recorded``), and lazily
    loaded residuals for live re-gating (:meth:`triage`, :meth:`verdict`)."""

    def __init__(
        self, root: Path, clips: list[ResultClip], config: ScoreConfig, config_hash: str | None, kind: str
    ) -> None:
        self.root = root
        self.clips = clips
        self.by_id = {c.clip_id: c for c in clips}
        self.config = config
        self.config_hash = config_hash
        self.kind = kind
        self.recorded = Thresholds.of(config)
        self._residuals: dict[str, Residuals] = {}
        self._families: dict[tuple[str, str, float], tuple[float | None, float | None]] = {}
        self._lock = threading.Lock()

    # --- opening -------------------------------------------------------------------------------
    @classmethod
    def open(cls, path: str | Path) -> "ResultsIndex":
        """A ``geocon bench`` results folder, or one record folder (``geocon score --out``)."""
        root = Path(path)
        if not root.exists():
            raise ResultsError(
                f"{root} does not exist: give a results folder from `geocon bench` or a record folder from `geocon "
                "score`"
            )
        if root.is_file() and root.name == "record.json":
            root = root.parent
        elif not root.is_dir():
            raise ResultsError(
                f"{root} is a file, not a folder: give a results folder from `geocon bench` or a record folder from "
                f"`geocon score --out` (a clip opens with `geocon view {shlex.quote(str(root))}`)"
            )
        if (root / MANIFEST_NAME).exists():  # a FIFO or a device in its place is refused, naming it
            return cls._open_bench(root)
        if (root / "record.json").exists():  # a FIFO or a device in its place is refused, naming it
            status = {"meta": {"model": "-", "category": None}, "rrd": None}
            try:
                _, d = read_record_json(root)
                clip = clip_from_record_json(root.name, status, root, d)
                config = ScoreConfig.from_dict(d["config"])
            except _RECORD_FAULTS as exc:  # not JSON, too large, another format, missing fields
                raise ResultsError(_unreadable(root, exc)) from None
            return cls(root, [clip], config, d.get("config_hash"), "record")
        raise ResultsError(
            f"{root} holds neither bench.json (from `geocon bench`) nor record.json (from `geocon score --out`)"
        )

    @classmethod
    def _open_bench(cls, root: Path) -> "ResultsIndex":
        try:
            manifest = read_manifest(root)
        except json.JSONDecodeError:
            raise ResultsError(f"{root / MANIFEST_NAME} is not valid JSON") from None
        except ReadRefused as exc:  # a FIFO, a device, past its bound, not UTF-8
            raise ResultsError(str(exc)) from None
        if manifest.get("format") != BENCH_FORMAT:
            raise ResultsError(
                f"{root / MANIFEST_NAME} is not a GeoCon benchmark manifest (format {manifest.get('format')!r})"
            )
        try:
            clips = read_bench_clips(root)
        except _RECORD_FAULTS:  # a record read because the tables are out of date is unreadable
            clips = _read_clips_listing_broken(root)
        return cls(root, clips, ScoreConfig.from_dict(manifest["config"]), manifest.get("config_hash"), "bench")

    # --- facets --------------------------------------------------------------------------------
    def facets(self) -> dict[str, list[str]]:
        """The values each filter can take, sorted."""
        return {
            "platform": sorted({c.platform for c in self.clips}),
            "category": sorted({c.category for c in self.clips if c.category}),
        }

    # --- re-gating -----------------------------------------------------------------------------
    def residuals(self, clip_id: str) -> Residuals:
        """The clip's stored residuals (read once, then kept)."""
        with self._lock:
            res = self._residuals.get(clip_id)
        if res is None:
            clip = self.by_id[clip_id]
            if clip.folder is None or clip.status != "ok":
                raise ResultsError(f"{clip_id} has no readable record: {clip.error}")
            try:
                res = load_residuals(clip.folder).prepare()
            except _RECORD_FAULTS as exc:
                raise ResultsError(self.mark_broken(clip_id, _unreadable(clip.folder, exc)).error) from None
            with self._lock:
                self._residuals[clip_id] = res
        return res

    def mark_broken(self, clip_id: str, reason: str) -> ResultClip:
        """List ``clip_id`` as :data:`BROKEN` from now on (its saved record turned out unreadable:
        ``reason``, one sentence naming the file) and forget what was read of it. Returns the
        clip as now listed."""
        with self._lock:
            clip = replace(self.by_id[clip_id], status=BROKEN, error=reason)
            self.by_id[clip_id] = clip
            self.clips = [clip if c.clip_id == clip_id else c for c in self.clips]  # a new list: safe to iterate
            self._residuals.pop(clip_id, None)
            self._families = {k: v for k, v in self._families.items() if k[0] != clip_id}
        return clip

    def loaded(self) -> int:
        """How many clips' residuals are in memory."""
        with self._lock:
            return len(self._residuals)

    def preload(self, progress: Callable[[int, int], None] | None = None, stop: threading.Event | None = None) -> None:
        """Read every clip's residuals (for a background thread, so later re-gating is fast). A clip
        whose record cannot be read is listed as :data:`BROKEN` (:meth:`mark_broken`) and the
        preload goes on."""
        ok = [c for c in self.clips if c.status == "ok"]
        for i, c in enumerate(ok):
            if stop is not None and stop.is_set():
                return
            try:
                self.residuals(c.clip_id)
            except ResultsError:
                pass  # now listed as broken, with the reason
            if progress is not None:
                progress(i + 1, len(ok))

    def _family(self, clip: ResultClip, family: str, tau: float) -> tuple[float | None, float | None]:
        if tau == self.recorded.tau(family):
            return clip.scores(family)
        key = (clip.clip_id, family, float(tau))
        with self._lock:
            hit = self._families.get(key)
        if hit is None:
            r = regate_family(self.residuals(clip.clip_id), family_spec(family).name, tau)
            hit = (r.ir, r.ge)
            with self._lock:
                self._families[key] = hit
        return hit

    def verdict(self, clip_id: str, thresholds: Thresholds) -> ClipVerdict | None:
        """The clip's verdict at ``thresholds`` (None for a clip that failed to score). At the
        recorded residual thresholds the recorded values are used; otherwise the clip is re-gated
        from its residuals, exactly as :func:`~geocon_core.scoring.regate.regate_clip` does."""
        clip = self.by_id[clip_id]
        if clip.status != "ok":
            return None
        try:
            if clip.shots:  # judged shot by shot: each shot's own gate and pairs
                return regate_clip(self.residuals(clip.clip_id), thresholds)
            h, f = (Scores(*self._family(clip, fam, thresholds.tau(fam)), clip.moved(fam)) for fam in ("H", "F"))
        except ResultsError:  # its record turned out unreadable: listed as broken from now on
            return None
        return with_drift(
            family_verdict(
                h, f, t_inf=clip.t_inf, pose_present=clip.pose_present, thresholds=thresholds, t_window=clip.t_window
            ),
            clip.drift,
        )

    def triage(
        self,
        thresholds: Thresholds | None = None,
        *,
        platform: str | None = None,
        category: str | None = None,
        gate_label: str | None = None,
        state: str | None = None,
        flagged_only: bool = False,
    ) -> list[TriageRow]:
        """The clips passing the filters (None = any), most severe first (:func:`severity_key`).
        ``gate_label`` filters on the hysteresis label (H/F/U) at ``thresholds``; ``state`` on the
        verdict name (:data:`VERDICTS`); ``flagged_only`` keeps the clips worth an audit
        (:attr:`TriageRow.flagged`)."""
        th = thresholds or self.recorded
        rows = []
        for c in self.clips:
            if (platform is not None and c.platform != platform) or (category is not None and c.category != category):
                continue
            verdict = self.verdict(c.clip_id, th)
            row = TriageRow(self.by_id[c.clip_id], verdict)  # as listed now (it may have turned out broken)
            if gate_label is not None and (row.verdict is None or row.verdict.label != gate_label):
                continue
            if state is not None and row.state != state:
                continue
            if flagged_only and not row.flagged:
                continue
            rows.append(row)
        rows.sort(key=severity_key)
        return rows

    def counts(self, rows: Iterable[TriageRow]) -> dict[str, int]:
        """How many of ``rows`` are in each verdict."""
        out = {name: 0 for name in VERDICTS}
        for r in rows:
            out[r.state] += 1
        return out
