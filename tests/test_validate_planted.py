"""`geocon validate --planted`: failures planted into annotated real-camera clips, each beside a
clean re-encode of its source, rendered once into the cache and reported per kind, severity and
set against the clean re-encodes (and the peer)."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

import geocon_core.plant as plant
from geocon_core.validation import (
    PLANT_KINDS,
    PLANT_LEVELS,
    CaseResult,
    ValidationPlan,
    compute_metrics,
    plan_cases,
    planted_rows,
    read_annotations,
    reencode_rows,
)
from geocon_core.validation.prepare import clip_for, prepare_case, prepare_key, source_sha256
from geocon_viewer.cli import app

from .conftest import SHARED_DATA
from .test_validate import _row

runner = CliRunner()
WALK = SHARED_DATA / "real" / "realestate10k" / "0bf152ef84195293.mp4"
"""A short real walk-through (16 frames of 384x256), cut to 12 frames below."""
HEADER = "clip,regime,gate,movers,static_camera,source,stable_scene,category,artifacts,note,root,exclude\n"


def _annotations(path: Path, rows: list[str]) -> Path:
    path.write_text(HEADER + "".join(f"{r}\n" for r in rows))
    return path


def test_the_planted_kinds_and_severities_are_geocon_plants():
    assert PLANT_KINDS == tuple(plant.PLANT_KINDS) and PLANT_LEVELS == plant.LEVELS


def test_plan_plants_every_annotated_real_camera_clip_of_the_half(tmp_path):
    for name in ("a.mp4", "b.mp4", "gen.mp4", "gone.mp4"):
        (tmp_path / name).write_bytes(b"x")
    notes = read_annotations(
        _annotations(
            tmp_path / "notes.csv",
            [
                "a.mp4,pan,H,0,no,real,yes,C2,,,real2,",
                "b.mp4,pan,H,0,no,real,yes,C2,,,real2,",
                "gen.mp4,pan,H,0,no,generated,yes,C2,,,real2,",  # generated: not a planted source
                "gone.mp4,pan,H,0,no,real,yes,C2,,,real2,a duplicate",  # excluded
                "missing.mp4,pan,H,0,no,real,yes,C2,,,real2,",  # not present
            ],
        )
    )
    plan = ValidationPlan(synthetic=False, real2=tmp_path, planted=True, plant_kinds=("slide", "morph"), seed=3)
    cases = plan_cases(plan, notes)
    planted = [c for c in cases if c.kind == "planted"]
    assert len(planted) == 2 * (2 * 3 + 1) and len(cases) == len(planted) + 3  # and the three real clips
    a = [c for c in planted if c.annotation is not None and c.annotation.clip == "a.mp4"]
    assert [c.case_id for c in a[:2]] == ["planted__real2__a.mp4__clean", "planted__real2__a.mp4__slide-low-s3"]
    assert {(c.failure, c.level, c.severity) for c in a} == {
        (None, None, None),
        *((k, lv, plant.amplitude_of(k, lv)) for k in ("slide", "morph") for lv in PLANT_LEVELS),
    }
    # --no-real: the clips are only the planted cases' sources; --split: one half only
    alone = plan_cases(ValidationPlan(synthetic=False, real2=tmp_path, planted=True, real=False), notes)
    assert alone and all(c.kind == "planted" for c in alone)
    half = notes["real2:a.mp4"].split
    kept = plan_cases(ValidationPlan(synthetic=False, real2=tmp_path, planted=True, real=False, split=half), notes)
    assert {c.annotation.key for c in kept if c.annotation} == {
        k for k in ("real2:a.mp4", "real2:b.mp4") if notes[k].split == half
    }
    with pytest.raises(ValueError, match="unknown severity 'huge'"):
        ValidationPlan(planted=True, plant_levels=("huge",))
    with pytest.raises(ValueError, match="--severity lists none"):
        ValidationPlan(planted=True, plant_levels=())


def test_cache_key_follows_source_bytes_kind_severity_seed_and_frames(tmp_path):
    src = tmp_path / "clip.mp4"
    src.write_bytes(b"one")
    notes = read_annotations(_annotations(tmp_path / "n.csv", ["clip.mp4,pan,H,0,no,real,yes,C2,,,real2,"]))

    def keys(**kw) -> dict[str, str]:
        plan = ValidationPlan(synthetic=False, real2=tmp_path, planted=True, real=False, **kw)
        return {c.case_id.rsplit("__", 1)[1]: prepare_key(c, plan, "") for c in plan_cases(plan, notes)}

    base = keys(plant_kinds=("slide",))
    assert len(set(base.values())) == 4  # clean, and slide at three severities
    seed = keys(plant_kinds=("slide",), seed=1)
    assert seed["clean"] == base["clean"]  # the clean re-encode depends on neither kind, severity nor seed
    assert seed["slide-high-s1"] != base["slide-high-s0"]
    frames = keys(plant_kinds=("slide",), max_frames=12)
    assert not set(frames.values()) & set(base.values())
    src.write_bytes(b"two")  # the same name, other bytes: everything is planted again
    assert not set(keys(plant_kinds=("slide",)).values()) & set(base.values())
    # a folder of frames is keyed by its frames' names and bytes
    frames_dir = tmp_path / "frames"
    frames_dir.mkdir()
    for i in range(2):
        cv2.imwrite(str(frames_dir / f"{i:03d}.png"), np.full((8, 8, 3), i, np.uint8))
    first = source_sha256(frames_dir)
    cv2.imwrite(str(frames_dir / "001.png"), np.full((8, 8, 3), 9, np.uint8))
    assert source_sha256(frames_dir) != first


def test_a_clip_that_cannot_be_planted_fails_its_cases_with_the_reason(tmp_path):
    frames_dir = tmp_path / "src" / "frames"
    frames_dir.mkdir(parents=True)
    for i in range(3):
        cv2.imwrite(str(frames_dir / f"{i:03d}.png"), np.full((16, 16, 3), 40 * i, np.uint8))
    notes = read_annotations(_annotations(tmp_path / "n.csv", ["frames,still,H,0,yes,real,yes,C1,,,real2,"]))
    plan = ValidationPlan(synthetic=False, real2=tmp_path / "src", planted=True, real=False, plant_kinds=("slide",))
    case = plan_cases(plan, notes)[1]
    folder = prepare_case(case, plan, tmp_path / "cache", "", ())
    with pytest.raises(ValueError, match="could not be planted: .*folder of frames"):
        clip_for(case, folder)


def test_planted_rows_pair_each_planted_clip_with_its_own_clean_reencode():
    def rows(half: str, scene: str, clean: float, slid: float, peer_clean: float, peer_slid: float, **kw):
        common = dict(kind="planted", source="real", group=half, scene=scene, family=None, height=None, codec=None)
        original = dict(kind="real", source="real", group=half, scene=scene, family=None, height=None, codec=None)
        return [
            _row(case_id=f"{scene}-orig", **original, clip_score=clean, verdict=kw.get("orig", "consistent")),
            _row(case_id=f"{scene}-clean", **common, clip_score=clean, peer_score=peer_clean,
                 verdict=kw.get("clean_verdict", "consistent")),
            _row(case_id=f"{scene}-slide", **common, failure="breathing", level="high", severity=10.0,
                 clip_score=slid, peer_score=peer_slid, verdict=kw.get("verdict", "consistent")),
        ]  # fmt: skip

    cases: list[CaseResult] = []
    for i in range(6):  # tune half: GeoCon ranks every planted clip above every clean one, the peer half of them
        cases += rows(
            "tune", f"t{i}", 0.1, 0.9, 0.5, 0.4 + 0.2 * (i % 2), verdict="inconsistent" if i < 3 else "consistent"
        )
    cases += rows("check", "c0", 0.2, 0.2, 0.3, 0.3, clean_verdict="inconsistent", orig="consistent")
    table = {(r.group, r.kind, r.level): r for r in planted_rows(cases)}
    assert set(table) == {("tune", "breathing", "high"), ("check", "breathing", "high"), ("all", "breathing", "high")}
    tune = table["tune", "breathing", "high"]
    assert (tune.n, tune.detected, tune.clean_n, tune.clean_flags) == (6, 3, 6, 0)
    assert tune.detection is not None and (tune.detection.low, tune.detection.high) == pytest.approx(
        (0.188, 0.812), abs=1e-3
    )
    assert tune.auc is not None and tune.auc.estimate == 1.0
    assert tune.peer_auc is not None and tune.peer_auc.estimate == pytest.approx((3 * 6 + 0) / 36)  # 0.6 beats 0.5
    assert tune.difference is not None and tune.difference.estimate == pytest.approx(0.5)
    assert "GeoCon - peer +0.50 [" in tune.detail and (tune.own_pairs, tune.above_own, tune.peer_above_own) == (6, 6, 3)
    assert "planted clip scored above its own clean re-encode: GeoCon 6/6, peer 3/6" in tune.detail
    check = table["check", "breathing", "high"]
    assert (check.n, check.detected, check.clean_flags, check.auc.estimate if check.auc else None) == (1, 0, 1, 0.5)
    assert "too few clips (1 vs 1) to tell the two apart" in check.detail
    assert table["all", "breathing", "high"].n == 7
    lines = {r.group: r for r in reencode_rows(cases)}
    assert (lines["check"].reencode_flags, lines["check"].original_flags, lines["tune"].n) == (1, 0, 6)
    assert lines["tune"].detail.endswith("the interval includes 0, so the two cannot be told apart on these clips")
    # planted cases never count in the synthetic rows of the same failure's name, nor as real clips
    metrics = {(m.metric, m.subset) for m in compute_metrics(cases)}
    assert not any(metric == "detection" for metric, _ in metrics)
    ff = next(m for m in compute_metrics(cases) if m.metric == "false flags" and "tune" in m.subset)
    assert ff.n == 6


@pytest.mark.full
@pytest.mark.skipif(not WALK.is_file(), reason="needs ../shared/data")
def test_planted_run_scores_planted_and_clean_cases_once_and_reports_them(tmp_path):
    data = tmp_path / "data"
    data.mkdir()
    shutil.copy(WALK, data / "walk.mp4")
    notes = _annotations(tmp_path / "notes.csv", ["walk.mp4,translation,F,0,no,real,yes,C5,,a walk-through,data,"])
    out = tmp_path / "val"
    args = ["validate", "--planted", "--plant-kinds", "slide", "--severity", "high", "--no-synthetic", "--no-peer"]
    args += ["--annotations", str(notes), "--data", str(data), "--real2", str(tmp_path / "none")]
    args += ["--footage", str(tmp_path / "none"), "--max-frames", "12", "--out", str(out)]
    res = runner.invoke(app, args)
    assert res.exit_code == 0, res.output
    doc = json.loads((out / "validation.json").read_text())
    cases = {c["case_id"]: CaseResult(**{**c, "artifact_kinds": tuple(c["artifact_kinds"])}) for c in doc["cases"]}
    slid, clean = "planted__real__walk.mp4__slide-high-s0", "planted__real__walk.mp4__clean"
    assert set(cases) == {"real__walk.mp4", slid, clean}
    assert {r.scene for r in cases.values()} == {"data:walk.mp4"} and {r.group for r in cases.values()} == {"data"}
    assert cases[slid].planted and cases[clean].reencode and cases[slid].severity == 10.0
    assert all(r.verdict != "failed" and r.clip_score is not None for r in cases.values())
    # the planted clip and the clean re-encode: 12 frames of the source, the re-encode the very bytes
    # `geocon plant` writes as the planted clip's clean twin
    status = {cid: json.loads((out / "cases" / cid / "case.json").read_text()) for cid in (slid, clean)}
    truth = plant.read_plant_truth(status[slid]["truth"])
    assert truth["source"]["frames_used"] == 12 and truth["kind"] == "slide" and truth["seed"] == 0
    assert plant.probe_source(Path(status[clean]["clip"])).sha256 == truth["clean"]["sha256"]
    # the report: one row with its intervals, the re-encode line, what was rendered
    (row,) = doc["planted"]["rows"]
    assert (row["kind"], row["level"], row["group"], row["n"], row["clean_n"]) == ("slide", "high", "data", 1, 1)
    assert row["detection"]["low"] == 0.0 and row["false_flags"]["high"] > 0.7 and row["auc"] is not None
    assert row["peer_auc"] is None and "no peer score" in row["detail"]
    made = doc["planted"]["cache"]
    assert (made["rendered"], made["reused"], made["clean_rendered"], made["clean_reused"]) == (1, 0, 1, 0)
    md = (out / "validation.md").read_text()
    assert "## Planted failures" in md and "| slide | high (10 px) | ../shared/data | " in md
    assert "Planted clips: 1 rendered in this run, 0 reused from the cache" in md
    assert "- ../shared/data: clean re-encodes " in md
    assert "Planted failures" in res.output
    assert re.search(r"this run took \d+ (s|min \d\d s) with 1 worker process\n", res.output), res.output[-300:]
    # a second run renders and scores nothing again
    made = {p: p.stat().st_mtime_ns for p in (out / "cache").glob("*/done.json")}
    scored = {p: p.stat().st_mtime_ns for p in (out / "cases").glob("*/case.json")}
    res = runner.invoke(app, args)
    assert res.exit_code == 0, res.output
    again = json.loads((out / "validation.json").read_text())["planted"]["cache"]
    assert (again["rendered"], again["reused"], again["clean_rendered"], again["clean_reused"]) == (0, 1, 0, 1)
    assert {p: p.stat().st_mtime_ns for p in (out / "cache").glob("*/done.json")} == made
    assert {p: p.stat().st_mtime_ns for p in (out / "cases").glob("*/case.json")} == scored


@pytest.mark.parametrize(
    ("option", "value", "words"),
    [
        ("--severity", "high,bogus", "unknown severity 'bogus'"),
        ("--severity", "high,HIGH", "--severity lists HIGH twice"),
        ("--plant-kinds", "melt", "unknown planted kind 'melt'"),
        ("--plant-kinds", ",", "--plant-kinds lists none"),
    ],
)
def test_bad_planted_lists_are_refused_in_one_line(tmp_path, option, value, words):
    args = ["validate", "--planted", option, value, "--no-synthetic", "--no-peer", "--out", str(tmp_path / "v")]
    res = runner.invoke(app, [*args, "--data", str(tmp_path)])
    lines = [line for line in res.stderr.splitlines() if line.strip()]
    assert res.exit_code == 2 and len(lines) == 1 and lines[0].startswith("error: ") and words in lines[0], res.stderr
    assert not (tmp_path / "v").exists()


def test_planted_options_without_planted_are_refused(tmp_path):
    res = runner.invoke(app, ["validate", "--severity", "high", "--no-real", "--out", str(tmp_path / "v")])
    assert res.exit_code == 2 and res.stderr.strip() == (
        "error: --severity chooses the planted cases; add --planted (the synthetic severities are --levels)"
    )
