"""AUCs over clips, their seeded stratified bootstrap, and paired differences of two scores or
two yes/no outcomes measured on the same clips (see :mod:`geocon_core.intervals`)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .shares import CONFIDENCE, Interval

__all__ = [
    "RESAMPLES",
    "SEED",
    "mann_whitney_auc",
    "bootstrap_aucs",
    "percentile_interval",
    "auc_interval",
    "paired_auc_difference",
    "paired_rate_difference",
]

RESAMPLES = 2000
"""Bootstrap replicates per interval."""
SEED = 0
"""The bootstrap's seed: the same clips and scores give the same interval."""


def _multiplicities(rng: np.random.Generator, n: int, resamples: int) -> np.ndarray:
    """How often each of ``n`` units is drawn in each of ``resamples`` draws of ``n`` with
    replacement: an integer array (resamples, n) whose rows sum to ``n``."""
    idx = rng.integers(0, n, size=(resamples, n))
    flat = (idx + n * np.arange(resamples)[:, None]).ravel()
    return np.bincount(flat, minlength=resamples * n).reshape(resamples, n)


def _as_columns(scores: Sequence[float] | np.ndarray) -> np.ndarray:
    a = np.asarray(scores, dtype=float)
    return a[:, None] if a.ndim == 1 else a


def _ranks(pos: np.ndarray, neg: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The order that sorts ``neg``, and per positive how many negatives lie strictly below it
    and how many below or tied (the Mann-Whitney counts)."""
    order = np.argsort(neg, kind="stable")
    sorted_neg = neg[order]
    return order, np.searchsorted(sorted_neg, pos, side="left"), np.searchsorted(sorted_neg, pos, side="right")


def mann_whitney_auc(pos: Sequence[float] | np.ndarray, neg: Sequence[float] | np.ndarray) -> float:
    """AUC of a score (higher meaning positive): the share of (positive, negative) pairs in which
    the positive scores higher, ties counting half (``U / (n_pos n_neg)``). Both sides must be
    non-empty."""
    p, q = np.asarray(pos, dtype=float), np.asarray(neg, dtype=float)
    if not p.size or not q.size:
        raise ValueError("an AUC needs at least one positive and one negative")
    _, below, upto = _ranks(p, q)
    return float((below + upto).sum()) / (2 * p.size * q.size)


def bootstrap_aucs(
    pos: Sequence[float] | np.ndarray,
    neg: Sequence[float] | np.ndarray,
    *,
    resamples: int = RESAMPLES,
    seed: int = SEED,
) -> tuple[np.ndarray, np.ndarray]:
    """AUC of each score (column) of ``pos`` (n_pos, S) against ``neg`` (n_neg, S), higher
    meaning positive: on the sample (shape (S,)) and on each stratified replicate (shape
    (resamples, S)). Row i of ``pos`` is one clip under every score, so all scores are read on the
    same draws of clips: ``numpy.random.default_rng(seed)`` draws the positives' indices
    (resamples, n_pos), then the negatives' (resamples, n_neg). A 1-D ``pos`` / ``neg`` is one
    score. Both sides must be non-empty and finite."""
    p, q = _as_columns(pos), _as_columns(neg)
    if p.shape[0] == 0 or q.shape[0] == 0:
        raise ValueError("an AUC needs at least one positive and one negative")
    if p.shape[1] != q.shape[1]:
        raise ValueError(f"positives and negatives must have the same scores, got {p.shape[1]} and {q.shape[1]}")
    if not (np.isfinite(p).all() and np.isfinite(q).all()):
        raise ValueError("scores must be finite")
    rng = np.random.default_rng(seed)
    wp = _multiplicities(rng, p.shape[0], resamples)
    wq = _multiplicities(rng, q.shape[0], resamples)
    pairs = p.shape[0] * q.shape[0]
    sample = np.empty(p.shape[1])
    boot = np.empty((resamples, p.shape[1]))
    for s in range(p.shape[1]):
        order, below, upto = _ranks(p[:, s], q[:, s])
        sample[s] = float((below + upto).sum()) / (2 * pairs)
        cum = np.zeros((resamples, q.shape[0] + 1))
        np.cumsum(wq[:, order], axis=1, out=cum[:, 1:])
        wins = cum[:, below] + cum[:, upto]  # twice the weighted wins of each positive
        boot[:, s] = (wp * wins).sum(axis=1) / (2 * pairs)
    return sample, boot


def percentile_interval(estimate: float, replicates: np.ndarray, n: int, *, confidence: float = CONFIDENCE) -> Interval:
    """``estimate`` with the percentile interval of its bootstrap ``replicates``."""
    a = (1 - confidence) / 2
    low, high = np.quantile(replicates, [a, 1 - a])
    return Interval(float(estimate), float(low), float(high), int(n))


def auc_interval(
    pos: Sequence[float] | np.ndarray,
    neg: Sequence[float] | np.ndarray,
    *,
    resamples: int = RESAMPLES,
    seed: int = SEED,
    confidence: float = CONFIDENCE,
) -> Interval:
    """AUC of one score with its stratified bootstrap interval; ``n`` counts both sides."""
    sample, boot = bootstrap_aucs(pos, neg, resamples=resamples, seed=seed)
    return percentile_interval(sample[0], boot[:, 0], len(pos) + len(neg), confidence=confidence)


def paired_auc_difference(
    pos_a: Sequence[float] | np.ndarray,
    neg_a: Sequence[float] | np.ndarray,
    pos_b: Sequence[float] | np.ndarray,
    neg_b: Sequence[float] | np.ndarray,
    *,
    resamples: int = RESAMPLES,
    seed: int = SEED,
    confidence: float = CONFIDENCE,
) -> Interval:
    """AUC(a) - AUC(b) of two scores of the same clips (``pos_a[i]`` and ``pos_b[i]`` score the
    same positive clip), with the interval of the difference over shared replicates."""
    if len(pos_a) != len(pos_b) or len(neg_a) != len(neg_b):
        raise ValueError("a paired difference needs both scores of the same clips")
    pos = np.column_stack([np.asarray(pos_a, float), np.asarray(pos_b, float)])
    neg = np.column_stack([np.asarray(neg_a, float), np.asarray(neg_b, float)])
    sample, boot = bootstrap_aucs(pos, neg, resamples=resamples, seed=seed)
    return percentile_interval(
        sample[0] - sample[1], boot[:, 0] - boot[:, 1], len(pos_a) + len(neg_a), confidence=confidence
    )


def paired_rate_difference(
    hits_a: Sequence[bool] | np.ndarray,
    hits_b: Sequence[bool] | np.ndarray,
    *,
    resamples: int = RESAMPLES,
    seed: int = SEED,
    confidence: float = CONFIDENCE,
) -> Interval:
    """Rate(a) - rate(b) of two yes/no outcomes of the same clips (``hits_a[i]`` and
    ``hits_b[i]`` are the same clip), with the bootstrap interval of the difference, the clips
    drawn once per replicate for both."""
    a, b = np.asarray(hits_a, bool), np.asarray(hits_b, bool)
    if a.shape != b.shape or a.ndim != 1:
        raise ValueError("a paired difference needs both outcomes of the same clips")
    if a.size == 0:
        raise ValueError("a rate needs at least one clip")
    d = a.astype(float) - b.astype(float)
    w = _multiplicities(np.random.default_rng(seed), d.size, resamples)
    return percentile_interval(float(d.mean()), (w @ d) / d.size, d.size, confidence=confidence)
