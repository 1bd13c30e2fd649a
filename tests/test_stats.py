"""Benchmark statistics against known answers."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from geocon_core.report import stats


@pytest.mark.parametrize(
    "k, n, low, high",
    [
        (81, 263, 0.2553, 0.3662),  # Newcombe (1998), Stat. Med. 17:857, example (a)
        (15, 148, 0.0624, 0.1605),  # example (b)
        (0, 20, 0.0, 0.1611),  # example (c)
        (1, 29, 0.0061, 0.1718),  # example (d)
        (5, 10, 0.2366, 0.7634),
    ],
)
def test_wilson_interval_matches_published_values(k, n, low, high):
    w = stats.wilson_interval(k, n)
    assert w.estimate == pytest.approx(k / n)
    assert w.low == pytest.approx(low, abs=6e-5) and w.high == pytest.approx(high, abs=6e-5)


def test_wilson_empty_is_nan():
    w = stats.wilson_interval(0, 0)
    assert math.isnan(w.estimate) and math.isnan(w.low) and w.n == 0


def test_scene_balanced_median_gives_each_scene_one_vote():
    # scene a was regenerated 5 times with value 10; scenes b, c once with 1 and 2
    values = [10, 10, 10, 10, 10, 1, 2]
    scenes = ["a"] * 5 + ["b", "c"]
    assert stats.scene_balanced_median(values, scenes) == 2.0  # median of (10, 1, 2)
    assert np.median(values) == 10  # the pooled median would be dominated by scene a
    assert stats.scene_balanced_median([np.nan, 3.0], ["a", "b"]) == 3.0


def test_bootstrap_ci_properties():
    rng = np.random.default_rng(5)
    v = rng.normal(2.0, 1.0, 40)
    s = np.arange(40)
    a = stats.bootstrap_median_ci(v, s, B=2000, seed=1)
    assert a.low <= a.estimate <= a.high and a.n == 40
    assert a == stats.bootstrap_median_ci(v, s, B=2000, seed=1)
    assert (a.low, a.high) != (
        stats.bootstrap_median_ci(v, s, B=2000, seed=2).low,
        stats.bootstrap_median_ci(v, s, B=2000, seed=2).high,
    )
    flat = stats.bootstrap_median_ci([3.0] * 6, list("abcdef"), B=500)
    assert (flat.estimate, flat.low, flat.high) == (3.0, 3.0, 3.0)
    one = stats.bootstrap_median_ci([1.0, 5.0], ["x", "x"], B=500)
    assert (one.estimate, one.low, one.high, one.n) == (3.0, 3.0, 3.0, 1)


def test_bootstrap_ci_covers_the_true_median_about_95_percent():
    rng = np.random.default_rng(11)
    hits = 0
    for i in range(200):
        v = rng.normal(0.0, 1.0, 30)
        ci = stats.bootstrap_median_ci(v, np.arange(30), B=400, seed=i)
        hits += ci.low <= 0.0 <= ci.high
    assert 0.88 <= hits / 200 <= 0.99


def test_median_difference_ci():
    a = stats.median_difference_ci([5, 6, 7], ["a", "b", "c"], [1, 2, 3], ["a", "b", "c"], B=2000)
    assert a.estimate == 4.0 and a.low > 0 and a.n == 3


def _clips() -> pd.DataFrame:
    rows = [
        # model, category, scene, gate_label, gate_model, pose_present
        ("p", "C1", "s1", "H", "H", True),
        ("p", "C1", "s2", "F", "F", True),  # anomaly
        ("p", "C1", "s3", None, "F", False),  # no pose: counted only under fail->F (as F: anomaly)
        ("p", "C1", "s4", "U", "H", True),  # gray zone: not present-only; kept H under fail->F
        ("p", "C3", "s5", "F", "F", True),
        ("p", "C3", "s6", "H", "H", True),  # anomaly
        ("q", "C1", "s1", "H", "H", True),
        ("q", "C1", "s2", "H", "H", True),
        ("q", "C3", "s5", "F", "F", True),
        ("q", "C3", "s6", "F", "F", True),
    ]
    df = pd.DataFrame(rows, columns=["model", "category", "scene_id", "gate_label", "gate_model", "pose_present"])
    df["expected_model"] = df["category"].map(stats.EXPECTED_MODEL)
    df["status"] = "ok"
    df["clip_id"] = [f"c{i}" for i in range(len(df))]
    return df


def test_gate_rates_on_a_hand_made_table():
    r = stats.gate_rates(_clips()).set_index(["model", "category"])
    pc1 = r.loc[("p", "C1")]
    assert (pc1.n_clips, pc1.n_present) == (4, 2)
    assert pc1.f_rate_present == 0.5 and pc1.anomaly_rate_present == 0.5  # s1 H, s2 F
    assert pc1.f_rate_fail_f == 0.5 and pc1.anomaly_rate_fail_f == 0.5  # F: s2, s3 (no pose); U kept H
    assert r.loc[("p", "C3")].anomaly_rate_present == 0.5
    assert r.loc[("q", "C1")].anomaly_rate_present == 0.0 and r.loc[("q", "C3")].f_rate_fail_f == 1.0
    w = stats.wilson_interval(1, 2)
    assert (pc1.f_rate_present_low, pc1.f_rate_present_high) == (w.low, w.high)


def test_consensus_on_a_hand_made_table():
    c = stats.consensus(_clips()).set_index(["scene_id", "category"])
    assert c.loc[("s1", "C1")].unanimous == True  # noqa: E712  H and H
    assert c.loc[("s2", "C1")].unanimous == False  # noqa: E712  F vs H
    assert c.loc[("s6", "C3")].unanimous == False  # noqa: E712
    assert c.loc[("s5", "C3")].unanimous == True  # noqa: E712
    assert pd.isna(c.loc[("s3", "C1")].unanimous)  # one platform, no pose
    out = stats.consensus(_clips())
    assert out.attrs["n_tuples"] == 4 and out.attrs["consensus_rate"] == 0.5


def test_coverage_table_counts_verdicts_and_pose_evidence():
    df = _clips()
    df["consistent"] = pd.array([True, False, None, True, True, None, True, True, False, True], dtype="boolean")
    df["pose_method"] = ["essential", "chain", "none", "rotation", "essential", "chain"] + ["essential"] * 4
    c = stats.coverage_table(df).set_index("model")
    p = c.loc["p"]
    assert (p.n_clips, p.consistent, p.inconsistent, p.not_judged) == (6, 3, 1, 2)
    assert (p.pose_first_last, p.pose_chain, p.pose_log, p.no_pose) == (3, 2, 0, 1)
    assert p.pose_coverage == pytest.approx(5 / 6)
    assert c.loc["q"].not_judged == 0 and c.loc["q"].pose_coverage == 1.0


def test_calibration_bins_are_equal_count_with_wilson():
    t = np.linspace(0.0, 0.2, 120)
    y = t > 0.1
    bins = stats.calibration_bins(t, y, K=12)
    assert len(bins) == 12 and (bins["n"] == 10).all()
    assert bins["k"].sum() == y.sum()
    assert bins.iloc[0].p == 0.0 and bins.iloc[-1].p == 1.0
    w = stats.wilson_interval(int(bins.iloc[6].k), 10)
    assert (bins.iloc[6].low, bins.iloc[6].high) == (w.low, w.high)


def test_net_benefit_and_balanced_accuracy_by_hand():
    t = np.array([0.0, 0.01, 0.05, 0.02, 0.1, 0.2])
    y = np.array([False, False, False, True, True, True])
    nb = stats.net_benefit(t, y, [0.03], costs=(0.5, 1.0, 2.0)).set_index("c")
    # predicted F at tau 0.03: 0.05 (FP), 0.1, 0.2 (TP) -> TP 2, FP 1, N 6
    assert nb.loc[0.5].net_benefit == pytest.approx((2 - 0.5) / 6)
    assert nb.loc[2.0].net_benefit == pytest.approx((2 - 2.0) / 6)
    assert stats.balanced_accuracy(t, y, 0.03) == pytest.approx((2 / 3 + 2 / 3) / 2)
    assert stats.balanced_accuracy(t, y, 0.015) == pytest.approx((1 + 2 / 3) / 2)


def test_bootstrap_tau_finds_the_separating_band():
    rng = np.random.default_rng(0)
    t = np.concatenate([rng.uniform(0.0, 0.035, 40), rng.uniform(0.05, 0.2, 40)])
    y = np.arange(80) >= 40
    boot = stats.bootstrap_tau(t, y, B=400, seed=0)
    assert boot.best_tau == 0.04 and int(boot.argmax_counts.sum()) == 400
    assert boot.mean[2] == 1.0 and boot.mean[0] < 1.0
    with pytest.raises(ValueError, match="both expected classes"):
        stats.bootstrap_tau(t[:40], y[:40])


def test_adap90_p80_and_rate():
    objs = pd.DataFrame({"model": ["p"] * 5, "category": ["C4"] * 5, "adap90": [1.0, 2.0, 3.0, 4.0, 5.0]})
    r = stats.adap90_summary(objs).iloc[0]
    assert r.p80 == pytest.approx(4.2) and r.rate_above_p80 == 0.2 and r.p50 == 3.0 and r.n_objects == 5


def test_percentile_aligned_by_hand():
    clips = pd.DataFrame({"model": ["p"] * 11, "ir": np.linspace(0.9, 1.0, 11), "ge": np.arange(11.0), "status": "ok"})
    r = stats.percentile_aligned(clips, percentiles=(50,), band=10).iloc[0]
    assert r.ir_p == pytest.approx(0.95) and r.ge_at == 5.0 and r.n == 3  # ir 0.94, 0.95, 0.96
