"""The reward of one clip: a number where higher is more consistent.

By default (``RewardConfig.reading = "windows"``) the reward is the mean over the clip's windows
of fresh tracks of their soft share (:mod:`.windows`), and the preset's record supplies the
verdict (a clip whose background cannot be judged is not rewarded), the gate's family and the
background readings reported beside it. With ``reading = "pairs"`` it is the mean, over the
record's scored frame pairs, of a soft inlier share: each background match weighs
``1 / (1 + (r / soft_px)^2)``, ``r`` its residual to the model the translation gate chose, movers
masked and matches that move on their own left out (``soft_px`` 0 gives the inlier ratio).
Its interval is a seeded percentile bootstrap over the windows (or pairs). The same frames and
preset give the same reward from memory or from ``geocon score``'s record of them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..config import RewardConfig
from ..record import ClipRecord
from .guards import GuardReading
from .windows import window_values

__all__ = ["RewardResult", "pair_values", "reward_of_record", "bootstrap_mean"]


@dataclass(frozen=True)
class RewardResult:
    """One clip's reward. ``score`` 0..1, higher = more consistent, None when the clip cannot be
    judged (then ``reason`` says why in one sentence and ``guard`` names the guard that tripped,
    or "background" when the scorer could not judge it); ``interval`` its bootstrap interval;
    ``readings`` the numbers behind it (background IR and GE, pairs, the verdict and clip score
    of the preset, the guards' measurements)."""

    name: str
    score: float | None
    interval: tuple[float, float] | None
    judged: bool
    reason: str | None
    guard: str | None
    readings: dict[str, Any] = field(default_factory=dict)
    pair_scores: tuple[float, ...] = ()
    """The reading of each frame pair the score is the mean of (what a margin is read on)."""
    seconds: float = 0.0

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "score": None if self.score is None else round(self.score, 6),
            "interval": None if self.interval is None else [round(v, 6) for v in self.interval],
            "judged": self.judged,
            "reason": self.reason,
            "guard": self.guard,
            "readings": self.readings,
            "pairs": len(self.pair_scores),
            "seconds": round(self.seconds, 3),
        }


def bootstrap_mean(values: np.ndarray, cfg: RewardConfig, seed: int | None = None) -> tuple[float, float]:
    """The percentile bootstrap interval of the mean of ``values`` at ``cfg.level``."""
    rng = np.random.default_rng(cfg.seed if seed is None else seed)
    idx = rng.integers(0, len(values), size=(cfg.bootstrap, len(values)))
    means = values[idx].mean(axis=1)
    a = (1.0 - cfg.level) / 2.0
    return float(np.quantile(means, a)), float(np.quantile(means, 1.0 - a))


def pair_values(record: ClipRecord, soft_px: float = 0.0) -> np.ndarray:
    """Each scored pair's reading (all gaps) under the background's chosen family: with
    ``soft_px`` > 0 the mean over its matches of ``1 / (1 + (r / soft_px)^2)`` (``r`` the match's
    residual: transfer error for H, Sampson distance in px for F; matches that move on their own
    left out, as they are of IR), else its inlier ratio."""
    family = record.background.model
    m = record.matches
    res = m.h_res if family == "H" else m.f_res_px
    own = m.h_ind if family == "H" else m.f_ind
    if own is None:  # MatchArrays fills it in; records always hold one
        own = np.zeros(len(res), bool)
    values = []
    for p in record.pairs:
        fit = p.fit(family) if p.skip is None else None
        if fit is None or not fit.valid or fit.ir is None:
            continue
        if soft_px <= 0.0:
            values.append(fit.ir)
            continue
        lo, hi = int(m.offsets[p.index]), int(m.offsets[p.index + 1])
        kept = res[lo:hi][~own[lo:hi]].astype(np.float64)
        kept = kept[np.isfinite(kept)]
        if len(kept):
            values.append(float(np.mean(1.0 / (1.0 + (kept / soft_px) ** 2))))
    return np.asarray(values, dtype=np.float64)


def reward_of_record(
    record: ClipRecord,
    cfg: RewardConfig,
    guards: GuardReading | None = None,
    name: str | None = None,
    frames: np.ndarray | None = None,
) -> RewardResult:
    """The reward of a scored clip (:class:`RewardResult`); ``guards``, when read, are reported and
    a tripped guard makes the clip cannot judge whatever its geometry. With ``cfg.reading``
    ``windows`` the score reads the sampled BGR ``frames`` the record was scored from
    (:func:`~geocon_core.reward.windows.window_values`, under the record's family); ``pairs``
    reads the record alone."""
    finding = record.finding()
    bg = record.background
    readings: dict[str, Any] = {
        "model": bg.model,
        "ir": bg.ir,
        "ge": bg.ge,
        "verdict": finding.verdict,
        "clip_score": finding.clip_score,
        "valid_pairs": bg.valid_pairs,
        "total_pairs": bg.total_pairs,
    }
    if guards is not None:
        readings["guards"] = guards.to_dict()
    label = name or record.video.path
    if guards is not None and guards.tripped is not None:
        return RewardResult(label, None, None, False, guards.reason, guards.tripped, readings)
    if finding.verdict == "cannot judge":
        return RewardResult(label, None, None, False, finding.reason, "background", readings)
    if cfg.reading == "windows":
        if frames is None:
            raise ValueError("the windows reading needs the frames the record was scored from")
        values = window_values(frames, bg.model, cfg) if bg.model in ("H", "F") else np.zeros(0)
        readings["windows"] = len(values)
    else:
        values = pair_values(record, cfg.soft_px)
    if len(values) == 0:
        reason = (
            "no window keeps enough tracks under a background model"
            if cfg.reading == "windows"
            else "no frame pair has a background model"
        )
        return RewardResult(label, None, None, False, reason, "background", readings)
    score = float(values.mean())
    interval = bootstrap_mean(values, cfg)
    return RewardResult(label, score, interval, True, None, None, readings, tuple(float(v) for v in values))
