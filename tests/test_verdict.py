"""The verdict rules: one ``is_flagged`` on which the benchmark (audit recordings), the triage list
(``flagged_only``), the report's flagged section and the audit app's "flagged" filter agree, for
every combination of report gate (passing, failing, not judged), pose (present, absent), gate
(agreeing or not with the clip's category) and the clip model's verdict (none: the background
decides; consistent, inconsistent, cannot judge: it decides instead of the report gate); and gate
defaults that are the config's."""

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


FINDINGS = (None, "consistent", "inconsistent", "cannot judge")


def _combos():
    return list(itertools.product(GATES, (True, False), (True, False), FINDINGS))


def _clip(gate: str, pose: bool, agrees: bool, finding: str | None = None) -> ResultClip:
    ir, ge = SCORES[gate]
    model = "H" if pose else "F"  # t_inf 0 gates H; without a pose the clip is gated F
    expected = model if agrees else ("F" if model == "H" else "H")
    return ResultClip(
        clip_id=f"{gate.replace(' ', '_')}-{'pose' if pose else 'nopose'}-{'agrees' if agrees else 'disagrees'}"
        f"-{(finding or 'background').replace(' ', '_')}",
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
        finding=finding,
    )


@pytest.fixture(scope="module")
def index() -> ResultsIndex:
    clips = [_clip(*c) for c in _combos()]
    return ResultsIndex(Path("."), clips, ScoreConfig(), None, "bench")


def _truth(gate: str, pose: bool, agrees: bool, finding: str | None) -> bool:
    passes = gate == "passes" if finding is None else finding == "consistent"
    return not (passes and pose and agrees)


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
                "clip_verdict": c.finding,
                "clip_score": None if c.finding is None else 0.5,
                "record": f"clips/{c.clip_id}",
                "rrd": None,
            }
        )
    ok = pd.DataFrame(rows).astype({"pose_present": "boolean", "consistent": "boolean"})
    page = _flagged(ok, [], "..")
    return set(re.findall(r"<tr><td>([^<]+)</td>", page))


def _app_flagged(index: ResultsIndex) -> set[str]:
    pytest.importorskip("viser")
    from geocon_viewer.audit.app import ANY, FLAGGED, AuditApp

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
    # of 48: not flagged, a clip with a pose and the expected gate that passes the report gate where
    # the background decides (1 of 12) or that the clip model calls consistent (3 of 12)
    assert len(expected) == 48 - 4

    bench = set()
    for c in index.clips:
        v = index.verdict(c.clip_id, index.recorded)
        record = SimpleNamespace(
            background=SimpleNamespace(consistent=v.consistent),
            gate=SimpleNamespace(pose_present=c.pose_present, model=v.model),
            model_verdict=lambda c=c: c.finding,
        )
        if bench_flagged(record, c.expected_model):
            bench.add(c.clip_id)
    triage = {r.clip_id for r in index.triage(flagged_only=True)}
    assert bench == expected
    assert triage == expected
    assert _report_flagged(index) == expected
    assert _app_flagged(index) == expected


def test_each_combination_is_what_it_claims(index):
    for gate, pose, agrees, finding in _combos():
        clip = _clip(gate, pose, agrees, finding)
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
    # where the clip model decides, it stands in for the report gate
    assert flag_reasons(
        consistent=True, pose_present=True, gate_model="H", expected_model="H", finding="inconsistent"
    ) == ("model",)
    assert not is_flagged(consistent=False, pose_present=True, gate_model="H", expected_model="H", finding="consistent")
    assert flag_reasons(
        consistent=True, pose_present=True, gate_model="H", expected_model="H", finding="cannot judge"
    ) == ("not_judged",)
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


@pytest.mark.full
def test_a_bench_of_the_default_flags_on_the_clip_models_verdict(tmp_path):
    """`geocon bench` with the default preset: the clips table, the results index (from the table
    and from record.json alone) and each record carry the same clip-model verdict, and the triage
    flag follows it."""
    pytest.importorskip("pandas")
    from geocon_core.bench import read_tables, run_bench
    from geocon_core.config import preset
    from geocon_core.record import read_record
    from geocon_core.synth import plan_benchmark, write_benchmark

    plan = plan_benchmark(families=("C1",), scenes=1, platforms=("clean", "breathing"), breathing_px=12.0)
    write_benchmark(tmp_path / "data", plan, width=320, height=180, num_frames=12)
    run_bench(tmp_path / "data", tmp_path / "r", preset("audit").with_(working_size=(320, 180)), workers=2)
    clips = read_tables(tmp_path / "r")["clips"].set_index("clip_id")
    records = {cid: read_record(tmp_path / "r" / "clips" / cid) for cid in clips.index}
    assert len(records) == 2
    for cid, rec in records.items():
        assert rec.model_verdict() is not None
        assert clips.loc[cid, "clip_verdict"] == rec.model_verdict()
        score = rec.finding().clip_score
        assert clips.loc[cid, "clip_score"] == pytest.approx(float("nan") if score is None else score, nan_ok=True)
    from_table = {c.clip_id: (c.finding, c.clip_score) for c in ResultsIndex.open(tmp_path / "r").clips}
    (tmp_path / "r" / "tables" / "clips.parquet").unlink()
    from_json = {c.clip_id: (c.finding, c.clip_score) for c in ResultsIndex.open(tmp_path / "r").clips}
    truth = {cid: (rec.model_verdict(), rec.finding().clip_score) for cid, rec in records.items()}
    assert from_table == from_json == truth
    index = ResultsIndex.open(tmp_path / "r")
    rows = index.triage()
    flagged = {r.clip_id for r in index.triage(flagged_only=True)}
    assert flagged == {cid for cid, rec in records.items() if rec.model_verdict() != "consistent"}
    # the list's verdict is the model's, most severe first
    state = {"inconsistent": "fails", "consistent": "passes", "cannot judge": "not judged"}
    assert [r.state for r in rows] == [state[truth[r.clip_id][0]] for r in rows]
