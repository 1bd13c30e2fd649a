"""`geocon bench` and `geocon report` leave nothing behind and refuse bad output paths in one
sentence: workers die with a killed parent, one run at a time per results folder, output paths
checked before any work, report folders replaced whole."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

pd = pytest.importorskip("pandas")
pytest.importorskip("pyarrow")

from typer.testing import CliRunner  # noqa: E402

from geocon_core.bench import read_tables  # noqa: E402
from geocon_core.files import FolderLock, LockHeld, OutPathError, check_out_dir, replace_dir  # noqa: E402  # noqa: E402
from geocon_core.synth import plan_benchmark, write_benchmark  # noqa: E402
from geocon_viewer.cli import app  # noqa: E402

from .proc_group import kill_parent_alone, live_group, running, wait_gone  # noqa: E402

GEOCON = [sys.executable, "-m", "geocon_viewer.cli"]
ARGS = ["--workers", "2", "--working-size", "640x360", "--no-rrd"]
N_CLIPS = 6


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([*GEOCON, *args], capture_output=True, text=True, timeout=300)


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("hygiene-data")
    write_benchmark(root, plan_benchmark(families=("C1", "C3"), scenes=1), width=320, height=180, num_frames=10)
    return root


@pytest.fixture(scope="module")
def two_runs(dataset, tmp_path_factory):
    """Two `geocon bench` runs into one folder, the second started while the first is scoring:
    (first's pid, first's result, second's result, results folder)."""
    out = tmp_path_factory.mktemp("hygiene-two") / "r"
    first = subprocess.Popen(
        [*GEOCON, "bench", str(dataset), "--out", str(out), *ARGS],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and first.poll() is None:
            try:
                if json.loads((out / "bench.lock").read_text())["pid"] == first.pid:
                    break
            except (OSError, ValueError):
                pass
            time.sleep(0.05)
        second = _run("bench", str(dataset), "--out", str(out), *ARGS)
        stdout, stderr = first.communicate(timeout=300)
    finally:
        first.kill()
    return first.pid, subprocess.CompletedProcess(first.args, first.returncode, stdout, stderr), second, out


def test_second_run_into_one_folder_refuses_naming_the_first(two_runs):
    pid, first, second, out = two_runs
    assert second.returncode == 2
    assert second.stderr == (
        f"error: --out {out} is in use by another `geocon bench` run (PID {pid}); wait for it to finish or "
        "choose another --out\n"
    )
    assert first.returncode == 0, first.stderr
    assert f"{N_CLIPS} clips: {N_CLIPS} scored, 0 failed ({N_CLIPS} in this run" in first.stdout
    assert not [line for line in first.stderr.splitlines() if line.startswith("failed ")]
    assert (read_tables(out)["clips"]["status"] == "ok").all()
    assert not (out / "bench.lock").exists()  # released at the end of the run


@pytest.mark.full
def test_killed_bench_leaves_no_process_and_resumes_to_the_same_tables(dataset, two_runs, tmp_path):
    """kill -9 of the parent alone (not its process group): its workers and the resource tracker
    exit within a few seconds, its lock is taken over, and the rerun's tables equal an
    uninterrupted run's."""
    reference = two_runs[3]
    out = tmp_path / "r"
    proc = subprocess.Popen(
        [*GEOCON, "bench", str(dataset), "--out", str(out), *ARGS],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    deadline = time.monotonic() + 180
    while time.monotonic() < deadline and proc.poll() is None:
        if list(out.glob("clips/*/status.json")) and len(live_group(proc.pid)) >= 4:  # parent, tracker, 2 workers
            break
        time.sleep(0.05)
    assert proc.poll() is None, "the run ended before it could be killed"
    kill_parent_alone(proc)
    before = {p.parent.name: p.read_bytes() for p in out.glob("clips/*/status.json")}
    assert 1 <= len(before) < N_CLIPS
    assert json.loads((out / "bench.lock").read_text())["pid"] == proc.pid  # left by the dead run
    again = _run("bench", str(dataset), "--out", str(out), *ARGS)
    assert again.returncode == 0, again.stderr
    assert f"({N_CLIPS - len(before)} in this run, {len(before)} finished earlier)" in again.stdout
    assert not (out / "bench.lock").exists()
    for name, data in before.items():
        assert (out / "clips" / name / "status.json").read_bytes() == data
    a, b = read_tables(reference), read_tables(out)
    for name in a:
        pd.testing.assert_frame_equal(a[name], b[name], check_exact=True)


_CHILD = """
import sys, time
from geocon_core.files.procs import die_with_parent
die_with_parent(int(sys.argv[1]), poll_s=float(sys.argv[2]), pdeathsig=sys.argv[3] == "1")
print("armed", flush=True)
time.sleep(120)
"""

_PARENT = """
import os, subprocess, sys, time
child = subprocess.Popen([sys.executable, "-c", sys.argv[1], str(os.getpid()), *sys.argv[2:]],
                         stdout=subprocess.PIPE, text=True)
child.stdout.readline()
print(child.pid, flush=True)
time.sleep(120)
"""


@pytest.mark.parametrize(("pdeathsig", "poll_s", "limit_s"), [(True, 60.0, 1.0), (False, 0.1, 2.0)])
def test_worker_dies_with_its_killed_parent(pdeathsig, poll_s, limit_s):
    """Each mechanism alone: the kernel's parent-death signal (the watchdog slowed to a minute),
    and the watchdog thread (no prctl)."""
    parent = subprocess.Popen(
        [
            sys.executable,
            "-c",
            textwrap.dedent(_PARENT),
            textwrap.dedent(_CHILD),
            str(poll_s),
            "1" if pdeathsig else "0",
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    child = int(parent.stdout.readline())
    try:
        time.sleep(0.3)
        assert running(child)
        parent.kill()
        parent.wait()
        seconds = wait_gone(lambda: running(child), 10.0)
        assert not running(child)
        assert seconds < limit_s
    finally:
        if running(child):
            os.kill(child, signal.SIGKILL)


def test_lock_is_exclusive_names_its_holder_and_is_removed_on_release(tmp_path):
    path = tmp_path / "bench.lock"
    with FolderLock(path):
        assert json.loads(path.read_text())["pid"] == os.getpid()
        with pytest.raises(LockHeld) as held:
            FolderLock(path).acquire()  # another open file: flock conflicts within one process too
        assert held.value.pid == os.getpid()
    assert not path.exists()
    with FolderLock(path):  # free again
        pass


def test_lock_file_of_a_dead_process_is_taken_over(tmp_path):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    path = tmp_path / "bench.lock"
    path.write_text(json.dumps({"pid": int(dead.stdout), "host": os.uname().nodename}))
    with FolderLock(path):
        assert json.loads(path.read_text())["pid"] == os.getpid()


def test_out_dir_check_names_the_option_and_creates_nothing(tmp_path):
    afile = tmp_path / "afile"
    afile.write_text("x")
    (tmp_path / "link").symlink_to(tmp_path / "nowhere")
    cases = {
        afile: f"--out {afile} exists and is not a folder; choose a folder (it is created if missing)",
        afile / "sub": f"--out {afile / 'sub'} cannot be created: {afile} is not a folder",
        Path("/proc/x"): "--out /proc/x is under /proc, which cannot hold files; choose a folder on disk",
        Path("/sys/fs/x"): "--out /sys/fs/x is under /sys, which cannot hold files; choose a folder on disk",
        tmp_path
        / "link": f"--out {tmp_path / 'link'} is a broken link (to {tmp_path / 'nowhere'}); choose another folder",
    }
    for path, message in cases.items():
        with pytest.raises(OutPathError) as err:
            check_out_dir(path)
        assert str(err.value) == message
    new = tmp_path / "a" / "b"
    assert check_out_dir(new, "--results") == new and not (tmp_path / "a").exists()
    assert check_out_dir(tmp_path) == tmp_path
    with pytest.raises(OutPathError, match=r"^--report "):
        check_out_dir(afile, "--report")


@pytest.mark.skipif(os.geteuid() == 0, reason="root may write anywhere")
def test_out_dir_check_refuses_a_folder_without_write_permission(tmp_path):
    locked = tmp_path / "locked"
    locked.mkdir(mode=0o500)
    try:
        with pytest.raises(OutPathError, match="no write permission in"):
            check_out_dir(locked / "new")
        with pytest.raises(OutPathError, match="without write permission"):
            check_out_dir(locked)
    finally:
        locked.chmod(0o700)


def test_bench_refuses_bad_out_in_one_sentence_before_any_work(dataset, tmp_path):
    afile = tmp_path / "afile"
    afile.write_text("keep me")
    for out, message in (
        (afile, f"error: --out {afile} exists and is not a folder; choose a folder (it is created if missing)\n"),
        (Path("/proc/x"), "error: --out /proc/x is under /proc, which cannot hold files; choose a folder on disk\n"),
    ):
        proc = _run("bench", str(dataset), "--out", str(out), *ARGS)
        assert (proc.returncode, proc.stderr, proc.stdout) == (2, message, "")
    assert afile.read_text() == "keep me"


def _snapshot(folder: Path) -> dict[str, tuple[int, bytes]]:
    return {
        str(p.relative_to(folder)): (p.stat().st_mtime_ns, p.read_bytes()) for p in folder.rglob("*") if p.is_file()
    }


@pytest.mark.full
def test_report_is_replaced_whole_and_a_failed_run_keeps_the_previous_one(two_runs, tmp_path, monkeypatch):
    import geocon_core.report.pages as report

    results = two_runs[3]
    out = tmp_path / "report"
    first = report.build_report(results, out, bootstrap=50, formats=("png",))
    assert first.html == out / "report.html" and first.html.is_file()
    assert first.figures and all(p.is_file() and p.parent == out / "figures" for p in first.figures)
    assert first.tables and all(p.is_file() and p.parent == out / "tables" for p in first.tables)
    (out / "figures" / "stale.png").write_bytes(b"from an older report")
    before = _snapshot(out)

    def boom(*_args, **_kw):
        raise RuntimeError("a figure failed")

    monkeypatch.setattr(report, "fig_ridgelines", boom)  # after tables and the first figures are written
    with pytest.raises(RuntimeError, match="a figure failed"):
        report.build_report(results, out, bootstrap=50, formats=("png",))
    assert _snapshot(out) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report"]  # no temporary folder left
    # (that a finished report replaces the old folder whole, stale files included: test_replace_dir_*)


def test_report_refuses_bad_paths_in_one_sentence(two_runs, tmp_path):
    results = two_runs[3]
    afile = tmp_path / "afile"
    afile.write_text("keep me")
    foreign = tmp_path / "mine"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("keep me")
    cases = [
        ((str(results), "--out", str(afile)), f"--out {afile} exists and is not a folder"),
        ((str(results), "--out", "/proc/x"), "--out /proc/x is under /proc, which cannot hold files"),
        (
            (str(results), "--out", str(foreign)),
            f"--out {foreign} holds files that are not part of a report (notes.txt)",
        ),
        (
            (str(results), "--out", str(results)),
            f"--out {results} is the results folder, and a report folder is replaced whole",
        ),
        ((str(tmp_path / "nothing"),), f"results folder {tmp_path / 'nothing'} does not exist"),
        ((str(afile),), f"{afile} is a file, not a results folder written by `geocon bench`"),
    ]
    for args, start in cases:
        res = CliRunner().invoke(app, ["report", *args])  # in-process: the checks come before any import of the report
        assert res.exit_code == 2, (args, res.stderr)
        assert res.stderr.startswith(f"error: {start}") and res.stderr.count("\n") == 1, res.stderr
    assert afile.read_text() == "keep me" and (foreign / "notes.txt").read_text() == "keep me"
    assert sorted(p.name for p in foreign.iterdir()) == ["notes.txt"]


def test_replace_dir_removes_temporary_folders_of_dead_runs(tmp_path):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    stale = tmp_path / f".report.part-{int(dead.stdout)}-abcd"
    stale.mkdir()
    live = tmp_path / f".report.part-{os.getpid()}-abcd"
    live.mkdir()
    with replace_dir(tmp_path / "report") as stage:
        (stage / "a.txt").write_text("new")
    assert (tmp_path / "report" / "a.txt").read_text() == "new"
    assert not stale.exists() and live.exists()
    (tmp_path / "report" / "stale.png").write_text("from an older report")
    with replace_dir(tmp_path / "report") as stage:
        (stage / "b.txt").write_text("newer")
    assert sorted(p.name for p in (tmp_path / "report").iterdir()) == ["b.txt"]  # replaced whole
