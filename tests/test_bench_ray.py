"""`geocon bench --executor ray` on Ray instances started inside the test run, bound to 127.0.0.1
with 2 CPUs: the results folder and the Parquet tables equal the process pool's byte for byte, a Ray
worker killed mid-clip loses nothing and counts nothing twice, a run resumes across executors, and
nothing of Ray outlives a killed `geocon bench`."""

from __future__ import annotations

import dataclasses
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytest.importorskip("ray")
pd = pytest.importorskip("pandas")
psutil = pytest.importorskip("psutil")

from geocon_core.bench import (  # noqa: E402  # noqa: E402
    TABLES,
    TABLES_DIR,
    load_dataset,  # noqa: E402
    read_status,
    read_tables,
    run_bench,  # noqa: E402
)
from geocon_core.bench.ray import LOOPBACK_ENV, score_packed  # noqa: E402
from geocon_core.config import preset  # noqa: E402
from geocon_core.synth import plan_benchmark, write_benchmark  # noqa: E402

from .bad_inputs import broken_bench_clip  # noqa: E402

GEOCON = [sys.executable, "-m", "geocon_viewer.cli"]
ARGS = ["--working-size", "640x360", "--no-rrd"]
RAY = ["--executor", "ray", "--workers", "2", *ARGS]
N_CLIPS = 4  # C4 (a moving object) on three platforms, and a clip that fails in scoring
SUMMARY = f"{N_CLIPS} clips: {N_CLIPS - 1} scored, 1 failed"


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("ray-data")
    write_benchmark(root, plan_benchmark(families=("C4",), scenes=1), width=320, height=180, num_frames=10)
    broken_bench_clip(root)
    return root


@pytest.fixture(scope="module")
def pool(dataset, tmp_path_factory) -> Path:
    """The process pool's results: the reference every Ray run is compared with."""
    out = tmp_path_factory.mktemp("ray-pool") / "r"
    cfg = preset("audit").with_(working_size=(640, 360))
    summary = run_bench(dataset, out, cfg, workers=2)
    assert (summary.total, summary.failed) == (N_CLIPS, 1)
    return out


