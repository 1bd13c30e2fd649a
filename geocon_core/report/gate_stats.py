"""Statistics of the translation gate over a benchmark (SPEC section 6; re-exported by
:mod:`geocon_core.report.stats`): Wilson intervals (defined in :mod:`geocon_core.intervals`),
calibration of P(F | t_inf) in equal-count bins, the net benefit ``(TP - c * FP) / N`` of
"predict F iff t_inf >= tau", and the bootstrap of balanced accuracy over a tau grid. Pure,
seeded functions.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
import pandas as pd

from ..intervals import Interval, wilson_interval

__all__ = [
    "TAU_GRID",
    "Interval",
    "TauBootstrap",
    "wilson_interval",
    "calibration_bins",
    "net_benefit",
    "balanced_accuracy",
    "bootstrap_tau",
]

TAU_GRID = (0.02, 0.03, 0.04, 0.06, 0.08)
"""The tau_t values the bootstrap compares."""
_NAN = float("nan")


def _finite(t_inf, is_f) -> tuple[np.ndarray, np.ndarray]:
    t, y = np.asarray(t_inf, float), np.asarray(is_f, bool)
    keep = np.isfinite(t)
    return t[keep], y[keep]


def calibration_bins(t_inf, is_f, *, K: int = 12, confidence: float = 0.95) -> pd.DataFrame:
    """P(F | t_inf) over ``K`` equal-count bins of the sorted finite t_inf (``np.array_split``)."""
    t, y = _finite(t_inf, is_f)
    order = np.argsort(t, kind="stable")
    rows = []
    for i, idx in enumerate(np.array_split(order, min(K, t.size)) if t.size else []):
        k, n = int(y[idx].sum()), idx.size
        w = wilson_interval(k, n, confidence=confidence)
        rows.append(
            {
                "bin": i,
                "t_low": float(t[idx].min()),
                "t_high": float(t[idx].max()),
                "t_mid": float(np.median(t[idx])),
                "n": n,
                "k": k,
                "p": w.estimate,
                "low": w.low,
                "high": w.high,
            }
        )
    return pd.DataFrame(rows, columns=["bin", "t_low", "t_high", "t_mid", "n", "k", "p", "low", "high"])


def net_benefit(
    t_inf, is_f, taus: Sequence[float] | np.ndarray, *, costs: Sequence[float] = (0.5, 1.0, 2.0)
) -> pd.DataFrame:
    """Net benefit ``(TP - c * FP) / N`` of predicting F iff ``t_inf >= tau``."""
    t, y = _finite(t_inf, is_f)
    rows = []
    for tau in taus:
        pred = t >= tau
        tp, fp = int((pred & y).sum()), int((pred & ~y).sum())
        for c in costs:
            rows.append(
                {
                    "tau": float(tau),
                    "c": float(c),
                    "tp": tp,
                    "fp": fp,
                    "n": t.size,
                    "net_benefit": (tp - c * fp) / t.size if t.size else _NAN,
                }
            )
    return pd.DataFrame(rows, columns=["tau", "c", "tp", "fp", "n", "net_benefit"])


def balanced_accuracy(t_inf, is_f, tau: float) -> float:
    """(TPR + TNR) / 2 of predicting F iff ``t_inf >= tau``; NaN without both classes."""
    t, y = _finite(t_inf, is_f)
    if y.all() or not y.any():
        return _NAN
    pred = t >= tau
    return float((pred[y].mean() + (~pred[~y]).mean()) / 2)


@dataclass(frozen=True, eq=False)
class TauBootstrap:
    """Bootstrap balanced accuracy per tau of ``grid``: mean and 95% percentile interval over the
    replicates, how often each tau was the argmax (ties go to the lowest tau), and the tau with
    the most argmax wins (ties again to the lowest)."""

    grid: tuple[float, ...]
    mean: np.ndarray
    low: np.ndarray
    high: np.ndarray
    argmax_counts: np.ndarray
    best_tau: float
    B: int


def bootstrap_tau(t_inf, is_f, *, grid: Sequence[float] = TAU_GRID, B: int = 400, seed: int = 0) -> TauBootstrap:
    """Resample clips with replacement within each expected class (so both classes stay present)
    and score every tau of ``grid`` by balanced accuracy."""
    t, y = _finite(t_inf, is_f)
    if y.all() or not y.any():
        raise ValueError("the calibration needs clips of both expected classes (H and F)")
    rng = np.random.default_rng(seed)
    pos, neg = t[y], t[~y]
    g = np.asarray(grid, float)
    ba = np.empty((B, g.size))
    for b in range(B):
        p = pos[rng.integers(0, pos.size, pos.size)]
        n = neg[rng.integers(0, neg.size, neg.size)]
        ba[b] = ((p[:, None] >= g).mean(axis=0) + (n[:, None] < g).mean(axis=0)) / 2
    wins = np.bincount(np.argmax(ba, axis=1), minlength=g.size)
    return TauBootstrap(
        tuple(float(v) for v in g),
        ba.mean(axis=0),
        np.quantile(ba, 0.025, axis=0),
        np.quantile(ba, 0.975, axis=0),
        wins,
        float(g[int(np.argmax(wins))]),
        B,
    )
