"""Clips with hard cuts: each shot is judged on its own (its gate, its pairs), the clip's gate is its
first shot's, a cut is never a geometry failure, and re-gating reproduces the recorded verdict."""

from __future__ import annotations

from pathlib import Path

import pytest

from geocon_core.config import ScoreConfig, preset
from geocon_core.media import Mp4Writer
from geocon_core.scoring import Thresholds, gate_shot, regate_clip, score_clip
from geocon_core.synth import ClipPlan, load_ground_truth

from .conftest import read_video

W, H, N = 320, 180, 12


@pytest.fixture(scope="module")
def two_shots(synth_clips, tmp_path_factory) -> tuple[Path, str, str]:
    """A translating camera (C3, gate F) cut to a still one (C1, gate H), 12 frames each, and the
    true gate of each shot."""
    plans = [ClipPlan("C3"), ClipPlan("C1")]
    folder = synth_clips(plans, seed=5, width=W, height=H, num_frames=N)
    truth = [load_ground_truth(folder / f"{p.clip_id}.gt.json") for p in plans]
    path = tmp_path_factory.mktemp("shots") / "c3_then_c1.mp4"
    with Mp4Writer(path, W, H, 24) as writer:
        for p in plans:
            for rgb in read_video(folder / f"{p.clip_id}.mp4"):
                writer.write(rgb)
    return path, truth[0].expected_gate, truth[1].expected_gate


@pytest.fixture(scope="module")
def record(two_shots):
    return score_clip(two_shots[0], preset("audit").with_(working_size=(W, H)))


def test_each_shot_is_gated_and_judged_on_its_own(two_shots, record):
    _, first_gate, second_gate = two_shots
    assert (first_gate, second_gate) == ("F", "H")
    assert record.video.cuts == (N,)
    assert [(s.start, s.end) for s in record.shots] == [(0, N - 1), (N, 2 * N - 1)]
    first, second = record.shots
    assert (first.label, second.label) == ("F", "H")
    assert first.t_inf > 0.05 and second.t_inf <= 0.03
    assert first.consistent is True and second.consistent is True
    # the clip's gate is the first shot's: it sees that shot's parallax, not a pose across the cut
    assert record.gate.label == "F" and record.gate.t_inf == first.t_inf
    assert record.background.consistent is True
    assert "judged on its own" in " ".join(record.warnings)
    # no pair across the cut was scored
    across = [p for p in record.pairs if p.t0 < N <= p.t1]
    assert across and all(p.skip == "hard_cut" for p in across)


def test_regating_at_the_recorded_thresholds_gives_the_recorded_verdict(record):
    v = regate_clip(record, Thresholds.of(record.config))
    assert v.consistent == record.background.consistent
    assert (v.ir, v.ge, v.model) == (record.background.ir, record.background.ge, record.background.model)
    assert v.label == record.gate.label
    # a threshold that fails every shot fails the clip
    strict = Thresholds.of(record.config)
    tight = Thresholds(0.01, 0.0005, strict.ir_gate, strict.ge_gate, strict.tau_t_low, strict.tau_t_high)
    assert regate_clip(record, tight).consistent is False


def test_a_clip_without_cuts_records_no_shots(synth_clips):
    folder = synth_clips([ClipPlan("C1")], seed=5, width=W, height=H, num_frames=N)
    rec = score_clip(folder / f"{ClipPlan('C1').clip_id}.mp4", preset("audit").with_(working_size=(W, H)))
    assert rec.shots == () and "shots" not in rec.summary()


def test_the_paper_keeps_one_gate_across_a_cut(two_shots):
    """``paper`` does not judge shot by shot (``judge_shots``); pairs across the cut are skipped."""
    rec = score_clip(two_shots[0], ScoreConfig(working_size=(W, H)))
    assert rec.shots == () and rec.video.cuts == (N,)
    assert all(p.skip == "hard_cut" for p in rec.pairs if p.t0 < N <= p.t1)


def test_the_gate_shot_is_the_first_with_two_frames():
    assert gate_shot([(0, 0), (1, 9)]) == 1
    assert gate_shot([(0, 5), (6, 9)]) == 0
    assert gate_shot([(0, 0), (1, 1)]) == 0


def test_the_audit_app_regates_a_clip_with_cuts_shot_by_shot(record, tmp_path):
    """The results index (the audit app's triage) gives a clip with cuts the recorded verdict at
    the recorded thresholds, and re-gates it shot by shot at others."""
    from geocon_core.record import write_record
    from geocon_core.results import ResultsIndex

    write_record(record, tmp_path / "rec")
    index = ResultsIndex.open(tmp_path / "rec")
    (clip,) = index.clips
    assert clip.shots == 2
    v = index.verdict(clip.clip_id, index.recorded)
    assert (v.consistent, v.ir, v.ge, v.label) == (
        record.background.consistent,
        record.background.ir,
        record.background.ge,
        record.gate.label,
    )
    tight = Thresholds(0.01, 0.0005, 0.97, 0.6, 0.03, 0.05)
    assert index.verdict(clip.clip_id, tight).consistent is False
