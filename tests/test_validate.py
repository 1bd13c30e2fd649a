"""`geocon validate`: the table agrees with the records it wrote and with the planted truth."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from geocon_core.record import read_record
from geocon_core.synth import load_ground_truth
from geocon_core.validation import (
    ANNOTATIONS_PATH,
    CaseResult,
    ValidationPlan,
    compute_metrics,
    detected,
    plan_cases,
    read_annotations,
    real_clips,
)
from geocon_core.validation.metrics import OBJECT_RATIO
from geocon_viewer.cli import app

from .conftest import SHARED_DATA

runner = CliRunner()


def _row(**kw) -> CaseResult:
    base = dict(
        case_id="x", kind="synthetic", clip="x", family="C4", failure=None, level=None, severity=None, height=256,
        codec="png", source="synthetic", truth_gate="H", truth_category="C4", truth_movers=2, static_camera=True,
        stable_scene=True, verdict="consistent", gate="H", pose_present=True, objects=2, max_adadfrc=0.1,
        category="C4",
    )  # fmt: skip
    return CaseResult(**{**base, **kw})


def test_detection_rule_uses_background_or_five_times_the_clean_object_score():
    clean = _row()
    assert detected(_row(failure="elastic", level="high", verdict="inconsistent", max_adadfrc=0.1), clean)
    assert detected(_row(failure="elastic", level="high", max_adadfrc=0.5), clean)
    assert not detected(_row(failure="elastic", level="high", max_adadfrc=0.49), clean)
    assert not detected(_row(failure="slide", level="high", max_adadfrc=9.0), clean)  # objects count for elastic only
    assert not detected(_row(failure="elastic", level="high", verdict="not judged", max_adadfrc=9.0), None)


def test_metrics_count_every_case_in_its_row_and_leave_the_gray_zone_out():
    rows = [
        _row(case_id="a"),
        _row(case_id="b", height=1080, verdict="inconsistent", gate="F"),
        _row(case_id="c", truth_gate=None, gate="F"),  # gray zone: not in gate accuracy
        _row(case_id="d", failure="slide", level="middle", verdict="inconsistent"),
        _row(case_id="e", failure="slide", level="middle", height=1080),
        _row(case_id="f", kind="real", source="real", verdict="inconsistent", truth_movers=0, objects=3, group="tune"),
        _row(case_id="g", kind="real", source="real", verdict="not judged", group="tune"),
        _row(case_id="h", kind="real", source="real", verdict="consistent", group="check"),
        _row(case_id="i", kind="real", source="generated", verdict="inconsistent", group="check",
             artifact_kinds=("morphing",)),
        _row(case_id="j", kind="real", source="generated", verdict="consistent", group="check",
             artifact_kinds=("watermark",)),
        _row(case_id="k", kind="real", source="generated", verdict="inconsistent", group="check"),
    ]  # fmt: skip
    table = {(m.metric, m.subset): m for m in compute_metrics(rows)}
    gate = table["gate accuracy", "synthetic"]
    assert (gate.hits, gate.n) == (3, 4)  # a, d, e right; b wrong; c left out
    ff = table["false flags", "clean synthetic"]
    assert (ff.hits, ff.n, ff.ok) == (1, 3, False)
    assert ff.detail == "256: 0/2  1080: 1/1"
    det = table["detection", "slide middle (8 px)"]
    assert (det.hits, det.n, det.ok) == (1, 2, False)
    # real cameras: only "inconsistent" is a false flag; "cannot judge" is its own row; per half
    tune = table["false flags", "real-camera clips, tune half"]
    assert (tune.hits, tune.n, tune.ok, tune.detail) == (1, 2, False, "f")
    assert (
        table["cannot judge", "real-camera clips, tune half"].hits,
        table["cannot judge", "real-camera clips, tune half"].n,
    ) == (1, 2)
    assert (
        table["false flags", "real-camera clips, check half"].hits,
        table["false flags", "real-camera clips, check half"].n,
    ) == (0, 1)
    assert ("false flags", "real-camera clips, ../shared/data (rules chosen on it earlier)") not in table  # no case
    flagged = {s: (m.hits, m.n) for (metric, s), m in table.items() if metric == "flagged inconsistent"}
    assert flagged == {
        "generated, visible artifact, check half": (1, 2),
        "generated, geometric artifact, check half": (1, 1),
        "generated, clean-looking, check half": (1, 1),
    }
    objects = table["object count", "real clips, annotated"]
    assert (objects.hits, objects.n) == (5, 6)  # f: 3 tracks > 1.5 * 0 + 1; the others 2 <= 1.5 * 2 + 1


@pytest.mark.slow  # a whole quick validation run (about 20 s); `geocon validate` itself runs it in full
def test_quick_run_table_matches_its_records_and_the_planted_failure(tmp_path):
    out = tmp_path / "val"
    args = ["validate", "--quick", "--out", str(out), "--heights", "256", "--codecs", "png", "--families", "C4"]
    args += ["--failures", "elastic", "--levels", "high", "--no-real"]  # quick keeps 24 frames
    res = runner.invoke(app, args)
    assert res.exit_code == 0, res.output
    doc = json.loads((out / "validation.json").read_text())
    cases = {c["case_id"]: c for c in doc["cases"]}
    assert set(cases) == {"C4__clean__h256__png", "C4__elastic-high__h256__png"}
    for cid, row in cases.items():
        case_dir = out / "cases" / cid
        rec = read_record(case_dir)
        status = json.loads((case_dir / "case.json").read_text())
        gt = load_ground_truth(status["truth"])
        assert rec.video.num_frames == gt.num_frames == 24
        assert rec.video.source_size == (456, 256)
        assert row["ir"] == rec.background.ir and row["gate"] == rec.gate.label
        assert row["objects"] == len(rec.objects) and row["truth_movers"] == len(gt.objects)
        assert row["truth_gate"] == gt.expected_gate
        want = {None: "not judged", True: "consistent", False: "inconsistent"}[rec.background.consistent]
        assert row["verdict"] == want
    planted = load_ground_truth(json.loads((out / "cases/C4__elastic-high__h256__png/case.json").read_text())["truth"])
    assert planted.failure is not None and (planted.failure.kind, planted.failure.severity) == ("elastic", 8.0)
    metrics = {(m["metric"], m["subset"]): m for m in doc["metrics"]}
    det = metrics["detection", "elastic high (8 px)"]
    rows = [CaseResult(**c) for c in doc["cases"]]
    clean = next(r for r in rows if r.failure is None)
    damaged = next(r for r in rows if r.failure == "elastic")
    assert det["n"] == 1 and det["hits"] == int(detected(damaged, clean))
    # an 8 px non-affine warp of a moving object is found by its rigidity score (24 frames: both
    # movers are tracked, so the background is judged without them)
    assert det["hits"] == 1 and damaged.max_adadfrc >= OBJECT_RATIO * clean.max_adadfrc
    assert clean.verdict == "consistent" and clean.objects == clean.truth_movers == 2
    ff = metrics["false flags", "clean synthetic"]
    assert ff["n"] == 1 and ff["hits"] == int(clean.verdict != "consistent")
    cases_md = (out / "validation.md").read_text().split("## Cases")[1]
    assert "elastic high" in res.output and cases_md.count("C4__") == 2


def test_plan_covers_the_grid():
    cases = plan_cases(ValidationPlan(data=None))
    assert len(cases) == 5 * 3 * (6 + 3 * 3 + 2 * 2 * 3)  # slide along and across on C2 and C3
    assert {c.width for c in cases} == {456, 682, 910, 1280, 1920}
    with pytest.raises(ValueError, match="unknown codec"):
        ValidationPlan(codecs=("mp3",))


@pytest.mark.skipif(not SHARED_DATA.is_dir(), reason="needs ../shared/data")
def test_every_real_clip_is_annotated():
    notes = read_annotations(ANNOTATIONS_PATH)
    clips = {p.relative_to(SHARED_DATA).as_posix() for p in real_clips(SHARED_DATA)}
    assert clips == {a.clip for a in notes.values() if a.root == "data"}
    real2 = SHARED_DATA.parent / "real2"
    if real2.is_dir():
        assert {p.name for p in real_clips(real2)} == {a.clip for a in notes.values() if a.root == "real2"}
    assert "made by looking at frames" in Path(ANNOTATIONS_PATH).read_text().lower()
    for note in notes.values():
        assert note.source in ("real", "rendered", "generated")
        assert note.regime in ("static", "rotation", "zoom", "translation", "")
        assert note.gate is None or note.gate == ("F" if note.regime == "translation" else "H")
        assert note.camera in ("still", "handheld", "drone", "vehicle", "walkthrough", "orbit", "pan", "zoom")
        assert note.mover_size in ("none", "small", "large")
        if note.source == "generated":
            assert note.generator, note.key
        if note.root != "data":  # where it came from, so the footage can be fetched again and checked
            assert note.repo.count("/") == 1 and len(note.commit) == 40 and note.path and note.licence, note.key
            assert len(note.sha256) == 64, note.key


@pytest.mark.skipif(not SHARED_DATA.is_dir(), reason="needs ../shared/data")
def test_shared_clips_hash_as_annotated():
    """The annotation names the bytes it was made from: a clip replaced under the same name is caught."""
    import hashlib

    roots = {"data": SHARED_DATA, "real2": SHARED_DATA.parent / "real2"}
    for note in read_annotations(ANNOTATIONS_PATH).values():
        path = roots.get(note.root, Path("/nonexistent")) / note.clip
        if note.sha256 and path.is_file():
            assert hashlib.sha256(path.read_bytes()).hexdigest() == note.sha256, note.key


def test_the_split_is_seeded_balanced_and_fixed():
    from collections import Counter

    from geocon_core.validation import split_of
    from geocon_core.validation.cases import SPLIT_SEED

    assert SPLIT_SEED == "geocon-validation-split/2026-11-26"  # changing it re-deals every clip
    assert split_of("real2:skv_bikes.mp4") == split_of("real2:skv_bikes.mp4")
    notes = [a for a in read_annotations(ANNOTATIONS_PATH).values() if a.root != "data" and not a.exclude]
    for source in ("real", "generated"):
        halves = Counter(a.split for a in notes if a.source == source)
        total = sum(halves.values())
        assert total >= 60 and min(halves["tune"], halves["check"]) >= 0.4 * total, (source, halves)


HELD_OUT = """
guoyww/AnimateDiff hehao13/CameraCtrl Doubiiu/DynamiCrafter hao-ai-lab/FastVideo hpcaitech/Open-Sora
PKU-YuanGroup/Open-Sora-Plan THUDM/CogVideo TencentARC/MotionCtrl svg-project/Sparse-VideoGen Vchitect/VBench
Drexubery/ViewCrafter ByteDance-Seed/Depth-Anything-3 CMU-Perceptual-Computing-Lab/openpose HL-hanlin/Ctrl-Adapter
Junyi42/monst3r KwaiVGI/LivePortrait KwaiVGI/ReCamMaster NUS-HPC-AI-Lab/VideoSys OpenTalker/SadTalker
SkyworkAI/SkyReels-V2 TIGER-AI-Lab/AnyV2V Tencent/HunyuanVideo-I2V TencentARC/GeometryCrafter Vchitect/VEnhancer
Vchitect/Vchitect-2.0 YBYBZhang/ControlVideo ageitgey/face_recognition aigc-apps/VideoX-Fun ali-vilab/VACE
hkchengrex/MMAudio hohonu-vicml/Trailblazer luxonis/depthai-experiments maxin-cn/Cinemo nv-tlabs/vipe
nvidia-cosmos/cosmos-predict1 nvidia-cosmos/cosmos-transfer1 open-mmlab/FoleyCrafter rhymes-ai/Allegro
theAIGuysCode/yolov4-deepsort xingyizhou/CenterTrack
""".split()
"""Repositories whose samples are kept for an independent check: no clip is taken from them, except
the clips of the first eleven that the annotation file held before the list was drawn up."""


def test_the_annotated_set_is_large_enough_and_leaves_the_held_out_repositories_alone():
    from collections import Counter

    notes = [a for a in read_annotations(ANNOTATIONS_PATH).values() if not a.exclude]
    generated = [a for a in notes if a.source == "generated"]
    real = [a for a in notes if a.source == "real"]
    artifact = [a for a in generated if a.geometric_artifact]
    assert len(generated) >= 200 and len(artifact) >= 80 and len(generated) - len(artifact) >= 80
    assert len(real) >= 150
    repos = {a.repo.split()[0] for a in generated if a.repo}
    assert len(repos) >= 35, sorted(repos)
    for a in notes:
        owner_name = a.repo.split()[0].lower() if a.repo else ""
        held = [r.lower() for r in HELD_OUT]
        assert owner_name not in held[11:], a.key  # the first eleven keep their earlier clips
        assert owner_name != "zai-org/cogvideo", a.key  # THUDM/CogVideo under its new owner
    hashes = Counter(a.sha256 for a in notes if a.sha256)
    assert not [h for h, n in hashes.items() if n > 1], "the same bytes annotated twice"
    for source in (generated, real):
        halves = Counter(a.split for a in source)
        assert min(halves["tune"], halves["check"]) >= 0.4 * len(source), halves


def test_plan_takes_annotated_clips_of_every_root_and_one_half(tmp_path):
    from geocon_core.validation import Annotation, missing_clips

    def note(root: str, clip: str) -> Annotation:
        return Annotation(clip, "static", "H", 0, True, "real", True, "C1", "", "", root=root)

    for root in ("data", "real2", "footage"):
        (tmp_path / root).mkdir()
    for name in ("a.mp4", "b.mp4"):
        (tmp_path / "data" / name).write_bytes(b"x")
    (tmp_path / "real2" / "c.mp4").write_bytes(b"x")
    notes = {n.key: n for n in (note("data", "a.mp4"), note("real2", "c.mp4"), note("footage", "gone.mp4"))}
    plan = ValidationPlan(data=tmp_path / "data", real2=tmp_path / "real2", footage=tmp_path / "footage")
    cases = plan_cases(replace(plan, synthetic=False), notes)
    assert [c.case_id for c in cases] == ["real__a.mp4", "real__b.mp4", "real2__c.mp4"]
    assert cases[1].annotation is None and cases[2].annotation == notes["real2:c.mp4"]
    assert [a.key for a in missing_clips(plan, notes)] == ["footage:gone.mp4"]
    half = notes["real2:c.mp4"].split
    other = "check" if half == "tune" else "tune"
    only_other = plan_cases(replace(plan, synthetic=False, split=other), notes)
    assert [c.case_id for c in only_other] == ["real__a.mp4", "real__b.mp4"]  # data is never split


def test_footage_is_filled_from_a_clone_and_checked(tmp_path):
    import hashlib
    import subprocess

    from geocon_core.validation import Annotation, fill_footage, footage_status

    repo = tmp_path / "sources" / "someone+clips"
    repo.mkdir(parents=True)
    run = dict(cwd=repo, check=True, capture_output=True)
    subprocess.run(["git", "init", "-q"], **run)
    (repo / "v").mkdir()
    (repo / "v" / "clip.mp4").write_bytes(b"frames")
    subprocess.run(["git", "add", "."], **run)
    env = ["-c", "user.name=t", "-c", "user.email=t@t"]
    subprocess.run(["git", *env, "commit", "-q", "-m", "x"], **run)
    commit = subprocess.run(["git", "rev-parse", "HEAD"], **run, text=True).stdout.strip()
    good = hashlib.sha256(b"frames").hexdigest()

    def note(clip: str, sha: str, repo_name: str = "someone/clips") -> Annotation:
        return Annotation(
            clip, "static", "H", 0, True, "real", True, "C1", "", "", root="footage",
            repo=repo_name, commit=commit, path="v/clip.mp4", sha256=sha,
        )  # fmt: skip

    cache = tmp_path / "cache"
    notes = [note("real/ok.mp4", good), note("real/bad.mp4", "0" * 64), note("real/none.mp4", good, "other/repo")]
    assert [i.state for i in footage_status(notes, cache)] == ["missing"] * 3
    states = {i.annotation.clip: i for i in fill_footage(notes, cache, tmp_path / "sources")}
    assert states["real/ok.mp4"].state == "filled" and (cache / "real/ok.mp4").read_bytes() == b"frames"
    assert states["real/bad.mp4"].state == "wrong bytes" and not (cache / "real/bad.mp4").exists()
    assert states["real/none.mp4"].state == "no clone" and "git clone --bare https://github.com/other/repo" in (
        states["real/none.mp4"].detail
    )
    assert {i.annotation.clip: i.state for i in footage_status(notes, cache)}["real/ok.mp4"] == "present"


@pytest.mark.full
def test_worst_pair_note_names_the_lowest_ir_pair_and_how_far_its_outliers_lie(synth_dir, scored_clip):
    from geocon_core.config import preset
    from geocon_core.validation.results import worst_pair_note

    cfg = preset("audit").with_(masks="none", scales=(1.0,), gaps=(8,))
    rec = scored_clip(synth_dir / "c1_static__breathing-s3.mp4", cfg)
    fits = [(p, p.h) for p in rec.pairs if p.h is not None and p.h.valid]
    worst, fit = min(fits, key=lambda pf: (pf[1].ir, pf[0].t0))
    note = worst_pair_note(rec)
    assert note is not None and note.startswith(f"pair ({worst.t0}, {worst.t1}), gap 8: IR {fit.ir:.3f}")
    low = float(note.split(" outliers ")[1].split("-")[0])
    assert low >= cfg.tau_h  # an outlier lies beyond the inlier threshold (the note rounds to 0.1 px)
    assert fit.ir < 0.97  # a 3 px breathing background, 8 frames apart, loses inliers


def test_report_lists_flagged_clean_and_real_camera_clips_as_exceptions(tmp_path):
    from geocon_core.validation import ValidationReport, write_report

    rows = (
        _row(case_id="clean-ok"),
        _row(case_id="clean-flagged", verdict="inconsistent", ir=0.95, worst_pair="pair (0, 8), gap 8: IR 0.950"),
        _row(case_id="damaged", failure="breathing", level="high", verdict="inconsistent"),
        _row(case_id="real-flagged", kind="real", source="real", verdict="inconsistent"),
        _row(case_id="generated-flagged", kind="real", source="generated", verdict="inconsistent"),
    )
    report = ValidationReport((), rows, "audit", "0", 0.0, 0.0, ValidationPlan(), len(rows))
    md, _ = write_report(report, tmp_path)
    text = md.read_text()
    section = text.split("## Exceptions")[1].split("## ")[0]
    assert "clean-flagged" in section and "pair (0, 8), gap 8: IR 0.950" in section and "real-flagged" in section
    assert "clean-ok" not in section and "damaged" not in section and "generated-flagged" not in section
    # a flagged clean-looking generated clip is listed among the most confident flags, to be explained
    confident = text.split("## The five most confident flags of clean-looking generated clips")[1].split("## ")[0]
    assert "generated-flagged" in confident and "real-flagged" not in confident


def test_seed_option_renders_other_scenes_for_a_held_out_check(tmp_path):
    cache = tmp_path / "cache"
    clips = {}
    for seed in (0, 1):
        out = tmp_path / f"seed{seed}"
        args = ["validate", "--out", str(out), "--cache", str(cache), "--seed", str(seed), "--heights", "64"]
        args += ["--codecs", "png", "--families", "C1", "--failures", "none", "--frames", "4", "--no-real"]
        res = runner.invoke(app, args)
        assert res.exit_code == 0, res.output
        status = json.loads((out / "cases" / "C1__clean__h64__png" / "case.json").read_text())
        assert load_ground_truth(status["truth"]).seed == seed
        assert json.loads((out / "validation.json").read_text())["plan"]["seed"] == seed
        assert f"scene seed {seed}" in (out / "validation.md").read_text()
        clips[seed] = status["clip"]
    assert clips[0] != clips[1]  # its own rendering, not the cached scene of the other seed


def test_track_coverage_is_the_least_single_track_share_over_the_movers():
    from geocon_core.validation.results import track_coverage

    T, H, W = 10, 60, 80
    truth = np.zeros((T, H, W), np.uint8)
    labels = np.zeros((T, H, W), np.uint16)
    truth[:, 5:25, 5:25] = 1  # mover 1: 400 px
    truth[:, 30:50, 40:70] = 2  # mover 2: 600 px
    labels[:8, 5:25, 5:25] = 5  # mover 1 followed by track 5 for 8 frames ...
    labels[8:, 5:25, 5:25] = 7  # ... then by a second id: 8 / 10 of its frames on one track
    labels[:, 30:50, 40:70] = 3
    labels[:3, 30:50, 40:70] = 0
    labels[:3, 30:40, 40:70] = 3  # half the mover: IoU 0.5, still covered
    labels[3:6, 30:50, 40:70] = 0
    labels[3:6, 30:35, 40:70] = 3  # a quarter: IoU 0.25, not covered -> 7 / 10
    assert track_coverage(labels, list(truth)) == pytest.approx(0.7)
    truth_big = np.repeat(np.repeat(truth, 2, axis=1), 2, axis=2)  # true masks at twice the size
    assert track_coverage(labels, list(truth_big)) == pytest.approx(0.7)
    truth[:, :, :] = 0
    truth[:, 0:5, 0:5] = 1  # 25 px: never visible enough to count
    assert track_coverage(labels, list(truth)) is None


def test_identity_rows_count_followed_movers_phantoms_and_still_camera_categories():
    rows = [
        _row(case_id="a", track_coverage=0.95),
        _row(case_id="b", track_coverage=0.6, category="C2"),
        _row(case_id="c", family="C3", truth_movers=0, static_camera=False, objects=0, category="C3", truth_gate="F"),
        _row(case_id="d", family="C3", truth_movers=0, static_camera=False, objects=2, category="C5", truth_gate="F"),
        _row(case_id="e", kind="real", source="real", truth_movers=0, static_camera=False, objects=1, category="C3"),
    ]
    table = {(m.metric, m.subset): m for m in compute_metrics(rows)}
    ident = table["object identity", "clean synthetic with movers"]
    assert (ident.hits, ident.n, ident.ok) == (1, 2, False) and ident.detail == "C4: 1/2;  least coverage 0.60"
    phantom = table["no phantom objects", "clean synthetic, moving camera"]
    assert (phantom.hits, phantom.n) == (1, 2)
    assert table["no phantom objects", "real camera, annotated"].hits == 0
    c4 = table["category C4", "still camera with movers, clean synthetic"]
    assert (c4.hits, c4.n) == (1, 2)


def test_report_only_says_when_planned_cases_have_no_record(tmp_path):
    args = ["validate", "--report-only", "--out", str(tmp_path / "empty"), "--heights", "64", "--codecs", "png"]
    args += ["--families", "C1", "--failures", "none", "--frames", "4", "--no-real"]
    res = runner.invoke(app, args)
    assert res.exit_code == 0, res.output
    assert "1 of 1 planned cases have no record" in " ".join(res.output.split())
    assert not (tmp_path / "empty" / "cache").exists() or not any((tmp_path / "empty" / "cache").iterdir())


def test_auc_rows_put_the_clip_score_beside_the_peer_on_each_half():
    gen = dict(kind="real", source="generated")
    rows = [
        # check half: artifacts score above clean clips for GeoCon; the peer ranks them the other way
        _row(case_id="a1", group="check", artifact_kinds=("morphing",), clip_score=0.9, peer_score=0.1, **gen),
        _row(case_id="a2", group="check", artifact_kinds=("melting",), clip_score=0.8, peer_score=0.2,
             verdict="inconsistent", **gen),
        _row(case_id="c1", group="check", clip_score=0.2, peer_score=0.5, verdict="inconsistent", **gen),
        _row(case_id="c2", group="check", clip_score=None, peer_score=0.6, verdict="not judged", **gen),
        _row(case_id="r1", group="check", kind="real", source="real", clip_score=0.1, peer_score=0.55,
             f_within=(0.5, 0.8, 0.9, 1.0), tau_f_px=6.0),
        _row(case_id="r2", group="check", kind="real", source="real", clip_score=0.1, peer_score=0.05,
             f_within=(0.7, 0.9, 1.0, 1.0), tau_f_px=8.0),
        # tune half: reported, no target
        _row(case_id="t1", group="tune", artifact_kinds=("morphing",), clip_score=0.3, peer_score=0.9, **gen),
        _row(case_id="t2", group="tune", clip_score=0.6, peer_score=0.1, **gen),
    ]  # fmt: skip
    table = {(m.metric, m.subset): m for m in compute_metrics(rows)}
    vis = table["AUC, clip score (visible artifact vs clean-looking generated)", "check half"]
    assert (vis.value, vis.hits, vis.n, vis.ok) == (1.0, 2, 4, True)  # c2 (cannot judge) counts at 0.5
    assert vis.detail == (
        "peer 0.00 [0.00, 0.00]; GeoCon - peer +1.00 [+1.00, +1.00]: too few clips (2 vs 2) to tell the two apart; "
        "1 not judged counted at 0.5"
    )
    geo = table["AUC, clip score (geometric artifact vs clean-looking generated)", "check half"]
    assert geo.ok is True and geo.target == ">= 0.80"
    real = table["AUC, clip score (generated vs real cameras)", "check half"]
    assert (real.hits, real.n) == (4, 6) and real.detail.startswith("peer 0.62")  # 5 of 8 pairs for the peer
    tune = table["AUC, clip score (visible artifact vs clean-looking generated)", "tune half"]
    assert (tune.value, tune.ok, tune.target) == (0.0, None, "reported")
    # flag rates beside the peer at GeoCon's clean-looking flag rate (1 of 2 -> the peer's top clean score, 0.6)
    clean = table["flagged inconsistent, GeoCon", "clean-looking generated, check half"]
    assert (clean.hits, clean.n) == (1, 2)
    assert clean.detail.startswith("peer at the same clean-looking rate: 50% [9%, 91%] (1/2); GeoCon - peer +0 points")
    loose = table["F keeps within 1 px (median share)", "real cameras, check half"]
    assert loose.value == pytest.approx(0.85) and loose.n == 2
    assert loose.detail == "0.5 px 0.60 · 1 px 0.85 · 2 px 0.95 · 4 px 1.00; tau_F ~ 7.0 px (median)"
    cams = table["flagged inconsistent, GeoCon", "real cameras, check half"]
    assert (cams.hits, cams.n) == (0, 2)
    assert cams.detail.startswith("peer at the same clean-looking rate: 0% [0%, 66%] (0/2); GeoCon - peer +0 points")
