"""`geocon bench` end to end on a synthetic benchmark with known truth: rankings, calibration,
failures counted, and a killed run that resumes without losing or re-scoring a clip."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pd = pytest.importorskip("pandas")
pytest.importorskip("pyarrow")

from geocon_core.bench import (  # noqa: E402
    COLUMNS,
    read_status,  # noqa: E402
    read_tables,
)
from geocon_core.record import read_record  # noqa: E402
from geocon_core.scoring import is_flagged  # noqa: E402
from geocon_core.synth import plan_benchmark, write_benchmark  # noqa: E402

from .bad_inputs import broken_bench_clip  # noqa: E402
from .proc_group import kill_parent_alone  # noqa: E402

GEOCON = [sys.executable, "-m", "geocon_viewer.cli"]
BENCH_ARGS = ["--workers", "2", "--working-size", "640x360"]


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("bench-data")
    write_benchmark(root, plan_benchmark(families=("C1", "C3", "C4"), scenes=2), width=320, height=180, num_frames=12)
    broken_bench_clip(root)
    return root


def _run(*args: str, **kw) -> subprocess.CompletedProcess:
    return subprocess.run([*GEOCON, *args], capture_output=True, text=True, timeout=600, **kw)


@pytest.fixture(scope="module")
def results(dataset, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("bench-results") / "r"
    proc = _run("bench", str(dataset), "--out", str(out), *BENCH_ARGS)
    assert proc.returncode == 0, proc.stderr
    assert "19 clips: 18 scored, 1 failed" in proc.stdout
    return out


@pytest.mark.full
def test_tables_hold_every_clip_and_count_the_failure(results):
    t = read_tables(results)
    clips = t["clips"]
    assert list(clips.columns) == COLUMNS["clips"]
    assert len(clips) == 19 and clips["clip_id"].is_unique
    failed = clips[clips["status"] == "failed"]
    assert list(failed["clip_id"]) == ["broken-c1"]
    assert "002.png" in failed["error"].iloc[0]
    ok = clips[clips["status"] == "ok"]
    assert (ok["gate_model"] == ok["expected_model"]).all()  # the synthetic truth gates as expected
    # pair and object tables agree with the records
    rec = json.loads((results / "clips" / "clean-c4_objects-s0" / "record.json").read_text())
    pairs = t["pairs"][t["pairs"]["clip_id"] == "clean-c4_objects-s0"]
    assert len(pairs) == len(rec["pairs"]) and pairs["h_inliers"].tolist() == [
        0 if p["h"] is None else p["h"]["n_inliers"]
        for p in rec["pairs"]  # 0: a skipped pair-scale
    ]
    objs = t["objects"][t["objects"]["clip_id"] == "clean-c4_objects-s0"]
    assert objs["adap90"].tolist() == [o["adap90"] for o in rec["objects"]]
    # the sensitivity scan at the recorded thresholds equals the clip's IR/GE exactly
    s = t["sensitivity"]
    chosen_default = s[s["is_default"] & s["chosen"]].set_index("clip_id")
    merged = ok.set_index("clip_id")[["ir", "ge"]].join(chosen_default[["ir", "ge"]].add_suffix("_scan"))
    assert (merged["ir"] == merged["ir_scan"]).all() and (merged["ge"] == merged["ge_scan"]).all()


@pytest.mark.full
def test_platform_with_breathing_ranks_worse_on_background_and_elastic_on_objects(results):
    from geocon_core.report import scene_balanced_median

    t = read_tables(results)
    ok = t["clips"][t["clips"]["status"] == "ok"]
    ge = {m: scene_balanced_median(g["ge"], g["scene_id"]) for m, g in ok.groupby("model")}
    assert max(ge, key=ge.get) == "breathing"
    assert ge["breathing"] > 2 * ge["clean"]
    objs = t["objects"]
    ada = {m: scene_balanced_median(g["adap90"], g["scene_id"]) for m, g in objs.groupby("model")}
    assert max(ada, key=ada.get) == "elastic"


@pytest.mark.full
def test_calibration_picks_a_threshold_where_the_truth_separates(results, dataset):
    from geocon_core.report import bootstrap_tau

    truth = {}
    for gt in dataset.rglob("*.gt.json"):
        meta = json.loads(gt.with_name(gt.name.replace(".gt.json", ".meta.json")).read_text())
        truth[meta["clip_id"]] = json.loads(gt.read_text())["t_inf"]
    ok = read_tables(results)["clips"].query("status == 'ok'")
    is_f = (ok["expected_model"] == "F").to_numpy()
    true_t = ok["clip_id"].map(truth).to_numpy()
    low, high = true_t[~is_f].max(), true_t[is_f].min()
    assert low < high  # the synthetic truth separates the classes
    boot = bootstrap_tau(ok["t_inf"].to_numpy(), is_f, B=400, seed=0)
    assert low < boot.best_tau < high
    assert int(np.sum(boot.argmax_counts)) == 400


@pytest.mark.full
def test_flagged_clips_get_a_recording_linked_from_the_table(results):
    clips = read_tables(results)["clips"].query("status == 'ok'")
    for row in clips.itertuples():
        status = read_status(results / row.record)
        summary = json.loads((results / row.record / "record.json").read_text())["summary"]
        flagged = is_flagged(
            consistent=summary["background"]["consistent"],
            pose_present=summary["gate"]["pose_present"],
            gate_model=summary["gate"]["model"],
            expected_model=row.expected_model,
            finding=read_record(results / row.record).model_verdict(),
        )
        if importlib_has_rerun():
            assert isinstance(row.rrd, str) == flagged, row.clip_id  # a missing path reads as NaN
            if flagged:
                assert (results / row.rrd).stat().st_size > 0 and status["rrd"] == "audit.rrd"


def importlib_has_rerun() -> bool:
    import importlib.util

    return importlib.util.find_spec("rerun") is not None


@pytest.mark.slow
def test_killed_run_resumes_without_losing_or_rescoring_a_clip(dataset, results, tmp_path):
    """kill -9 of the `geocon bench` process alone (not its process group, as a user's kill does):
    its workers and the resource tracker exit within 5 s, the lock file it leaves is taken over, and
    the rerun's tables equal an uninterrupted run's. (tests/test_bench_hygiene.py does the same on
    a smaller dataset in the default run.)"""
    out = tmp_path / "r"
    proc = subprocess.Popen(
        [*GEOCON, "bench", str(dataset), "--out", str(out), *BENCH_ARGS],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline:
        done = list(out.glob("clips/*/status.json"))
        if len(done) >= 5 or proc.poll() is not None:
            break
        time.sleep(0.2)
    kill_parent_alone(proc)  # a hard kill of the parent: its workers must die mid-clip
    before = {p.parent.name: (p.stat().st_mtime_ns, p.read_bytes()) for p in out.glob("clips/*/status.json")}
    assert 5 <= len(before) < 19
    assert not (out / "tables").exists()
    assert json.loads((out / "bench.lock").read_text())["pid"] == proc.pid  # the dead run's lock, taken over
    again = _run("bench", str(dataset), "--out", str(out), *BENCH_ARGS)
    assert again.returncode == 0, again.stderr
    assert f"resuming: {len(before)} clip(s) already finished" in again.stderr
    assert f"({19 - len(before)} in this run, {len(before)} finished earlier)" in again.stdout
    assert not (out / "bench.lock").exists()
    for name, (mtime, data) in before.items():  # finished clips were not scored again
        status = out / "clips" / name / "status.json"
        assert status.stat().st_mtime_ns == mtime and status.read_bytes() == data
    a, b = read_tables(results), read_tables(out)
    for name in a:
        pd.testing.assert_frame_equal(a[name], b[name], check_exact=True)


@pytest.mark.full
def test_resuming_with_other_settings_is_refused(dataset, results, tmp_path):
    out = tmp_path / "r"
    shutil.copytree(results, out)
    proc = _run("bench", str(dataset), "--out", str(out), "--preset", "strict", "--working-size", "640x360")
    assert proc.returncode == 2
    assert "scored with another configuration" in proc.stderr


def test_invalid_dataset_exits_2_listing_problems(tmp_path):
    (tmp_path / "a.meta.json").write_text(json.dumps({"clip_id": "a"}))
    proc = _run("bench", str(tmp_path), "--out", str(tmp_path / "out"))
    assert proc.returncode == 2
    assert "a.meta.json: missing fields" in proc.stderr and "no clip file" in proc.stderr
    assert not (tmp_path / "out").exists()


@pytest.mark.slow  # the full report with its bootstrap (about 20 s)
def test_report_is_self_contained_and_names_its_config(results, tmp_path):
    import re

    from geocon_core.report import build_report, scene_balanced_median

    out = tmp_path / "report"
    proc = _run("report", str(results), "--out", str(out), "--bootstrap", "500")
    assert proc.returncode == 0, proc.stderr
    page = (out / "report.html").read_text()
    bench = json.loads((results / "bench.json").read_text())
    assert bench["config_hash"] in page
    refs = re.findall(r'(?:src|href)="([^"]+)"', page)
    assert refs and not [r for r in refs if r.startswith(("http:", "https:", "//"))]  # opens offline
    assert page.count('src="data:image/png;base64,') >= 8
    for name in (
        "tinf",
        "margins",
        "calibration",
        "net_benefit_bootstrap",
        "ridgelines",
        "effect_sizes",
        "adap90",
        "top_objects",
        "sensitivity",
    ):
        assert (out / "figures" / f"{name}.png").is_file() and (out / "figures" / f"{name}.svg").is_file()
        assert bench["config_hash"] in (out / "figures" / f"{name}.svg").read_text()  # every figure names its config
    assert "broken-c1" in page and "002.png" in page  # the failed clip is listed with its reason
    # flagged clips link to their record folders, relative to the report
    for href in [r for r in refs if r.endswith("record.json")]:
        assert (out / href).resolve().is_file()
    # the scene-balanced table holds the statistics module's numbers
    ok = read_tables(results)["clips"].query("status == 'ok'")
    ge_breathing = scene_balanced_median(
        ok[ok["model"] == "breathing"]["ge"], ok[ok["model"] == "breathing"]["scene_id"]
    )
    assert f"{ge_breathing:.4g}" in page
    # degenerate input: one platform without objects still gives a report, naming what it skipped
    one = tmp_path / "one"
    shutil.copytree(results, one)
    tables = read_tables(one)
    for name, df in tables.items():
        keep = df[df["model"] == "clean"] if name != "objects" and name != "object_frames" else df.iloc[0:0]
        keep.to_parquet(one / "tables" / f"{name}.parquet", index=False)
    res = build_report(one, bootstrap=200, formats=("png",))
    assert res.html.is_file()
    assert any("Effect sizes" in w for w in res.warnings) and any("AdaP90" in w for w in res.warnings)


@pytest.mark.full
def test_clips_without_status_are_scored_again_and_the_tables_match(dataset, results, tmp_path):
    """The resume rule on a copy of a finished run: clips whose ``status.json`` is missing (the
    state a killed worker leaves) are scored again, every other clip is kept as it was, and the
    tables equal those of the uninterrupted run. (The hard kill itself is the slow test above.)"""
    out = tmp_path / "r"
    shutil.copytree(results, out)
    shutil.rmtree(out / "tables")
    lost = sorted(out.glob("clips/clean-*/status.json"))[:2]
    assert len(lost) == 2
    for status in lost:
        status.unlink()
    kept = {p.parent.name: (p.stat().st_mtime_ns, p.read_bytes()) for p in out.glob("clips/*/status.json")}
    again = _run("bench", str(dataset), "--out", str(out), *BENCH_ARGS)
    assert again.returncode == 0, again.stderr
    assert f"resuming: {len(kept)} clip(s) already finished" in again.stderr
    assert f"(2 in this run, {len(kept)} finished earlier)" in again.stdout
    for name, (mtime, data) in kept.items():
        status = out / "clips" / name / "status.json"
        assert status.stat().st_mtime_ns == mtime and status.read_bytes() == data
    assert all(p.is_file() for p in lost)
    a, b = read_tables(results), read_tables(out)
    for name in a:
        pd.testing.assert_frame_equal(a[name], b[name], check_exact=True)
