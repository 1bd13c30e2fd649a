"""The verdict rules: one ``is_flagged`` on which the benchmark (audit recordings), the triage list
(``flagged_only``), the report's flagged section and the audit app's "flagged" filter agree, for
every combination of report gate (passing, failing, not judged), pose (present, absent) and gate
(agreeing or not with the clip's category); and gate defaults that are the config's."""

from __future__ import annotations

import itertools
import re
from pathlib import Path
from types import SimpleNamespace

import pytest

from geocon_core.bench.clip import _flagged as bench_flagged
from geocon_core.config import ScoreConfig
from geocon_core.geometry import FAMILIES, family_spec
from geocon_core.results import ResultClip, ResultsIndex
from geocon_core.scoring import (
    FitRow,
    Scores,
    Thresholds,
    aggregate_gaps,
    binary_gate,
    clip_verdict,
    family_verdict,
    flag_reasons,
    gate_decision,
    hysteresis_gate,
    is_flagged,
)

GATES = ("passes", "fails", "not judged")
SCORES = {"passes": (0.99, 0.2), "fails": (0.3, 4.0), "not judged": (None, None)}
EXPECTING = {"H": "C1", "F": "C3"}  # a category whose expected model is H / F


def _combos():
    return list(itertools.product(GATES, (True, False), (True, False)))


def _clip(gate: str, pose: bool, agrees: bool) -> ResultClip:
    ir, ge = SCORES[gate]
    model = "H" if pose else "F"  # t_inf 0 gates H; without a pose the clip is gated F
    expected = model if agrees else ("F" if model == "H" else "H")
    return ResultClip(
        clip_id=f"{gate.replace(' ', '_')}-{'pose' if pose else 'nopose'}-{'agrees' if agrees else 'disagrees'}",
        platform="p",
        category=EXPECTING[expected],
        expected_model=expected,
        status="ok",
        error=None,
        folder=None,
        rrd=None,
        prompt=None,
        t_inf=0.0 if pose else None,
        pose_present=pose,
        ir_h=ir,
        ge_h=ge,
        ir_f=ir,
        ge_f=ge,
        adap90_max=None,
        n_objects=0,
    )


@pytest.fixture(scope="module")
def index() -> ResultsIndex:
    clips = [_clip(*c) for c in _combos()]
    return ResultsIndex(Path("."), clips, ScoreConfig(), None, "bench")


def _truth(gate: str, pose: bool, agrees: bool) -> bool:
    return not (gate == "passes" and pose and agrees)


def _report_flagged(index: ResultsIndex) -> set[str]:
    pd = pytest.importorskip("pandas")
    from geocon_core.report.pages import _flagged

    rows = []
    for c in index.clips:
        v = index.verdict(c.clip_id, index.recorded)
        assert v is not None
        rows.append(
            {
                "clip_id": c.clip_id,
                "model": c.platform,
                "category": c.category,
                "expected_model": c.expected_model,
                "gate_model": v.model,
                "pose_present": c.pose_present,
                "consistent": v.consistent,
                "record": f"clips/{c.clip_id}",
                "rrd": None,
            }
        )
    ok = pd.DataFrame(rows).astype({"pose_present": "boolean", "consistent": "boolean"})
    page = _flagged(ok, [], "..")
    return set(re.findall(r"<tr><td>([^<]+)</td>", page))


def _app_flagged(index: ResultsIndex) -> set[str]:
    pytest.importorskip("viser")
    from geocon_viewer.audit_app import ANY, FLAGGED, AuditApp

    handles = SimpleNamespace(
        state=SimpleNamespace(value=FLAGGED),
        platform=SimpleNamespace(value=ANY),
        category=SimpleNamespace(value=ANY),
        gate_label=SimpleNamespace(value=ANY),
    )
    filters = AuditApp._filters(handles)  # type: ignore[arg-type]
    return {r.clip_id for r in index.triage(index.recorded, **filters)}


def test_bench_results_report_and_app_flag_the_same_clips(index):
    expected = {_clip(*c).clip_id for c in _combos() if _truth(*c)}
    assert len(expected) == 11  # of 12: only a passing clip with a pose and the expected gate is not flagged

    bench = set()
    for c in index.clips:
        v = index.verdict(c.clip_id, index.recorded)
        record = SimpleNamespace(
            background=SimpleNamespace(consistent=v.consistent),
            gate=SimpleNamespace(pose_present=c.pose_present, model=v.model),
        )
        if bench_flagged(record, c.expected_model):
            bench.add(c.clip_id)
    triage = {r.clip_id for r in index.triage(flagged_only=True)}
    assert bench == expected
    assert triage == expected
    assert _report_flagged(index) == expected
    assert _app_flagged(index) == expected


def test_each_combination_is_what_it_claims(index):
    for gate, pose, agrees in _combos():
        clip = _clip(gate, pose, agrees)
        v = index.verdict(clip.clip_id, index.recorded)
        assert v.consistent is {"passes": True, "fails": False, "not judged": None}[gate]
        assert v.model == ("H" if pose else "F")
        assert (v.model == clip.expected_model) is agrees


