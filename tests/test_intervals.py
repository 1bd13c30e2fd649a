"""Intervals of the validation report: Wilson intervals of shares, the seeded bootstrap of AUCs
over clips, and paired differences with the peer, against known answers."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy.stats import mannwhitneyu, rankdata

from geocon_core.intervals import (
    Interval,
    auc_interval,
    bootstrap_aucs,
    mann_whitney_auc,
    paired_auc_difference,
    paired_rate_difference,
    wilson_interval,
)
from geocon_core.validation import ValidationPlan, ValidationReport, compute_metrics, format_value, write_report
from geocon_core.validation.metrics import MIN_COMPARE, difference_text

from .test_validate import _row

Z95 = 1.959963984540054
"""The 97.5% point of the standard normal."""


@pytest.mark.parametrize(
    "k, n, low, high",
    [
        # R: prop.test(k, n, correct = FALSE)$conf.int
        (0, 10, 0.0, 0.2775328),
        (3, 10, 0.1077913, 0.6032219),
        (5, 10, 0.2365931, 0.7634069),
        (10, 10, 0.7224672, 1.0),
    ],
)
def test_wilson_interval_matches_prop_test_without_correction(k, n, low, high):
    w = wilson_interval(k, n)
    assert w.estimate == k / n and w.n == n
    assert w.low == pytest.approx(low, abs=5e-8) and w.high == pytest.approx(high, abs=5e-8)


def test_wilson_interval_matches_the_score_formula_and_is_exact_at_the_ends():
    # the score interval solved by hand: (p + z^2/2n -+ z sqrt(p(1-p)/n + z^2/4n^2)) / (1 + z^2/n)
    k, n = 7, 23
    p = k / n
    centre, half = p + Z95**2 / (2 * n), Z95 * math.sqrt(p * (1 - p) / n + Z95**2 / (4 * n * n))
    w = wilson_interval(k, n)
    assert (w.low, w.high) == pytest.approx(((centre - half) / (1 + Z95**2 / n), (centre + half) / (1 + Z95**2 / n)))
    assert wilson_interval(0, 54).low == 0.0 and wilson_interval(54, 54).high == 1.0
    with pytest.raises(ValueError):
        wilson_interval(11, 10)


def _brute_auc(pos, neg) -> float:
    p, q = np.asarray(pos, float)[:, None], np.asarray(neg, float)[None, :]
    return float(((p > q).sum() + 0.5 * (p == q).sum()) / (p.size * q.size))


def test_auc_matches_the_mann_whitney_formula():
    pos = [0.9, 0.7, 0.7, 0.4, 0.3, 0.8]
    neg = [0.7, 0.2, 0.1, 0.4, 0.5]
    # U from the ranks of the pooled sample (ties at their mean rank): U = R_pos - n_pos (n_pos + 1) / 2
    ranks = rankdata(pos + neg)
    u = ranks[: len(pos)].sum() - len(pos) * (len(pos) + 1) / 2
    assert u == 23.5  # 22 wins and 3 ties (0.7 twice, 0.4 once) counted half
    assert mann_whitney_auc(pos, neg) == pytest.approx(u / (len(pos) * len(neg)))
    assert mann_whitney_auc(pos, neg) == pytest.approx(mannwhitneyu(pos, neg).statistic / 30)
    assert auc_interval(pos, neg).estimate == pytest.approx(u / 30)
    assert mann_whitney_auc([0.5, 0.7], [0.5]) == 0.75  # one tie, one win


def test_each_bootstrap_replicate_is_the_auc_of_the_clips_it_drew():
    rng = np.random.default_rng(4)
    pos, neg = rng.integers(0, 6, 9).astype(float), rng.integers(0, 5, 7).astype(float)  # many ties
    _, boot = bootstrap_aucs(pos, neg, resamples=300, seed=11)
    draw = np.random.default_rng(11)
    ip, iq = draw.integers(0, pos.size, (300, pos.size)), draw.integers(0, neg.size, (300, neg.size))
    want = [_brute_auc(pos[ip[b]], neg[iq[b]]) for b in range(300)]
    assert boot[:, 0] == pytest.approx(want, abs=1e-12)


def test_a_perfectly_separated_sample_has_auc_one_and_its_interval_ends_at_one():
    iv = auc_interval([0.6, 0.7, 0.8, 0.95], [0.1, 0.2, 0.3, 0.5, 0.55])
    assert (iv.estimate, iv.high) == (1.0, 1.0) and iv.n == 9
    assert iv.low == 1.0  # every resample keeps the two sides apart


def test_auc_interval_shrinks_as_one_over_root_n_when_the_sample_is_replicated():
    rng = np.random.default_rng(0)
    pos, neg = rng.normal(1.0, 1.0, 20), rng.normal(0.0, 1.0, 20)
    once, four = auc_interval(pos, neg), auc_interval(np.tile(pos, 4), np.tile(neg, 4))
    assert four.estimate == once.estimate  # replicating the clips leaves the AUC as it is
    assert 0.4 < (four.high - four.low) / (once.high - once.low) < 0.6  # 1 / sqrt(4)


def test_the_same_seed_gives_the_same_interval():
    rng = np.random.default_rng(2)
    pos, neg = rng.normal(0.5, 1.0, 15), rng.normal(0.0, 1.0, 12)
    assert auc_interval(pos, neg, seed=7) == auc_interval(pos, neg, seed=7)
    assert auc_interval(pos, neg, seed=7) != auc_interval(pos, neg, seed=8)
    hits_a, hits_b = rng.random(30) < 0.5, rng.random(30) < 0.3
    assert paired_rate_difference(hits_a, hits_b) == paired_rate_difference(hits_a, hits_b)


def test_the_paired_difference_of_a_score_with_itself_is_exactly_zero():
    rng = np.random.default_rng(3)
    pos, neg = rng.integers(0, 4, 25) / 4, rng.integers(0, 4, 18) / 4
    assert paired_auc_difference(pos, neg, pos, neg) == Interval(0.0, 0.0, 0.0, 43)
    hits = rng.random(40) < 0.4
    assert paired_rate_difference(hits, hits) == Interval(0.0, 0.0, 0.0, 40)


def test_a_clearly_better_score_has_a_paired_interval_above_zero():
    rng = np.random.default_rng(5)
    n_pos, n_neg = 30, 30
    good_pos, good_neg = rng.normal(2.0, 1.0, n_pos), rng.normal(0.0, 1.0, n_neg)  # AUC about 0.92
    noise_pos, noise_neg = rng.normal(0.0, 1.0, n_pos), rng.normal(0.0, 1.0, n_neg)  # AUC about 0.5
    better = paired_auc_difference(good_pos, good_neg, noise_pos, noise_neg)
    assert better.low > 0.0 and better.estimate == pytest.approx(
        mann_whitney_auc(good_pos, good_neg) - mann_whitney_auc(noise_pos, noise_neg)
    )
    worse = paired_auc_difference(noise_pos, noise_neg, good_pos, good_neg)
    assert (worse.estimate, worse.low, worse.high) == pytest.approx((-better.estimate, -better.high, -better.low))


def test_pairing_narrows_the_difference_of_rates_measured_on_the_same_clips():
    # b flags the same 30 of 100 clips as a, and a three more: the rates differ by 3 points
    a = np.zeros(100, bool)
    a[:33] = True
    b = a.copy()
    b[30:33] = False
    paired = paired_rate_difference(a, b)
    assert paired.estimate == pytest.approx(0.03) and paired.low >= 0.0 and paired.high - paired.low < 0.08
    # two independent samples of the same rates would give an interval about +-0.13 wide
    wa, wb = wilson_interval(33, 100), wilson_interval(30, 100)
    assert (wa.high - wa.low) + (wb.high - wb.low) > 0.3
    clear = paired_rate_difference(np.arange(50) < 40, np.arange(50) < 10)  # 80% against 20%
    assert clear.estimate == pytest.approx(0.6) and clear.low > 0.3


def test_the_report_says_whether_a_difference_is_inside_its_interval():
    close = Interval(0.04, -0.12, 0.19, 40)
    assert difference_text(close, points=False, more="separates these clips better") == (
        "GeoCon - peer +0.04 [-0.12, +0.19]: the interval includes 0, so the two cannot be told apart on these clips"
    )
    ahead = Interval(-0.25, -0.41, -0.08, 40)
    assert difference_text(ahead, points=True, more="flags more of these clips") == (
        "GeoCon - peer -25 points [-41, -8]: the interval excludes 0, the peer flags more of these clips"
    )
    assert difference_text(ahead, points=True, more="flags more", few="3") == (
        "GeoCon - peer -25 points [-41, -8]: too few clips (3) to tell the two apart"
    )


def _generated_check_half(n: int, peer_gap: float, seed: int = 0) -> list:
    """``n`` clips with a visible artifact and ``n`` clean-looking generated clips, plus ``n`` real
    cameras, on the check half: GeoCon's clip score and the peer's, each noisy around a gap."""
    rng = np.random.default_rng(seed)
    gen = dict(kind="real", source="generated", group="check")
    rows = []
    for i in range(n):
        rows.append(
            _row(
                case_id=f"a{i}",
                artifact_kinds=("morphing",),
                clip_score=float(rng.normal(0.6, 0.2)),
                peer_score=float(rng.normal(0.5 + peer_gap, 0.2)),
                verdict="inconsistent",
                **gen,
            )
        )
        rows.append(
            _row(
                case_id=f"c{i}",
                clip_score=float(rng.normal(0.4, 0.2)),
                peer_score=float(rng.normal(0.5, 0.2)),
                verdict="inconsistent" if i % 4 == 0 else "consistent",
                **gen,
            )
        )
        rows.append(
            _row(
                case_id=f"r{i}",
                kind="real",
                source="real",
                group="check",
                clip_score=0.1,
                peer_score=float(rng.normal(0.3, 0.1)),
            )
        )
    return rows  # fmt: skip


def test_auc_rows_carry_the_bootstrap_and_the_paired_difference_with_the_peer():
    rows = _generated_check_half(20, peer_gap=0.2)
    table = {(m.metric, m.subset): m for m in compute_metrics(rows)}
    vis = table["AUC, clip score (visible artifact vs clean-looking generated)", "check half"]
    pos = [r for r in rows if r.case_id.startswith("a")]
    neg = [r for r in rows if r.case_id.startswith("c")]
    ours = auc_interval([r.clip_score for r in pos], [r.clip_score for r in neg])
    peer = auc_interval([r.peer_score for r in pos], [r.peer_score for r in neg])
    diff = paired_auc_difference(
        [r.clip_score for r in pos],
        [r.clip_score for r in neg],
        [r.peer_score for r in pos],
        [r.peer_score for r in neg],
    )
    assert (vis.interval, vis.peer, vis.difference) == (ours, peer, diff)  # one set of resamples, the same seed
    assert vis.value == ours.estimate and vis.interval is not None and vis.interval.low < vis.value < vis.interval.high
    assert format_value(vis) == f"{ours.estimate:.2f} [{ours.low:.2f}, {ours.high:.2f}] (20 vs 20)"
    assert vis.detail.startswith(f"peer {peer.estimate:.2f} [{peer.low:.2f}, {peer.high:.2f}]; GeoCon - peer ")
    assert diff.low <= 0.0 <= diff.high  # two similar scores on 40 clips
    assert vis.detail.endswith("the interval includes 0, so the two cannot be told apart on these clips")
    # the same input gives the same numbers
    assert compute_metrics(rows) == compute_metrics(rows)


def test_rate_rows_carry_wilson_intervals_and_flag_rates_the_paired_difference():
    rows = _generated_check_half(MIN_COMPARE + 3, peer_gap=0.2, seed=1)
    table = {(m.metric, m.subset): m for m in compute_metrics(rows)}
    for row in table.values():
        if row.value is not None and not row.metric.startswith(("AUC", "clean IR", "F keeps")):
            assert row.interval == wilson_interval(row.hits, row.n), row.metric
            assert format_value(row).endswith(f"({row.hits}/{row.n})") and "%, " in format_value(row)
    flags = table["flagged inconsistent, GeoCon", "visible artifact, check half"]
    assert flags.peer is not None and flags.difference is not None
    ours = [r.verdict == "inconsistent" for r in rows if r.case_id.startswith("a")]
    assert flags.difference.estimate == pytest.approx(sum(ours) / len(ours) - flags.peer.estimate)
    assert "GeoCon - peer " in flags.detail and " points [" in flags.detail


def test_too_few_clips_are_never_called_apart():
    rows = _generated_check_half(2, peer_gap=-0.5)  # GeoCon far ahead, but on 2 vs 2 clips
    table = {(m.metric, m.subset): m for m in compute_metrics(rows)}
    vis = table["AUC, clip score (visible artifact vs clean-looking generated)", "check half"]
    assert "too few clips (2 vs 2) to tell the two apart" in vis.detail and "excludes" not in vis.detail


def test_the_written_report_explains_and_stores_its_intervals(tmp_path):
    rows = _generated_check_half(6, peer_gap=0.0, seed=2)
    report = ValidationReport(tuple(compute_metrics(rows)), tuple(rows), "audit", "0" * 16, 1.0, 1.0,
                              ValidationPlan(), len(rows))  # fmt: skip
    md, js = write_report(report, tmp_path)
    text = md.read_text()
    assert "Brackets hold 95% intervals" in text and "2000 bootstrap resamples" in text
    assert "| cases scored | all | 100% [" in text
    doc = json.loads(js.read_text())
    auc_row = next(m for m in doc["metrics"] if m["metric"].startswith("AUC") and m["peer"] is not None)
    assert set(auc_row["interval"]) == {"estimate", "low", "high", "n"}
    assert auc_row["difference"]["low"] <= auc_row["difference"]["estimate"] <= auc_row["difference"]["high"]


def test_a_bound_that_excludes_zero_never_reads_zero():
    from geocon_core.intervals import Interval
    from geocon_core.validation.metrics import difference_text

    text = difference_text(Interval(-0.14, -0.28, -0.004, 97), points=False, more="separates these clips better")
    assert "[-0.28, -0.004]" in text and "excludes 0, the peer" in text
    assert "[+0.0004, +0.20]" in difference_text(Interval(0.1, 0.0004, 0.2, 97), points=False, more="x")
    assert difference_text(Interval(0.0, 0.0, 0.0, 97), points=True, more="x").startswith(
        "GeoCon - peer +0 points [+0, +0]"
    )
    assert "-0.4 points" in difference_text(Interval(-0.004, -0.1, 0.1, 97), points=True, more="x")
