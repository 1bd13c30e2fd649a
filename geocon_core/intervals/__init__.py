"""Confidence intervals shared by the benchmark report (:mod:`geocon_core.report`) and the
validation report (:mod:`geocon_core.validation`): :mod:`.shares` (Wilson) and :mod:`.bootstrap`
(AUCs and paired differences). Pure, seeded functions on numpy arrays; no extra is needed.

- **Wilson score interval** of a proportion ``k / n`` (:func:`wilson_interval`): the interval of
  R's ``prop.test(k, n, correct = FALSE)``; it stays inside [0, 1] and is not empty at 0 / n or
  n / n.
- **AUC** of a score separating positives from negatives (:func:`mann_whitney_auc`): the
  Mann-Whitney statistic ``U / (n_pos n_neg)``, the chance that a random positive scores above a
  random negative, ties counting half.
- **Stratified bootstrap over clips**: each of ``resamples`` replicates draws the positives and
  the negatives with replacement, each side keeping its size, from a generator seeded with
  ``seed``, so the same input gives the same interval; the interval is the percentile interval of
  the replicates. A replicate is a vector of multiplicities per clip, and its AUC is read from the
  sorted scores once (no sort per replicate).
- **Paired differences** (:func:`paired_auc_difference`, :func:`paired_rate_difference`): two
  scores of the same clips are compared on the same replicates (the clips are drawn once, both
  scores read on each draw), so the interval of the difference reflects that both were measured
  on the same clips. A score compared with itself gives exactly 0 [0, 0].
"""

from .bootstrap import (
    RESAMPLES,
    SEED,
    auc_interval,
    bootstrap_aucs,
    mann_whitney_auc,
    paired_auc_difference,
    paired_rate_difference,
    percentile_interval,
)
from .shares import CONFIDENCE, Interval, wilson_interval

__all__ = [
    "CONFIDENCE",
    "RESAMPLES",
    "SEED",
    "Interval",
    "wilson_interval",
    "mann_whitney_auc",
    "bootstrap_aucs",
    "percentile_interval",
    "auc_interval",
    "paired_auc_difference",
    "paired_rate_difference",
]
