"""The clip's readings beside the background fit (geocon_core.signals) and the clip model.

Ground truth: synthetic scenes with known geometry (a static rigid scene moves nowhere and fails no
flow test; a scene with moving objects has a known moving share) and failures planted with known
extent; the model's fit is checked on readings drawn with a known separation."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from geocon_core.config import SignalsConfig, preset
from geocon_core.media import open_video
from geocon_core.signals import (
    READING_LABELS,
    AppearanceReading,
    ClipModel,
    ClipReadings,
    ModelTerm,
    appearance_reading,
    fit_clip_model,
    load_clip_model,
    plan_pairs,
    reduce_gray,
    unkept_share,
)

CFG = SignalsConfig(enabled=True)


def _reading(path: Path) -> AppearanceReading:
    _fps, frames = open_video(str(path))
    grays = {i: reduce_gray(cv2.cvtColor(f, cv2.COLOR_BGR2GRAY), CFG) for i, f in enumerate(frames)}
    return appearance_reading(grays, len(grays), CFG)


def _read(path: Path) -> dict[str, float | None]:
    return _reading(path).to_dict()


@pytest.fixture(scope="module")
def scenes(synth_clips):
    from geocon_core.synth import ClipPlan

    folder = synth_clips([ClipPlan("C1"), ClipPlan("C4")], seed=3, width=640, height=360, num_frames=24)
    return folder


def _clip(folder: Path, family: str) -> Path:
    """The clean clip of ``family`` (the folder is shared with other modules' clips, failures included)."""
    (clip,) = (p for p in folder.glob(f"{family.lower()}_*.mp4") if "__" not in p.stem)
    return clip


def test_pairs_are_spread_over_the_clip_and_bounded():
    far, near = plan_pairs(200, CFG)
    assert len(far) == len(near) == CFG.max_pairs
    assert far[0] == (0, CFG.gap) and far[-1] == (199 - CFG.gap, 199)
    assert near[0] == (0, 1) and near[-1] == (198, 199)
    assert plan_pairs(3, CFG)[0] == [(0, 2)]  # shorter than the gap: its first and last frame
    assert plan_pairs(1, CFG) == ([], [])
    assert reduce_gray(np.zeros((1080, 1920), np.uint8), CFG).shape == (216, 384)
    assert reduce_gray(np.zeros((100, 120), np.uint8), CFG).shape == (100, 120)


def test_a_static_rigid_scene_fails_no_flow_test_and_nothing_moves(scenes):
    r = _read(_clip(scenes, "C1"))
    assert r["flow_failure"] == pytest.approx(0.0, abs=0.005)
    assert r["interior_failure"] == pytest.approx(0.0, abs=0.005)
    assert r["mover_share"] == pytest.approx(0.0, abs=0.005)
    assert r["unexplained_appearance"] < 0.06  # sensor noise and compression only


def test_the_moving_share_follows_the_objects_that_move(scenes):
    from geocon_core.synth import load_ground_truth

    clip = _clip(scenes, "C4")
    truth = float(np.mean(load_ground_truth(clip.with_suffix(".gt.json")).masked_share))
    reading = _reading(clip)
    r = reading.to_dict()
    assert truth > 0.03
    assert r["mover_share"] == pytest.approx(truth, abs=0.04)
    # the picture holds the number: the movers map averages to the moving share
    assert reading.maps is not None
    assert float(reading.maps.shares("movers").mean()) == pytest.approx(r["mover_share"], abs=0.01)
    # failures sit on the objects' outlines (occlusion), not inside surfaces
    assert r["interior_failure"] < 0.25 * r["flow_failure"]


@pytest.mark.full
def test_a_planted_breathing_background_moves_on_its_own_and_is_not_explained(scenes, tmp_path):
    from geocon_core.plant import plant_clip

    result = plant_clip(_clip(scenes, "C1"), "breathing", "middle", 0, tmp_path)
    clean, planted = _read(result.clean), _read(result.planted)
    assert clean["mover_share"] < 0.005 < 0.03 < planted["mover_share"]
    assert planted["unexplained_appearance"] > clean["unexplained_appearance"] + 0.01


@pytest.mark.full
@pytest.mark.parametrize(
    "kind", ["morph", pytest.param("slide", marks=pytest.mark.slow), pytest.param("redraw", marks=pytest.mark.slow)]
)
def test_the_unexplained_map_lights_up_the_planted_region(scenes, tmp_path, kind):
    from geocon_core.plant import plant_clip

    result = plant_clip(_clip(scenes, "C1"), kind, "high", 0, tmp_path)
    maps = {}
    for name, path in (("planted", result.planted), ("clean", result.clean)):
        reading = _reading(path)
        assert reading.maps is not None
        maps[name] = reading.maps.shares("unexplained")
    region = result.planting.mask(reading.pairs[-1].t1).astype(np.uint8)
    inside = cv2.resize(region, maps["planted"].shape[::-1], interpolation=cv2.INTER_NEAREST) > 0
    assert 0.05 < inside.mean() < 0.3
    planted, clean = maps["planted"], maps["clean"]
    # the damage is where it was planted: above the rest of the frame and above the clean clip there
    assert planted[inside].mean() > 1.4 * max(planted[~inside].mean(), clean[inside].mean())
    assert abs(planted[~inside].mean() - clean[~inside].mean()) < 0.005


def test_unkept_share_reads_neighbouring_pairs_at_the_largest_scale():
    res = np.array([0.1] * 30 + [5.0] * 10 + [0.1] * 40 + [9.0] * 5, np.float32)
    pairs = [(1, 1.0, 0, 40), (1, 0.5, 40, 80), (4, 1.0, 80, 85)]
    # 854 px wide at scale 1: 1 px; the gap-4 pair and the smaller scale do not count
    assert unkept_share(pairs, res, 854, CFG) == pytest.approx(10 / 40)
    assert unkept_share(pairs, res, 854 * 10, CFG) == pytest.approx(0.0)  # 10 px allowed
    assert unkept_share([(1, 1.0, 0, 5)], res, 854, CFG) is None  # too few matches
    assert unkept_share([], res, 854, CFG) is None


def _model(names: tuple[str, str] = ("a", "b")) -> ClipModel:
    a, b = names
    terms = (ModelTerm(a, "reading a", 0.5, 0.25, 2.0), ModelTerm(b, "reading b", 0.0, 1.0, 0.0))
    return ClipModel("test", -1.0, terms, 0.4, {})


def test_the_score_is_the_sum_of_its_contributions():
    m = _model()
    parts = m.contributions({"a": 1.0, "b": 3.0})
    assert parts == {"a": pytest.approx(4.0), "b": 0.0}
    assert m.score({"a": 1.0, "b": 3.0}) == pytest.approx(1 / (1 + math.exp(-3.0)))
    assert m.contributions({"a": None})["a"] == 0.0  # a missing reading says nothing
    assert m.score({"a": 0.9}) > m.score({"a": 0.6})  # monotone
    named = _model(("unkept", "flow_failure"))  # a model file names readings GeoCon makes
    back = ClipModel.from_dict(json.loads(json.dumps(named.to_dict())))
    assert back == named and back.digest() == named.digest()


@pytest.mark.parametrize(
    ("change", "words"),
    [
        (lambda d: d.update(format="other/1"), "not a geocon-clip-model/1 file"),
        (lambda d: d["terms"][0].update(weight=-1.0), "terms[0] ('unkept') weight is -1.0, and it must be at least 0"),
        (lambda d: d.update(threshold=1.5), "threshold is 1.5, outside (0, 1)"),
        (lambda d: d.pop("terms"), "has no field 'terms'"),
    ],
)
def test_a_bad_model_file_is_refused_with_its_reason(change, words):
    d = _model(("unkept", "flow_failure")).to_dict()
    change(d)
    with pytest.raises(ValueError, match=__import__("re").escape(words)):
        ClipModel.from_dict(d)


def test_the_fit_finds_the_reading_that_separates_and_its_threshold_spares_real_clips():
    rng = np.random.default_rng(0)
    n = 300
    broken = rng.random(n) < 0.3
    real = ~broken & (rng.random(n) < 0.5)
    signal = np.where(broken, rng.normal(1.0, 0.5, n), rng.normal(0.0, 0.5, n))
    noise = rng.normal(0.0, 1.0, n)
    against = np.where(broken, rng.normal(-1.0, 0.5, n), rng.normal(0.0, 0.5, n))  # larger = sounder
    readings = [{"s": float(s), "n": float(z), "x": float(x)} for s, z, x in zip(signal, noise, against, strict=True)]
    terms = [("s", "signal"), ("n", "noise"), ("x", "against")]
    groups = ["broken" if b else ("real" if r else "clean") for b, r in zip(broken, real, strict=True)]
    model = fit_clip_model(readings, list(broken), groups, list(real), terms, version="t")
    w = {t.name: t.weight for t in model.terms}
    assert w["s"] > 1.0
    assert w["n"] < 0.2 * w["s"]
    assert w["x"] == 0.0  # held at zero: a larger reading never lowers the score
    real_scores = [model.score(r) for r, k in zip(readings, real, strict=True) if k]
    assert sum(s >= model.threshold for s in real_scores) <= 0.05 * len(real_scores)
    caught = [model.score(r) >= model.threshold for r, b in zip(readings, broken, strict=True) if b]
    assert np.mean(caught) > 0.5
    again = fit_clip_model(readings, list(broken), groups, list(real), terms, version="t")
    assert again == model  # the same clips give the same model


def test_the_shipped_model_is_the_one_the_default_config_pins():
    cfg = preset("audit")
    model = load_clip_model(cfg.signals.model)
    assert cfg.signals.enabled
    assert model.digest() == cfg.signals.model_sha256
    assert set(model.names) <= set(READING_LABELS)
    assert all(t.weight >= 0 for t in model.terms) and 0 < model.threshold < 1


@pytest.mark.full
def test_readings_made_while_scoring_equal_those_read_again(scenes, scored_clip, tmp_path):
    from geocon_core.record import read_record, write_record
    from geocon_core.scoring import read_readings

    cfg = preset("audit")
    rec = scored_clip(_clip(scenes, "C4"), cfg)
    assert isinstance(rec.readings, ClipReadings) and rec.readings.appearance is not None
    write_record(rec, tmp_path / "rec")
    back = read_record(tmp_path / "rec")
    assert back.readings == rec.readings
    again = read_readings(replace(back, readings=None), tmp_path / "rec", cfg)
    assert again.readings == rec.readings
    finding = rec.finding()
    assert finding.parts and finding.clip_score == pytest.approx(
        load_clip_model(cfg.signals.model).score(rec.reading_values())
    )
    summary = rec.summary()
    weighed = {t.name for t in load_clip_model(cfg.signals.model).terms if t.weight > 0}
    assert set(summary["why"]) == weighed and len(weighed) >= 4


def test_a_decisive_background_failure_fails_the_clip_whatever_the_model_says():
    from geocon_core.record import ClipFinding
    from geocon_core.record.finding import model_finding

    m = _model()  # threshold 0.4; "a" at its center gives 1 / (1 + e) = 0.27: consistent
    background = ClipFinding("inconsistent", "the background breaks its H model", 0.99)
    calm = model_finding(background, {"a": 0.5, "shortfall": 2.0}, m, decisive_shortfall=6.0)
    assert calm.verdict == "consistent" and calm.clip_score == pytest.approx(m.score({"a": 0.5}))
    assert "stays under the model's 0.40" in calm.reason and "the background breaks" in calm.reason
    loud = model_finding(background, {"a": 0.5, "shortfall": 7.0}, m, decisive_shortfall=6.0)
    assert loud.verdict == "inconsistent" and loud.clip_score == 0.99
    assert loud.reason.startswith("the background fails decisively (7.0 gate ranges short, beyond 6)")
    flagged = model_finding(background, {"a": 1.0}, m)
    assert flagged.verdict == "inconsistent" and "reading a +4.00" in flagged.reason
    # a drifting layer fails the clip beside a background that fails its gate at all, not alone
    drifting = "a layer drifts 3.0 px across the camera's travel"
    both = model_finding(background, {"a": 0.5, "shortfall": 0.2}, m, decisive_shortfall=6.0, drift=drifting)
    assert both.verdict == "inconsistent" and both.clip_score == 0.99 and drifting in both.reason
    alone = model_finding(background, {"a": 0.5, "shortfall": -0.2}, m, decisive_shortfall=6.0, drift=drifting)
    assert alone.verdict == "consistent"
    # a background that cannot be judged: the clip is judged on its other readings, if it has any
    unjudged = ClipFinding("cannot judge", "too few valid pairs", None)
    judged = model_finding(unjudged, {"a": 1.0, "shortfall": None}, m)
    assert judged.verdict == "inconsistent" and judged.reason.endswith("too few valid pairs")
    assert model_finding(unjudged, {"a": None, "shortfall": None}, m) is unjudged


def test_the_fit_is_made_on_the_tune_half_and_reports_both_halves(tmp_path):
    from geocon_core.validation import FitCase, fit_markdown, fit_model

    rng = np.random.default_rng(1)
    cases = []
    for i in range(240):
        split = "tune" if i % 2 else "check"
        group = ("artifact", "clean", "real", "planted:morph", "reencode")[i % 5]
        broken = group in ("artifact", "planted:morph")
        # the reading separates the annotated clips; the planted ones read like their re-encodes
        shift = 1.0 if group == "artifact" else 0.0
        values = {"unkept": float(rng.normal(shift, 0.4)), "flow_failure": float(rng.normal(0, 1))}
        cases.append(FitCase(f"c{i}", split, broken, group != "clean", values, float(rng.random()), None, group))
    annotations = tmp_path / "a.csv"
    annotations.write_text("clip\n")
    report = fit_model(cases, version="t", annotations_path=annotations, terms=("unkept", "flow_failure"))
    weights = {t.name: t.weight for t in report.model.terms}
    assert weights["unkept"] > 1.0 and weights["flow_failure"] < 0.3
    assert report.model.fitted["clips"] == {"artifact": 24, "clean": 24, "real": 24}  # tune only, planted left out
    tune, check = report.rows
    assert tune.split == "tune" and check.split == "check"
    assert check.auc is not None and check.auc.estimate > 0.9
    assert check.peer is not None and check.difference is not None and check.difference.low > 0
    assert [k for k, _, _ in check.planted] == ["morph"] and check.reencode_flagged[1] == 24
    page = fit_markdown(report)
    assert "| check |" in page and "planted kind" in page and report.model.digest() in page


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["--fit", "--out", "{tmp}/none"], "no scored cases to fit on"),
        (["--fit-with", "{tmp}", "--out", "{tmp}/v"], "--fit-with adds cases to a fit; add --fit"),
    ],
)
def test_validate_fit_refuses_what_it_cannot_fit(tmp_path, args, words):
    from typer.testing import CliRunner

    from geocon_viewer.cli import app

    argv = ["validate", "--no-synthetic", "--no-real", *[a.format(tmp=tmp_path) for a in args]]
    result = CliRunner().invoke(app, argv)
    assert result.exit_code != 0 and words in " ".join(result.output.split()), result.output