def _same_results(reference: Path, out: Path) -> None:
    """The tables of ``out`` equal the reference's byte for byte (and as frames), and every clip's
    status equals the reference's but for the seconds it took."""
    for name in TABLES:
        assert (out / TABLES_DIR / f"{name}.parquet").read_bytes() == (
            reference / TABLES_DIR / f"{name}.parquet"
        ).read_bytes(), name
    a, b = read_tables(reference), read_tables(out)
    for name in a:
        pd.testing.assert_frame_equal(a[name], b[name], check_exact=True)
    assert len(a["objects"]) > 0  # the comparison covers object rows, not only clip rows
    for folder in sorted((reference / "clips").iterdir()):
        want, got = read_status(folder), read_status(out / "clips" / folder.name)
        assert want is not None and got is not None
        assert {k: v for k, v in got.items() if k != "seconds"} == {k: v for k, v in want.items() if k != "seconds"}


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture(scope="module")
def head(tmp_path_factory):
    """A Ray head started as a user starts one (`ray start --head`, README "Benchmarks on a Ray
    cluster"), on 127.0.0.1 with 2 CPUs. (The default run's tests use the private instance that
    `--executor ray` starts without --ray-address: also a head on 127.0.0.1 with 2 CPUs.)"""
    ray_cli = Path(sys.executable).with_name("ray")
    env = {**os.environ, LOOPBACK_ENV: "0"}
    port = _free_port()
    start = [str(ray_cli), "start", "--head", f"--port={port}", "--num-cpus=2", "--include-dashboard=false"]
    proc = subprocess.run([*start, "--disable-usage-stats"], env=env, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    try:
        yield f"127.0.0.1:{port}"
    finally:
        subprocess.run([str(ray_cli), "stop", "--force"], env=env, capture_output=True, timeout=120)


@pytest.mark.slow
def test_a_run_on_a_ray_head_gives_the_process_pools_results(dataset, pool, head, tmp_path):
    out = tmp_path / "r"
    env = {**os.environ, "RAY_AUTH_MODE": "token"}  # the head asks for the token `ray start` saved
    proc = subprocess.run(
        [*GEOCON, "bench", str(dataset), "--out", str(out), *RAY, "--ray-address", head],
        capture_output=True,
        text=True,
        timeout=300,
        env=env,
    )
    assert proc.returncode == 0, proc.stderr
    assert f"note: scoring on the cluster at {head}: 2 CPUs, 1 per clip" in proc.stderr
    assert SUMMARY in proc.stdout
    assert "failed broken-c1: " in proc.stderr  # the failure is reported with its reason, as with the pool
    _same_results(pool, out)


def _ray_tasks(root: int) -> list:
    """The Ray worker processes under ``root`` that are scoring a clip now."""
    found = []
    for proc in psutil.Process(root).children(recursive=True):
        try:
            if proc.cmdline()[:1] == ["ray::score_packed"]:
                found.append(proc)
        except psutil.Error:
            pass
    return found


def _listening(root: int) -> set[str]:
    """The addresses that ``root`` and its descendants listen on."""
    hosts = set()
    for proc in [psutil.Process(root), *psutil.Process(root).children(recursive=True)]:
        try:
            conns = proc.net_connections(kind="tcp")
        except psutil.Error:
            continue
        hosts |= {c.laddr.ip for c in conns if c.status == psutil.CONN_LISTEN}
    return hosts


@pytest.mark.full
def test_a_killed_ray_worker_loses_nothing_and_counts_nothing_twice(dataset, pool, tmp_path):
    """A private local instance (no --ray-address): kill -9 of a Ray worker in the middle of a
    clip; that clip is scored again and the tables equal the pool's. Every Ray service of the
    instance listens on the loopback alone."""
    out = tmp_path / "r"
    proc = subprocess.Popen(
        [*GEOCON, "bench", str(dataset), "--out", str(out), *RAY],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        deadline, victims = time.monotonic() + 120, []
        while time.monotonic() < deadline and proc.poll() is None and not victims:
            victims = _ray_tasks(proc.pid)
            time.sleep(0.02)
        assert victims, "no Ray task was seen scoring a clip"
        hosts = _listening(proc.pid)
        victims[0].send_signal(signal.SIGKILL)
        stdout, stderr = proc.communicate(timeout=300)
    finally:
        proc.kill()
    assert hosts and all(h in ("127.0.0.1", "::ffff:127.0.0.1") for h in hosts), hosts
    assert proc.returncode == 0, stderr
    assert "note: scoring on a local Ray instance (127.0.0.1): 2 CPUs, 1 per clip" in stderr
    assert "the Ray worker scoring it died (WorkerCrashedError); scoring it again" in stderr
    assert f"{SUMMARY} ({N_CLIPS} in this run, 0 finished earlier)" in stdout
    _same_results(pool, out)


@pytest.mark.slow
def test_a_pool_run_resumes_on_ray_and_nothing_outlives_a_killed_driver(dataset, pool, tmp_path):
    """A process pool's results folder with two clips lost is finished by Ray (the kept clips are
    not scored again); then kill -9 of a Ray run's driver: within 10 s no process it started runs."""
    out = tmp_path / "r"
    shutil.copytree(pool, out)
    shutil.rmtree(out / TABLES_DIR)
    lost = sorted(out.glob("clips/*c4*/status.json"))[:2]
    assert len(lost) == 2
    for status in lost:
        status.unlink()
    kept = {p.parent.name: (p.stat().st_mtime_ns, p.read_bytes()) for p in out.glob("clips/*/status.json")}
    again = subprocess.run(
        [*GEOCON, "bench", str(dataset), "--out", str(out), *RAY], capture_output=True, text=True, timeout=300
    )
    assert again.returncode == 0, again.stderr
    assert f"(2 in this run, {N_CLIPS - 2} finished earlier)" in again.stdout
    for name, (mtime, data) in kept.items():
        status = out / "clips" / name / "status.json"
        assert status.stat().st_mtime_ns == mtime and status.read_bytes() == data
    _same_results(pool, out)

    proc = subprocess.Popen(
        [*GEOCON, "bench", str(dataset), "--out", str(tmp_path / "killed"), *RAY],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    try:
        deadline, started = time.monotonic() + 120, []
        while time.monotonic() < deadline and proc.poll() is None and not _ray_tasks(proc.pid):
            time.sleep(0.05)
        started = psutil.Process(proc.pid).children(recursive=True)
        assert any(p.name() == "raylet" for p in started)
    finally:
        proc.kill()
        proc.wait()
    gone, alive = psutil.wait_procs(started, timeout=10)
    for p in alive:
        p.kill()
    assert not alive, f"still running 10 s after the driver was killed: {[p.pid for p in alive]}"


def test_a_clip_a_worker_cannot_read_fails_with_a_sentence(dataset, tmp_path):
    entry = next(e for e in load_dataset(dataset) if e.clip_id.startswith("clean"))
    hidden = dataclasses.replace(entry, video=tmp_path / "not-mounted" / entry.video.name)
    status, files = score_packed(hidden, preset("audit").to_dict(), None, 1)
    assert status["status"] == "failed" and files == {}
    assert status["error"].startswith(f"ClipNotVisible: the Ray worker on {socket.gethostname()} cannot read the clip")
    assert "every node of the cluster sees at the same path" in status["error"]


@pytest.mark.full
def test_ray_options_are_refused_in_one_sentence_before_any_work(dataset, tmp_path):
    out = tmp_path / "r"
    proc = subprocess.run(
        [*GEOCON, "bench", str(dataset), "--out", str(out), "--ray-address", "127.0.0.1:1", *ARGS],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 2 and "--ray-address needs --executor ray" in proc.stderr
    nobody = f"127.0.0.1:{_free_port()}"
    proc = subprocess.run(
        [*GEOCON, "bench", str(dataset), "--out", str(out), *RAY, "--ray-address", nobody],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 2
    assert f"--ray-address {nobody}: no Ray cluster answers there" in proc.stderr
    assert not out.exists()
