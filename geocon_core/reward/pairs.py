"""Preference pairs for DPO-style training: rank the clips of each prompt, keep best against worst
when the margin clears the noise.

A manifest is a CSV file with a ``path`` column (a clip: video, GIF or folder of frames, relative
to the manifest's folder or absolute) and a ``group`` column (the prompt, or any id that says
which clips compete; a column named ``prompt`` serves when there is no ``group``). Each clip is
scored once (:class:`~geocon_core.reward.RewardScorer`); its result is appended to a scores
file beside the output as soon as it is known, so a run that stops resumes where it was. Each
group with at least two judged clips gives one pair: its best clip (chosen) against its worst
(rejected), written when the lower end of the margin's interval is above 0 and counted as
"inside the noise" otherwise. A clip that cannot be judged is never chosen; it is listed with its
reason.

A pair's line (JSON): ``group``, ``chosen``, ``rejected`` (paths as the manifest gives them),
``chosen_score``, ``rejected_score``, ``margin`` (their difference), ``margin_interval`` (its
bootstrap interval, each clip's frame pairs resampled), ``preset``, ``config_hash`` (the
scorer's settings) and ``reward_hash`` (the reward's: sampling, guards, reading): the
``chosen`` / ``rejected`` names DPO trainers read.
"""

from __future__ import annotations

import csv
import dataclasses
import hashlib
import json
import os
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..config import RewardConfig, config_hash
from ..media import ClipError
from .api import RewardScorer
from .result import RewardResult

__all__ = [
    "reward_hash",
    "ManifestError",
    "ManifestRow",
    "PairsSummary",
    "read_manifest",
    "margin_interval",
    "write_pairs",
    "decode_clip",
]

SCORES_SUFFIX = ".scores.jsonl"
"""The scores file beside a pairs file (``pairs.jsonl`` -> ``pairs.scores.jsonl``)."""
MAX_FRAMES_READ = 2000
"""A clip file longer than this is refused (a training sample is seconds long)."""


class ManifestError(ValueError):
    """A manifest that cannot be read; the message is one sentence."""


@dataclass(frozen=True)
class ManifestRow:
    path: str
    """As the manifest gives it."""
    resolved: Path
    group: str


@dataclass
class PairsSummary:
    """What a run of :func:`write_pairs` did."""

    clips: int = 0
    scored: int = 0
    resumed: int = 0
    groups: int = 0
    pairs: int = 0
    in_noise: int = 0
    small_groups: int = 0
    unjudged: list[tuple[str, str]] = field(default_factory=list)


def read_manifest(path: str | Path) -> list[ManifestRow]:
    """The rows of a manifest; raises :class:`ManifestError` with one sentence when it cannot be used."""
    p = Path(path)
    if not p.is_file():
        raise ManifestError(f"{p}: no such manifest file (a CSV with columns path and group)")
    try:
        with p.open(newline="", encoding="utf-8-sig") as fh:
            reader = csv.DictReader(fh)
            columns = [c.strip().lower() for c in reader.fieldnames or []]
            rows = list(reader)
    except (UnicodeDecodeError, csv.Error) as err:
        raise ManifestError(f"{p}: not a readable CSV file ({err})") from None
    if "path" not in columns:
        raise ManifestError(f"{p}: no 'path' column (columns: {', '.join(columns) or 'none'}); give each clip's path")
    group_col = "group" if "group" in columns else "prompt" if "prompt" in columns else None
    if group_col is None:
        raise ManifestError(
            f"{p}: no 'group' (or 'prompt') column saying which clips compete (columns: {', '.join(columns)})"
        )
    out: list[ManifestRow] = []
    seen: set[str] = set()
    for line, raw in enumerate(rows, start=2):
        row = {(k or "").strip().lower(): (v or "").strip() for k, v in raw.items()}
        clip, group = row.get("path", ""), row.get(group_col, "")
        if not clip:
            raise ManifestError(f"{p}: line {line} has no path")
        if not group:
            raise ManifestError(f"{p}: line {line} ({clip}) has no {group_col}")
        resolved = Path(clip) if os.path.isabs(clip) else p.parent / clip
        if not resolved.exists():
            raise ManifestError(
                f"{p}: line {line}: {clip} does not exist (paths are relative to the manifest's folder)"
            )
        if clip in seen:
            raise ManifestError(f"{p}: line {line}: {clip} is listed twice")
        seen.add(clip)
        out.append(ManifestRow(clip, resolved, group))
    if not out:
        raise ManifestError(f"{p}: the manifest lists no clip")
    return out