@pytest.mark.full
def test_a_new_clip_model_reads_readings_and_keeps_the_background_fit(tmp_path, monkeypatch):
    """validate does not score a case again when only ``signals`` changed: the record gets the
    readings a fresh score would make and keeps its background fit; any other change scores again."""
    from geocon_core.config import config_hash
    from geocon_core.record import read_record
    from geocon_core.validation import CaseSpec, ValidationPlan
    from geocon_core.validation.runner import run_cases

    plan = ValidationPlan(heights=(256,), codecs=("png",), families=("C4",), frames=16, data=None)
    case = CaseSpec("C4__clean__h256__png", "synthetic", family="C4", height=256, codec="png")
    audit = preset("audit")
    without = replace(audit, signals=replace(audit.signals, enabled=False))
    cache, first, fresh = tmp_path / "cache", tmp_path / "a", tmp_path / "b"
    [(_, s0)] = run_cases([case], plan, without, first, cache, peer=False)
    before = read_record(first / "cases" / case.case_id)
    assert s0["status"] == "ok" and before.readings is None
    [(_, s1)] = run_cases([case], plan, audit, first, cache, peer=False)
    assert "readings_seconds" in s1 and s1["config_hash"] == config_hash(audit) != s0["config_hash"]
    refreshed = read_record(first / "cases" / case.case_id)
    [(_, s2)] = run_cases([case], plan, audit, fresh, cache, peer=False)
    scored = read_record(fresh / "cases" / case.case_id)
    assert "readings_seconds" not in s2
    assert refreshed.readings is not None and refreshed.readings == scored.readings
    assert refreshed.config_hash == scored.config_hash and refreshed.background == before.background
    assert refreshed.finding() == scored.finding()
    np.testing.assert_array_equal(refreshed.matches.f_res_px, before.matches.f_res_px)
    # the clip prepared again under another cache key (new renderer code) with the same bytes: kept
    import geocon_core.validation.runner as runner

    monkeypatch.setattr(runner, "code_digest", lambda: "another-renderer")
    [(_, again)] = run_cases([case], plan, audit, first, cache, peer=False)
    assert len(list(cache.iterdir())) == 2 and again == s1  # rendered again, not scored again
    # a record written before a setting of the background's existed is scored again, not read again
    record_json = first / "cases" / case.case_id / "record.json"
    doc = json.loads(record_json.read_text())
    del doc["config"]["multiview"]
    record_json.write_text(json.dumps(doc))
    refit = replace(audit, signals=replace(audit.signals, decisive_shortfall=7.0))
    [(_, s4)] = run_cases([case], plan, refit, first, cache, peer=False)
    assert "readings_seconds" not in s4 and s4["config_hash"] == config_hash(refit)
    other = replace(audit, ir_gate=audit.ir_gate + 0.01)  # a setting of the background fit: scored again
    [(_, s3)] = run_cases([case], plan, other, first, cache, peer=False)
    assert "readings_seconds" not in s3 and s3["config_hash"] == config_hash(other)