def test_flag_reasons_name_each_cause():
    assert flag_reasons(consistent=True, pose_present=True, gate_model="H", expected_model="H") == ()
    assert flag_reasons(consistent=None, pose_present=False, gate_model="F", expected_model="H") == (
        "not_judged",
        "no_pose",
    )
    assert flag_reasons(consistent=False, pose_present=True, gate_model="F", expected_model="H") == (
        "fails",
        "gate_mismatch",
    )
    # no category, no expected model: the gate cannot disagree with it
    assert not is_flagged(consistent=True, pose_present=True, gate_model="F", expected_model=None)


def test_gate_defaults_are_the_configs():
    cfg = ScoreConfig()
    for t in (0.0, cfg.tau_t_low, 0.035, cfg.tau_t, 0.045, cfg.tau_t_high, 0.2):
        assert hysteresis_gate(t) == hysteresis_gate(t, cfg.tau_t_low, cfg.tau_t_high)
        assert binary_gate(t) == binary_gate(t, cfg.tau_t)
    assert gate_decision(None, pose_present=False) == ("F", "F", None)


def test_the_scorer_and_regating_compose_one_verdict():
    th = Thresholds.of(ScoreConfig())
    v = clip_verdict(t_inf=0.04, pose_present=True, ir_h=0.9, ge_h=0.5, ir_f=0.95, ge_f=0.4, thresholds=th)
    assert (v.label, v.model, v.binary_label) == ("U", "F", "H")  # gray zone: the higher IR wins
    assert th.tau("H") == th.tau_h and th.tau("F") == th.tau_f


def test_family_table_names_the_valid_families():
    assert list(FAMILIES) == ["H", "F"]
    with pytest.raises(ValueError, match="family must be 'H' or 'F', got 'E'"):
        family_spec("E")


# --- the coverage rule ---------------------------------------------------------------------------


def _rows(gap: int, n_valid: int, n_invalid: int, n_skipped: int = 0) -> list[FitRow]:
    ok = [FitRow(gap, 1.0, True, 0.99, 0.1) for _ in range(n_valid)]
    bad = [FitRow(gap, 1.0, False, None, None) for _ in range(n_invalid)]
    skipped = [FitRow(gap, 1.0, False, None, None, judgeable=False) for _ in range(n_skipped)]
    return ok + bad + skipped


def test_a_gap_under_the_coverage_share_is_not_judged():
    # 2 valid of 33 judgeable pair-scales: no headline, however good those two fits are
    per_gap, ir, ge = aggregate_gaps(_rows(1, 2, 31), gaps=(1,), scales=(1.0,), aggregation="median", min_coverage=0.5)
    assert (ir, ge) == (None, None)
    assert per_gap[0].ir == pytest.approx(0.99) and not per_gap[0].judged
    assert per_gap[0].judgeable_pairs == 33 and per_gap[0].coverage == pytest.approx(2 / 33)
    v = family_verdict(
        Scores(ir, ge), Scores(None, None), t_inf=0.0, pose_present=True, thresholds=Thresholds.of(ScoreConfig())
    )
    assert v.consistent is None


def test_pairs_skipped_by_design_do_not_count_against_coverage():
    # 6 valid, 4 invalid, 20 duplicate-frame rows: 60% of the judgeable rows
    per_gap, ir, _ = aggregate_gaps(
        _rows(1, 6, 4, n_skipped=20), gaps=(1,), scales=(1.0,), aggregation="median", min_coverage=0.5
    )
    assert per_gap[0].judged and per_gap[0].judgeable_pairs == 10 and ir == pytest.approx(0.99)
    per_gap, ir, _ = aggregate_gaps(
        _rows(1, 6, 4, n_skipped=20), gaps=(1,), scales=(1.0,), aggregation="median", min_coverage=0.7
    )
    assert not per_gap[0].judged and ir is None


def test_an_unjudged_gap_leaves_the_headline_to_the_judged_ones():
    rows = _rows(1, 9, 1) + [FitRow(8, 1.0, True, 0.5, 9.0)] + _rows(8, 0, 9)
    per_gap, ir, ge = aggregate_gaps(rows, gaps=(1, 8), scales=(1.0,), aggregation="worst", min_coverage=0.5)
    assert [g.judged for g in per_gap] == [True, False]
    assert ir == pytest.approx(0.99) and ge == pytest.approx(0.1)  # gap 8's lone fit is not the headline


def test_a_failing_background_of_moving_matches_is_not_judged_and_a_passing_one_passes():
    th = Thresholds(1.0, 0.1, 0.97, 0.6, 0.03, 0.05, 0.0, 0.5)
    fails, passes = Scores(0.8, 0.9, 0.6), Scores(0.99, 0.2, 0.9)
    v = family_verdict(fails, fails, t_inf=0.0, pose_present=True, thresholds=th)
    assert (v.model, v.consistent, v.untrusted, v.report_margin) == ("H", None, True, None)
    assert family_verdict(passes, passes, t_inf=0.0, pose_present=True, thresholds=th).consistent is True
    clean = Scores(0.8, 0.9, 0.49)
    assert family_verdict(clean, clean, t_inf=0.0, pose_present=True, thresholds=th).consistent is False
    # the bench index reads the same shares from its clips
    clip = _clip("fails", True, True)
    moved = ResultClip(**{**clip.__dict__, "ir_h": 0.8, "ge_h": 0.9, "ind_h": 0.6})
    idx = ResultsIndex(Path("."), [moved], ScoreConfig(untrusted_share=0.5), None, "bench")
    got = idx.verdict(moved.clip_id, idx.recorded)
    assert got is not None and got.consistent is None and got.untrusted