def reward_hash(cfg: RewardConfig) -> str:
    """First 16 hex digits of the SHA-256 of the reward settings' canonical JSON."""
    text = json.dumps(dataclasses.asdict(cfg), sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def decode_clip(path: Path) -> np.ndarray:
    """The clip's frames as decoded, (T, h, w, 3) uint8 BGR (at most :data:`MAX_FRAMES_READ`)."""
    from ..media import source_frames

    frames = list(source_frames(path, MAX_FRAMES_READ + 1))
    if len(frames) > MAX_FRAMES_READ:
        raise ClipError(f"{path}: more than {MAX_FRAMES_READ} frames; cut a training sample's length")
    if len(frames) < 2:
        raise ClipError(f"{path}: has {len(frames)} frame{'s' if len(frames) != 1 else ''}; at least 2 are needed")
    if len({f.shape for f in frames}) > 1:
        raise ClipError(f"{path}: its frames differ in size")
    return np.stack(frames)


def margin_interval(a: RewardResult, b: RewardResult, cfg: RewardConfig) -> tuple[float, float]:
    """The bootstrap interval of ``a.score - b.score``: each clip's frame pairs resampled on
    their own (seeded), at ``cfg.level``."""
    rng = np.random.default_rng(cfg.seed)
    va, vb = np.asarray(a.pair_scores), np.asarray(b.pair_scores)
    ma = va[rng.integers(0, len(va), size=(cfg.bootstrap, len(va)))].mean(axis=1)
    mb = vb[rng.integers(0, len(vb), size=(cfg.bootstrap, len(vb)))].mean(axis=1)
    q = (1.0 - cfg.level) / 2.0
    d = ma - mb
    return float(np.quantile(d, q)), float(np.quantile(d, 1.0 - q))


def _saved(scores: Path, key: str) -> Iterator[dict[str, Any]]:
    if not scores.is_file():
        return
    with scores.open(encoding="utf-8") as fh:
        for line in fh:
            try:
                row = json.loads(line)
            except ValueError:
                continue  # a line cut short when a run stopped: scored again
            if isinstance(row, dict) and row.get("key") == key and isinstance(row.get("path"), str):
                yield row


def _result(row: dict[str, Any]) -> RewardResult:
    interval = row.get("interval")
    return RewardResult(
        row["path"],
        row.get("score"),
        None if interval is None else (float(interval[0]), float(interval[1])),
        bool(row.get("judged")),
        row.get("reason"),
        row.get("guard"),
        row.get("readings") or {},
        tuple(float(v) for v in row.get("pair_scores") or ()),
        float(row.get("seconds") or 0.0),
    )


def write_pairs(
    manifest: str | Path,
    out: str | Path,
    scorer: RewardScorer | None = None,
    *,
    resume: bool = True,
    progress: Callable[[int, int], None] | None = None,
) -> PairsSummary:
    """Score every clip of ``manifest`` and write the preference pairs to ``out`` (JSONL, written
    whole at the end); scores go to ``out``'s scores file as they come (:data:`SCORES_SUFFIX`) and
    are reused by a later run with the same settings when ``resume``."""
    rows = read_manifest(manifest)
    scorer = scorer or RewardScorer()
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    scores = out.with_name(out.name.removesuffix(".jsonl") + SCORES_SUFFIX)
    key = f"{config_hash(scorer.config)}:{reward_hash(scorer.reward)}"
    summary = PairsSummary(clips=len(rows))
    done: dict[str, RewardResult] = {}
    if resume:
        done = {r["path"]: _result(r) for r in _saved(scores, key)}
    elif scores.exists():
        scores.unlink()
    wanted = {r.path for r in rows}
    summary.resumed = len(wanted & done.keys())
    todo = [r for r in rows if r.path not in done]

    def one(row: ManifestRow) -> RewardResult:
        try:
            return scorer.score(decode_clip(row.resolved), name=row.path, channel_order="bgr")
        except ClipError as err:
            return RewardResult(row.path, None, None, False, str(err), "frames")

    with scores.open("a", encoding="utf-8") as fh, ThreadPoolExecutor(max_workers=scorer.workers) as pool:
        futures = {pool.submit(one, row): row for row in todo}
        for i, future in enumerate(as_completed(futures), 1):
            row, result = futures[future], future.result()
            line = {"key": key, "path": row.path, **result.to_dict(), "pair_scores": list(result.pair_scores)}
            fh.write(json.dumps(line) + "\n")  # as each clip finishes: a stopped run loses none
            fh.flush()
            done[row.path] = result
            summary.scored += 1
            if progress is not None:
                progress(i, len(todo))
    groups: dict[str, list[ManifestRow]] = {}
    for row in rows:
        groups.setdefault(row.group, []).append(row)
    summary.groups = len(groups)
    lines = []
    for group, members in groups.items():
        judged = [done[m.path] for m in members if done[m.path].judged and done[m.path].score is not None]
        summary.unjudged += [(m.path, done[m.path].reason or "") for m in members if not done[m.path].judged]
        if len(judged) < 2:
            summary.small_groups += 1
            continue
        ranked = sorted(judged, key=lambda r: (-(r.score or 0.0), r.name))
        best, worst = ranked[0], ranked[-1]
        lo, hi = margin_interval(best, worst, scorer.reward)
        if lo <= 0.0:
            summary.in_noise += 1
            continue
        lines.append(
            {
                "group": group,
                "chosen": best.name,
                "rejected": worst.name,
                "chosen_score": round(best.score or 0.0, 6),
                "rejected_score": round(worst.score or 0.0, 6),
                "margin": round((best.score or 0.0) - (worst.score or 0.0), 6),
                "margin_interval": [round(lo, 6), round(hi, 6)],
                "preset": scorer.config.preset,
                "config_hash": config_hash(scorer.config),
                "reward_hash": reward_hash(scorer.reward),
            }
        )
    tmp = out.with_name(out.name + ".part")
    tmp.write_text("".join(json.dumps(line) + "\n" for line in lines), encoding="utf-8")
    os.replace(tmp, out)
    summary.pairs = len(lines)
    return summary
