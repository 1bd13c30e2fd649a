"""Command-line failures around GeoCon's inputs: a Rerun viewer URL that is malformed or answers
nowhere, too few open files, a bench worker killed mid-run, a terminal that shows ASCII only,
non-finite or repeated options, and out-of-memory advice; odd option values (an option as another's
value, an option given twice, options that exclude each other, counts and seeds past any use); the
process's surroundings (Ctrl-C while loading, a second Ctrl-C, a closed terminal, ``ulimit -t``,
closed standard streams, an empty ``HOME``). Each ends in one sentence (exit 2 for a bad option,
exit 1 for the machine or the network), never a traceback, and leaves nothing behind.

The catalogue (``CASES``) runs through :func:`tests.test_bad_input.judge`; a case that exits 1 is
held to the rules of a refusal as well (one ``error:`` line naming its words, nothing added or
changed). Network traffic goes to loopback addresses only: a name that does not resolve lies under
the reserved ``.invalid`` domain, and an unreachable host is a monkeypatched connection."""

from __future__ import annotations

import errno
import os
import re
import signal
import socket
import subprocess
import sys
import textwrap
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from geocon_viewer.cli import RESOURCE_ERRORS, app

from . import test_bad_input as catalogue
from .bad_inputs import pan_frames, snapshot, write_video
from .test_bad_input import FAST, Case, Ctx, Outcome, dataset, judge, nothing, run_case, score

assets = catalogue.assets
ctx = catalogue.ctx
"""The catalogue's fixtures, visible to the tests here: the shared inputs, the case's folder."""

GEOCON = [sys.executable, "-m", "geocon_viewer.cli"]
SMALL = ("--frames", "4", "--size", "64x64")
"""Synthetic clips of the cases: 4 frames of 64x64."""


def _closed_loopback_port() -> int:
    """A port on 127.0.0.1 that nothing listens on (bound, then closed again)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


CLOSED_PORT = _closed_loopback_port()


def view_connect(url: str) -> tuple[str, ...]:
    return ("view", "rec", "--connect", url)


def mp4_count(folder: str, n: int) -> Callable[[Ctx, Outcome], None]:
    """A check: ``folder`` holds ``n`` clips, and the command said ``n clips``."""

    def check(ctx: Ctx, res: Outcome) -> None:
        written = sorted((ctx.tmp / folder).rglob("*.mp4"))
        assert len(written) == n, f"{len(written)} clips written, expected {n}"
        assert f"{n} clips in" in res.stdout, res.stdout

    return check


CONNECT = [
    Case(
        "view-connect-not-a-url",
        lambda c: c.record(),
        view_connect("not a url"),
        2,
        ("--connect", "not a url", "rerun+http://"),
        needs=("rerun",),
    ),
    Case(
        "view-connect-http-scheme",
        lambda c: c.record(),
        view_connect("http://127.0.0.1:9876/proxy"),
        2,
        ("--connect", "rerun+http://"),
        needs=("rerun",),
    ),
    Case(
        "view-connect-port-99999",
        lambda c: c.record(),
        view_connect("rerun+http://127.0.0.1:99999/proxy"),
        2,
        ("--connect", "port"),
        needs=("rerun",),
    ),
    Case(
        "view-connect-no-host",
        lambda c: c.record(),
        view_connect("rerun+http://:9876/proxy"),
        2,
        ("--connect", "no host"),
        needs=("rerun",),
    ),
    Case(
        "view-connect-not-proxy",
        lambda c: c.record(),
        view_connect("rerun+http://127.0.0.1:9876/other"),
        2,
        ("--connect", "/proxy"),
        needs=("rerun",),
    ),
    Case(
        "view-connect-closed-port",
        lambda c: c.record(),
        view_connect(f"rerun+http://127.0.0.1:{CLOSED_PORT}/proxy"),
        1,
        (f"127.0.0.1:{CLOSED_PORT}", "refused", "rerun"),
        needs=("rerun",),
    ),
    Case(
        "view-connect-does-not-resolve",
        lambda c: c.record(),
        view_connect("rerun+http://no-viewer.invalid:9876/proxy"),
        1,
        ("no-viewer.invalid", "does not resolve"),
        needs=("rerun",),
    ),
]

OPTIONS = [
    *(
        Case(f"synth-noise-{v}", nothing, ("synth", "C1", "--out", "s", "--noise", v, *SMALL), 2, ("--noise", "255"))
        for v in ("inf", "nan", "-1", "1e9")
    ),
    Case(
        "synth-severity-inf",
        nothing,
        ("synth", "C1", "--out", "s", "--failure", "breathing", "--severity", "inf", *SMALL),
        2,
        ("breathing", "inf"),
    ),
    Case("synth-noise-255-ok", nothing, ("synth", "C1", "--out", "out", "--noise", "255", *SMALL), 0),
    *(
        Case(
            f"bench-{option[2:]}-{v}",
            dataset,
            ("bench", "ds", "--out", "res", *FAST, "--executor", "ray", option, v),
            2,
            (option, v),
        )
        for option, v in (
            ("--ray-cpus-per-clip", "inf"),
            ("--ray-cpus-per-clip", "nan"),
            ("--ray-cpus-per-clip", "0"),
            ("--ray-gpus-per-clip", "inf"),
            ("--ray-gpus-per-clip", "nan"),
        )
    ),
    Case(
        "bench-ray-gpus-negative-with-the-pool",
        dataset,
        ("bench", "ds", "--out", "res", *FAST, "--ray-gpus-per-clip", "-1"),
        2,
        ("--ray-gpus-per-clip", "-1"),
    ),
]

LISTS = [
    Case(
        "synth-bench-family-twice",
        nothing,
        ("synth-bench", "--out", "d", "--scenes", "1", "--families", "C1,C1", *SMALL),
        2,
        ("--families", "C1", "twice"),
    ),
    Case(
        "synth-bench-family-and-its-alias",
        nothing,
        ("synth-bench", "--out", "d", "--scenes", "1", "--families", "C1,c1_static", *SMALL),
        2,
        ("--families", "c1_static"),
    ),
    Case(
        "synth-bench-no-family",
        nothing,
        ("synth-bench", "--out", "d", "--scenes", "1", "--families", ",", *SMALL),
        2,
        ("--families",),
    ),
    Case(
        "synth-bench-count-is-what-is-written",
        nothing,
        ("synth-bench", "--out", "out", "--scenes", "1", "--families", "C1,C2", *SMALL),
        0,
        check=mp4_count("out", 6),
    ),
    Case(
        "validate-height-twice",
        nothing,
        ("validate", "--heights", "256,256", "--no-real", "--report-only", "--out", "v"),
        2,
        ("--heights", "256"),
    ),
    Case(
        "validate-codec-twice",
        nothing,
        ("validate", "--codecs", "png,PNG", "--no-real", "--report-only", "--out", "v"),
        2,
        ("--codecs",),
    ),
]

CASES = CONNECT + OPTIONS + LISTS


def judge_all(case: Case, ctx: Ctx, res: Outcome, before: dict[str, str]) -> list[str]:
    """:func:`judge`, and for a failure of the machine or the network (exit 1) the rules of a
    refusal: one ``error:`` line naming the case's words, nothing added or changed."""
    problems = judge(case, ctx, res, before)
    if res.code == 1:
        lines = [line for line in res.stderr.splitlines() if line.strip()]
        if len(lines) != 1 or not lines[0].startswith("error: "):
            problems.append(f"stderr is not one line 'error: ...': {res.stderr!r}")
        sentence = lines[0] if lines else ""
        problems += [f"the sentence should name {word!r}" for word in case.says if word not in sentence]
        after = snapshot(ctx.tmp)
        if after != before:
            problems.append(f"a failed run changed the folder: {sorted(set(after) ^ set(before))}")
    return problems


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_bad_cli(case: Case, ctx: Ctx):
    run_case(case, ctx, judge_all)


# --- view --connect: an unreachable viewer, a viewer that goes away -------------------------------


@pytest.mark.parametrize(
    ("error", "words"),
    [(TimeoutError("timed out"), "no answer within"), (OSError(errno.EHOSTUNREACH, "No route to host"), "no route")],
)
def test_view_connect_to_an_unreachable_viewer_is_one_sentence(ctx: Ctx, monkeypatch, error, words):
    pytest.importorskip("rerun")
    ctx.record()
    before = snapshot(ctx.tmp)

    def unreachable(_sock: socket.socket, _address: object) -> None:
        raise error

    monkeypatch.setattr(socket.socket, "connect", unreachable)  # no packet leaves this machine
    case = Case("unreachable", nothing, view_connect("rerun+http://127.0.0.1:9876/proxy"), 1, (words, "9876"))
    res = ctx.invoke(list(case.argv))
    problems = judge_all(case, ctx, res, before)
    assert not problems, f"{res.describe()}\n  - " + "\n  - ".join(problems)


def test_view_connect_to_a_viewer_that_goes_away_is_one_sentence(ctx: Ctx, monkeypatch):
    pytest.importorskip("rerun")
    import geocon_viewer.capture
    import geocon_viewer.rerun

    ctx.record()
    before = snapshot(ctx.tmp)

    def severed(*_args: object, **_options: object) -> None:
        raise RuntimeError("gRPC connection severed")

    # the command line takes both through their packages' public names
    monkeypatch.setattr(geocon_viewer.capture, "check_viewer_url", lambda url, **_: ("127.0.0.1", 9876))
    monkeypatch.setattr(geocon_viewer.rerun, "write_rrd", severed)
    case = Case("severed", nothing, view_connect("rerun+http://127.0.0.1:9876/proxy"), 1, ("stopped answering",))
    res = ctx.invoke(list(case.argv))
    problems = judge_all(case, ctx, res, before)
    assert not problems, f"{res.describe()}\n  - " + "\n  - ".join(problems)


# --- too few open files ---------------------------------------------------------------------------


def _one_sentence(res: subprocess.CompletedProcess, *words: str) -> str:
    lines = [line for line in res.stderr.splitlines() if line.strip()]
    assert res.returncode == 1, res.stderr
    assert "Traceback" not in res.stderr and len(lines) == 1 and lines[0].startswith("error: "), res.stderr
    for word in words:
        assert word in lines[0], lines[0]
    return lines[0]


def _limited(soft: int, hard: int):
    import resource

    def cap() -> None:
        resource.setrlimit(resource.RLIMIT_NOFILE, (soft, hard))

    return cap


@pytest.fixture()
def clip(tmp_path: Path) -> Path:
    return write_video(tmp_path / "clip.mp4", pan_frames(160, 90, 8, seed=1))


def test_too_few_open_files_is_refused_up_front(tmp_path, clip):
    res = subprocess.run(
        [*GEOCON, "score", "clip.mp4", *FAST, "--out", "rec"],
        cwd=tmp_path, capture_output=True, text=True, timeout=120, preexec_fn=_limited(16, 16),
    )  # fmt: skip
    _one_sentence(res, "16 files", "ulimit -n")
    assert not (tmp_path / "rec").exists()


@pytest.mark.full
def test_a_low_soft_open_files_limit_is_raised_when_the_hard_limit_allows(tmp_path, clip):
    import resource

    hard = resource.getrlimit(resource.RLIMIT_NOFILE)[1]
    if hard != resource.RLIM_INFINITY and hard < 64:  # below GeoCon's minimum: nothing to raise to
        pytest.skip(f"the hard open-files limit here is {hard}")
    res = subprocess.run(
        [*GEOCON, "score", "clip.mp4", *FAST, "--out", "rec", "--rrd", "rec.rrd"],
        cwd=tmp_path, capture_output=True, text=True, timeout=300, preexec_fn=_limited(8, hard),
    )  # fmt: skip
    assert res.returncode == 0 and "Traceback" not in res.stderr, res.stderr
    assert (tmp_path / "rec" / "record.json").is_file()


def _run_patched(cwd: Path, patch: str, *argv: str) -> subprocess.CompletedProcess:
    """``geocon ARGV`` through its console script, after the Python statements ``patch``."""
    script = "\n".join(
        [
            "import sys",
            textwrap.dedent(patch),
            "from geocon_viewer.cli import main",
            f"sys.argv = ['geocon', *{list(argv)!r}]",
            "main()",
        ]
    )
    return subprocess.run([sys.executable, "-c", script], cwd=cwd, capture_output=True, text=True, timeout=120)


@pytest.mark.parametrize("code", ["EMFILE", "ENFILE"])
def test_running_out_of_file_descriptors_midway_is_one_sentence(tmp_path, code):
    patch = f"""
        import errno
        from geocon_viewer.cli import commands_synth
        def render_plans(*args, **kwargs):
            raise OSError(errno.{code}, "Too many open files")
        commands_synth.render_plans = render_plans
    """
    res = _run_patched(tmp_path, patch, "synth", "C1", "--out", "s", *SMALL)
    _one_sentence(res, "too many open files")
    assert getattr(errno, code) in RESOURCE_ERRORS


# --- a bench worker killed mid-run ----------------------------------------------------------------


@pytest.mark.full
def test_a_killed_bench_worker_and_resource_tracker_print_no_traceback(tmp_path):
    """``kill -9`` of every multiprocessing child of a running ``geocon bench --workers 2`` (the
    workers and the resource tracker, as ``pkill -f multiprocessing`` does): the run recovers, says
    so in one note per death, and prints no traceback or warning."""
    psutil = pytest.importorskip("psutil")
    pytest.importorskip("pyarrow")
    from geocon_core.synth import plan_benchmark, write_benchmark

    data = tmp_path / "ds"
    write_benchmark(data, plan_benchmark(families=("C1", "C2"), scenes=2), width=160, height=96, num_frames=12)
    proc = subprocess.Popen(
        [*GEOCON, "bench", str(data), "--out", "res", *FAST, "--workers", "2", "--no-rrd"],
        cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
    )  # fmt: skip
    try:
        killed: list[int] = []
        deadline = time.monotonic() + 120
        while not killed and time.monotonic() < deadline and proc.poll() is None:
            if list((tmp_path / "res").glob("clips/*")):  # a worker is scoring
                for child in psutil.Process(proc.pid).children():
                    try:
                        cmdline = " ".join(child.cmdline())
                    except psutil.NoSuchProcess:  # a child that ended between the listing and the look
                        continue
                    if "multiprocessing" in cmdline:
                        os.kill(child.pid, signal.SIGKILL)
                        killed.append(child.pid)
            time.sleep(0.05)
        stdout, stderr = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert len(killed) >= 2, "the run ended before its workers could be killed"
    assert proc.returncode == 0, stderr
    assert "Traceback" not in stderr and "Warning" not in stderr, stderr
    assert "12 clips: 12 scored, 0 failed" in stdout, stdout
    notes = [line for line in stderr.splitlines() if line.startswith("note: ")]
    assert any("a worker process died" in n and "scoring" in n for n in notes), stderr
    assert any("resource tracker" in n for n in notes), stderr


TRACKER_LIMIT_S = 120
"""A ``geocon bench`` of two small clips whose resource tracker is killed ends within this long."""
KILL_TRACKER = """
    import os, signal
    from concurrent.futures import ProcessPoolExecutor
    from multiprocessing import resource_tracker
    real_shutdown = ProcessPoolExecutor.shutdown
    def shutdown(self, *args, **kwargs):  # the tracker killed after the last check, as the pool ends
        tracker = resource_tracker._resource_tracker
        if tracker._pid is not None:
            os.kill(tracker._pid, signal.SIGKILL)
            os.waitpid(tracker._pid, 0)
        return real_shutdown(self, *args, **kwargs)
    ProcessPoolExecutor.shutdown = shutdown
"""
"""Patched into a ``geocon bench`` run: the resource tracker is killed just before each worker pool
shuts down (after the run's last look at it), when the pool's five semaphores are forgotten."""


@pytest.mark.full
def test_a_resource_tracker_killed_as_the_pool_ends_prints_no_traceback(tmp_path):
    """The tracker killed once every clip is scored (``pkill -f resource_tracker`` at the end of a
    run): the pool's shutdown starts a new one, quietly, and the run says so in one note; it printed
    a warning and five ``KeyError`` tracebacks, one per semaphore the new tracker never knew."""
    pytest.importorskip("pyarrow")
    data = tmp_path / "ds"
    (data / "p").mkdir(parents=True)
    for name, seed in (("a", 1), ("b", 2)):
        write_video(data / "p" / f"{name}.mp4", pan_frames(96, 64, 6, seed=seed))
    script = "\n".join(
        ["import sys", textwrap.dedent(KILL_TRACKER), "from geocon_viewer.cli import main",
         f"sys.argv = ['geocon', 'bench', {str(data)!r}, '--out', 'res', '--preset', 'fast', '--workers', '2', "
         "'--no-rrd']", "main()"]
    )  # fmt: skip
    res = subprocess.run(
        [sys.executable, "-c", script], cwd=tmp_path, capture_output=True, text=True, timeout=TRACKER_LIMIT_S
    )
    assert res.returncode == 0, res.stderr
    assert "Traceback" not in res.stderr and "KeyError" not in res.stderr and "Warning" not in res.stderr, res.stderr
    assert "2 clips: 2 scored, 0 failed" in res.stdout, res.stdout
    notes = [line for line in res.stderr.splitlines() if "resource tracker" in line]
    assert notes == ["note: the worker pool's resource tracker process had died; a new one was started"], res.stderr


QUIET_BLOCK = """
    import gc, os, signal, sys
    import multiprocessing
    from multiprocessing import resource_tracker
    from geocon_core.files import quiet_tracker_restarts
    lock = multiprocessing.get_context("spawn").Lock()  # a named semaphore, registered with the tracker
    tracker = resource_tracker._resource_tracker
    os.kill(tracker._pid, signal.SIGKILL)
    os.waitpid(tracker._pid, 0)
    if sys.argv[1] == "quiet":
        with quiet_tracker_restarts() as restarted:
            del lock
            gc.collect()
        print("restarted" if restarted else "not restarted")
    else:
        del lock
        gc.collect()
    os.close(tracker._fd)  # the new tracker reads the end of its pipe and exits
    os.waitpid(tracker._pid, 0)  # once it has printed what it prints
    tracker._fd = tracker._pid = None
"""
"""A semaphore forgotten after its tracker was killed (its new tracker ends with this process)."""


@pytest.mark.parametrize("mode", ["quiet", "plain"])
def test_a_tracker_started_again_inside_the_quiet_block_prints_nothing(tmp_path, mode):
    """Inside :func:`~geocon_core.files.quiet_tracker_restarts` the new tracker's traceback and
    multiprocessing's warning go nowhere, and the block says a tracker was started again; outside
    it (``plain``, the check that the scene is real) both reach the terminal."""
    res = subprocess.run(
        [sys.executable, "-c", textwrap.dedent(QUIET_BLOCK), mode],
        cwd=tmp_path, capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    if mode == "quiet":
        assert res.stdout.strip() == "restarted" and res.stderr == "", res.stderr
    else:
        assert "KeyError" in res.stderr and "relaunching" in res.stderr, res.stderr


# --- a terminal that shows ASCII only -------------------------------------------------------------

ASCII_ENV = {"LANG": "C", "LC_ALL": "C", "PYTHONIOENCODING": "ascii"}


def _ascii_run(cwd: Path, *argv: str) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONUTF8", "LC_CTYPE")} | ASCII_ENV
    res = subprocess.run([*GEOCON, *argv], cwd=cwd, capture_output=True, env=env, timeout=300)
    assert res.returncode == 0, res.stderr.decode(errors="replace")
    assert b"Traceback" not in res.stderr and b"UnicodeEncodeError" not in res.stderr, res.stderr
    assert res.stdout.isascii(), res.stdout
    return res


def test_an_ascii_terminal_gets_the_score_summary_with_stand_ins(tmp_path, synth_clips):
    from geocon_core.synth import ClipPlan

    src = synth_clips([ClipPlan("C4")], seed=1, width=128, height=96, num_frames=8)
    res = _ascii_run(
        tmp_path, "score", str(src / "c4_objects.mp4"), *FAST, "--masks", str(src / "c4_objects.masks"), "--out", "r"
    )
    assert re.search(rb"AdaDFRC [0-9.]+ px2", res.stdout), res.stdout  # px\u00b2


@pytest.mark.full
@pytest.mark.parametrize(
    "argv",
    [("synth", "C1", "--out", "s", *SMALL), ("synth-failures",), ("presets",), ("doctor",)],
    ids=lambda argv: argv[0],
)
def test_an_ascii_terminal_gets_every_table(tmp_path, argv):
    _ascii_run(tmp_path, *argv)


@pytest.mark.full
def test_an_ascii_terminal_gets_the_bench_and_report_output(tmp_path):
    pytest.importorskip("pyarrow")
    pytest.importorskip("matplotlib")
    _ascii_run(tmp_path, "synth-bench", "--out", "ds", "--scenes", "1", "--families", "C1", *SMALL)
    _ascii_run(tmp_path, "bench", "ds", "--out", "res", *FAST, "--no-rrd")
    _ascii_run(tmp_path, "report", "res", "--bootstrap", "100")


# --- out-of-memory advice -------------------------------------------------------------------------


def _options(command) -> set[str]:
    return {o for p in command.params for o in (*p.opts, *p.secondary_opts) if o.startswith("--")}


def test_each_commands_memory_advice_names_only_its_own_options():
    import typer

    from geocon_viewer.cli import _memory_sentence, _resource_sentence

    commands = typer.main.get_command(app).commands  # type: ignore[attr-defined]
    for name, command in commands.items():
        named = set(re.findall(r"--[a-z][a-z0-9-]*", _memory_sentence(name)))
        assert named <= _options(command), f"geocon {name}: the advice names {sorted(named - _options(command))}"
    for code in RESOURCE_ERRORS:  # said for every command alike: no command's options
        sentence = _resource_sentence(OSError(code, os.strerror(code)))
        assert not re.findall(r"--[a-z]", sentence), sentence
    assert "--bootstrap" in _memory_sentence("report") and "--frames" in _memory_sentence("synth")


def test_out_of_memory_in_report_advises_fewer_bootstrap_resamples(tmp_path):
    pytest.importorskip("matplotlib")
    patch = """
        import geocon_core.report
        def build_report(*args, **kwargs):
            raise MemoryError
        geocon_core.report.build_report = build_report
    """
    res = _run_patched(tmp_path, patch, "report", "res")
    sentence = _one_sentence(res, "out of memory", "--bootstrap")
    assert "--working-size" not in sentence


# --- odd option values: an option as a value, an option twice, options that exclude each other ----


def no_folder(*names: str) -> Callable[[Ctx, Outcome], None]:
    """A check: the refused run left none of the folders ``names`` (an empty folder is invisible
    to :func:`snapshot`, which lists files)."""

    def check(ctx: Ctx, _res: Outcome) -> None:
        left = [name for name in names if (ctx.tmp / name).exists()]
        assert not left, f"a refused run left the folders {left}"

    return check


def config_row(*words: str, absent: tuple[str, ...] = ()) -> Callable[[Ctx, Outcome], None]:
    """A check: the summary's ``config`` row says ``words`` and none of ``absent``."""

    def check(_ctx: Ctx, res: Outcome) -> None:
        text = " ".join(res.stdout.split())  # the table wraps its cells
        assert all(w in text for w in words) and not any(w in text for w in absent), res.stdout

    return check


def record_in(folder: str) -> Callable[[Ctx, Outcome], None]:
    def check(ctx: Ctx, _res: Outcome) -> None:
        assert (ctx.tmp / folder / "record.json").is_file(), sorted(p.name for p in ctx.tmp.iterdir())

    return check


def pan(ctx: Ctx) -> None:
    ctx.pan()


def pan_and_junk_checkpoint(ctx: Ctx) -> None:
    ctx.pan()
    ctx.write("sam2.pt", np.random.default_rng(11).bytes(2000))


def paper_orb(*more: str) -> tuple[str, ...]:
    return ("score", "clip.mp4", "--preset", "paper", "--matcher", "orb", "--out", "out", *more)


ODD = [
    Case("score-out-value-is-an-option", pan, ("score", "clip.mp4", *FAST, "--out", "--json"), 2,
         ("--out", "--json", "./--json"), check=no_folder("--json")),
    Case("score-masks-value-is-an-option", pan, score("clip.mp4", "--masks", "--no-masks"), 2,
         ("--masks", "--no-masks")),
    Case("score-pose-log-value-is-an-option", pan, score("clip.mp4", "--pose-log", "--rrd", "a.rrd"), 2,
         ("--pose-log", "--rrd")),
    Case("score-out-equals-an-option-name-is-taken-as-written", pan, ("score", "clip.mp4", *FAST, "--out=--json"), 0,
         check=record_in("--json")),
    Case("synth-frames-twice", nothing, ("synth", "C1", "--out", "s", *SMALL, "--frames", "9"), 2,
         ("--frames", "4", "9", "twice"), check=no_folder("s")),
    Case("synth-same-value-twice-is-fine", nothing, ("synth", "C1", "--out", "out", *SMALL, "--frames", "4", "--json",
         "--json"), 0, check=lambda c, _res: (c.tmp / "out" / "c1_static.mp4").stat()),
    Case("score-preset-twice", pan, ("score", "clip.mp4", "--preset", "paper", *FAST, "--out", "out"), 2,
         ("--preset", "paper", "fast")),
    Case("score-dense-and-no-dense", pan, score("clip.mp4", "--dense", "--no-dense"), 2, ("--dense", "--no-dense")),
    Case("bench-rrd-and-no-rrd", dataset, ("bench", "ds", "--out", "res", *FAST, "--rrd", "--no-rrd"), 2,
         ("--rrd", "--no-rrd")),
    Case("dataset-root-may-repeat", dataset, ("dataset", "ds", "--root", "ds", "--root", "."), 0),
    Case("view-at-twice", lambda c: c.record(), ("view", "rec", "--headless", "--at", "3", "--at", "5"), 2,
         ("--at", "3", "5"), needs=("rerun",)),
    Case("view-headless-and-serve", lambda c: c.record(), ("view", "rec", "--headless", "--serve"), 2,
         ("--serve", "--headless"), needs=("rerun",)),
    Case("view-serve-and-connect", lambda c: c.record(),
         ("view", "rec", "--serve", "--connect", "rerun+http://127.0.0.1:9876/proxy"), 2, ("--serve", "--connect"),
         needs=("rerun",)),
    Case("view-unknown-preset-with-a-saved-record", lambda c: c.record(), ("view", "rec", "--headless", "--preset",
         "nope"), 2, ("nope", "valid:"), needs=("rerun",)),
    Case("bench-working-size-0x0", dataset, ("bench", "ds", "--out", "res", *FAST, "--working-size", "0x0"), 2,
         ("--working-size", "0x0"), forbids=("--size",)),
    Case("bench-working-size-past-8k", dataset, ("bench", "ds", "--out", "res", *FAST, "--working-size", "10000x100"),
         2, ("--working-size", "8192"), forbids=("--size", "encoder")),
    Case("score-sam2-size-0", pan_and_junk_checkpoint, score("clip.mp4", "--masks", "sam2", "--sam2-checkpoint",
         "sam2.pt", "--sam2-size", "0"), 2, ("--sam2-size", "got 0")),
    Case("score-sam2-size-a-million", pan_and_junk_checkpoint, score("clip.mp4", "--masks", "sam2",
         "--sam2-checkpoint", "sam2.pt", "--sam2-size", "1048576"), 2, ("--sam2-size", "4096")),
    Case("score-missing-clip-default-out", nothing, score("nothere.mp4", out=None), 2, ("nothere.mp4",),
         check=no_folder("geocon-out")),
    Case("score-missing-clip-nested-out", nothing, score("nothere.mp4", out="a/b/rec"), 2, ("nothere.mp4",),
         check=no_folder("a")),
    Case("score-paper-preset-with-a-matcher-says-so", pan, paper_orb(), 0,
         check=config_row("paper preset changed by options", "matcher orb")),
    Case("synth-size-8192x8192", nothing, ("synth", "C1", "--out", "s", "--frames", "2", "--size", "8192x8192"), 2,
         ("--size", "67 million pixels", "8192x4320")),
    Case("synth-size-8k-uhd-is-allowed-up-front", nothing, ("synth", "C1", "--out", "s", "--frames", "2", "--size",
         "7680x4320", "--failure", "nope"), 2, ("nope",)),
    Case("footage-status-with-from", lambda c: (c.tmp / "clones").mkdir(), ("footage", "status", "--from", "clones"),
         2, ("--from", "fill")),
    Case("teach-frames-0", nothing, ("teach", "--frames", "0"), 2, ("--frames", "4", "120"), needs=("viser",)),
    Case("score-fast-preset-unchanged", pan, score("clip.mp4"), 0, check=config_row("fast preset, hash",
         absent=("changed by options",))),
    Case("score-brought-masks-are-no-change", lambda c: c.c4(), score("c4.mp4", "--masks", "c4.masks"), 0,
         check=config_row("fast preset, hash", absent=("changed by options",))),
]  # fmt: skip


def test_the_odd_values_catalogue_is_complete():
    names = [c.name for c in CASES + ODD]
    assert len(names) == len(set(names)), "case names are unique"


@pytest.mark.parametrize("case", ODD, ids=[c.name for c in ODD])
def test_odd_option_values(case: Case, ctx: Ctx):
    run_case(case, ctx, judge_all)


@pytest.mark.parametrize(
    ("argv", "option"),
    [
        (("synth", "C1", "--out", "s", "--frames", "99999999999999999999999", "--size", "64x64"), "--frames"),
        (("synth", "C1", "--out", "s", "--frames", "100001", "--size", "64x64"), "--frames"),
        (("synth-bench", "--out", "s", "--scenes", "1000000000", "--families", "C1", *SMALL), "--scenes"),
        (("validate", "--out", "s", "--no-real", "--frames", "99999999999999999999"), "--frames"),
        (("validate", "--out", "s", "--no-real", "--max-frames", "99999999999999999999"), "--max-frames"),
        (("demo", "--out", "s", "--seed", "-1"), "--seed"),
        (("demo", "--out", "s", "--seed", "4294967296"), "--seed"),
        (("teach", "--seed", "-5"), "--seed"),
    ],
    ids=lambda v: "-".join(v) if isinstance(v, tuple) else v,
)
def test_out_of_range_counts_and_seeds_are_refused_before_any_work(tmp_path, monkeypatch, argv, option):
    """Counts past any use (``--frames 1e23`` overflowed NumPy, ``--scenes 1e9`` planned for ever)
    and seeds NumPy cannot take (``demo --seed -1`` was a traceback, ``teach --seed -5`` a broken
    page) are refused by the parser, naming the option."""
    monkeypatch.chdir(tmp_path)
    res = CliRunner().invoke(app, list(argv))
    assert res.exit_code == 2 and option in res.output and "Traceback" not in res.output, res.output
    assert not (tmp_path / "s").exists()


# --- the process: Ctrl-C while loading, a second Ctrl-C, a hang-up, ulimit -t, closed streams ------


def _run_script(cwd: Path, script: str, **options) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", textwrap.dedent(script)], cwd=cwd, capture_output=True, text=True,
                          timeout=120, **options)  # fmt: skip


def test_ctrl_c_while_the_command_loads_prints_no_traceback(tmp_path):
    """Ctrl-C in the first half second, while ``geocon`` imports its libraries, ends it (130)
    without the 40-line traceback of the import it cut short."""
    res = _run_script(
        tmp_path,
        """
        import os, signal, sys

        class CtrlC:  # Ctrl-C arrives while the commands' modules load
            def find_spec(self, name, path=None, target=None):
                if name == "geocon_viewer.cli.commands_demo":
                    os.kill(os.getpid(), signal.SIGINT)
                return None

        sys.meta_path.insert(0, CtrlC())
        sys.argv = ["geocon", "presets"]
        from geocon_viewer.cli import main
        main()
        """,
    )
    assert res.returncode == 130 and "Traceback" not in res.stderr and "KeyboardInterrupt" not in res.stderr, res


def _sentence_after_progress(res: subprocess.CompletedProcess, *words: str) -> None:
    """Exit 1 and one ``error:`` sentence holding ``words``, after nothing but progress bars."""
    lines = [line for line in res.stderr.splitlines() if line.strip() and " frames " not in line]
    assert res.returncode == 1 and "Traceback" not in res.stderr, res.stderr
    assert len(lines) == 1 and lines[0].startswith("error: "), res.stderr
    assert all(word in lines[0] for word in words), lines[0]


def _interrupted_synth(cwd: Path, signum: str, *, again: bool) -> subprocess.CompletedProcess:
    """``geocon synth C4`` that gets ``signum`` while it renders frame 3 and, with ``again``, the
    same signal again while it removes its temporary files. The signal starts at its default, as
    in a terminal: a test run under ``nohup`` (SIGHUP ignored) or as a background job (SIGINT
    ignored) passes the ignoring on, and GeoCon rightly keeps an ignored signal ignored."""
    return _run_patched(
        cwd,
        f"""
        import os, signal
        default = signal.default_int_handler if signal.{signum} == signal.SIGINT else signal.SIG_DFL
        signal.signal(signal.{signum}, default)
        from geocon_core.synth import writer
        render, remove = writer.render_frame, writer._remove
        def render_frame(scene, t, failure):
            if t == 3:
                os.kill(os.getpid(), signal.{signum})
            return render(scene, t, failure)
        def again(path):
            if {again}:
                os.kill(os.getpid(), signal.{signum})
            remove(path)
        writer.render_frame, writer._remove = render_frame, again
        """,
        "synth", "C4", "--out", "s", "--frames", "8", "--size", "64x64",
    )  # fmt: skip


def test_a_second_ctrl_c_lets_the_clean_up_finish(tmp_path):
    """A second Ctrl-C while the first one's clean-up runs no longer cuts it short (it left the
    temporary clip and masks behind, and could abort in native threads)."""
    res = _interrupted_synth(tmp_path, "SIGINT", again=True)
    assert res.returncode == 130 and "Traceback" not in res.stderr and "terminate" not in res.stderr, res.stderr
    assert not (tmp_path / "s").exists(), sorted(p.name for p in (tmp_path / "s").iterdir())


def test_a_closed_terminal_stops_the_run_cleanly(tmp_path):
    """SIGHUP (the terminal or the ssh session closed) stops the run as Ctrl-C does; it killed
    the process and left the temporary clip and masks."""
    res = _interrupted_synth(tmp_path, "SIGHUP", again=False)
    assert res.returncode == 130 and "Traceback" not in res.stderr, res.stderr
    assert not (tmp_path / "s").exists(), sorted(p.name for p in (tmp_path / "s").iterdir())


def test_the_cpu_time_limit_stops_the_run_with_one_sentence(tmp_path):
    """SIGXCPU (the soft limit of ``ulimit -t``) stops the run cleanly with one sentence; it
    killed the process (and dumped core) and left the temporary clip and masks. It repeats every
    second past the limit: the repeats do not cut the clean-up short."""
    res = _interrupted_synth(tmp_path, "SIGXCPU", again=True)
    _sentence_after_progress(res, "CPU time limit", "ulimit -t")
    assert not (tmp_path / "s").exists(), sorted(p.name for p in (tmp_path / "s").iterdir())


@pytest.mark.full
def test_a_real_ulimit_t_ends_synth_with_one_sentence(tmp_path):
    import resource

    def cap() -> None:
        hard = resource.getrlimit(resource.RLIMIT_CPU)[1]
        resource.setrlimit(resource.RLIMIT_CPU, (3, hard))

    res = subprocess.run(
        [*GEOCON, "synth", "C4", "--out", "s", "--frames", "5000", "--size", "160x90"],
        cwd=tmp_path, capture_output=True, text=True, timeout=120, preexec_fn=cap,
    )  # fmt: skip
    _sentence_after_progress(res, "CPU time limit")
    assert not (tmp_path / "s").exists()


def _closed(*fds: int, address_space: int | None = None) -> Callable[[], None]:
    import resource

    def close() -> None:
        if address_space is not None:
            resource.setrlimit(resource.RLIMIT_AS, (address_space, address_space))
        for fd in fds:
            os.close(fd)

    return close


def test_json_on_a_closed_stdout_is_one_sentence_and_the_record_is_kept(tmp_path, clip):
    """``geocon score --json >&-``: Python leaves ``sys.stdout`` None, where the JSON was an
    AttributeError traceback."""
    res = subprocess.run(
        [*GEOCON, "score", "clip.mp4", *FAST, "--out", "rec", "--json"],
        cwd=tmp_path, stderr=subprocess.PIPE, text=True, timeout=120, preexec_fn=_closed(1),
    )  # fmt: skip
    _one_sentence(res, "standard output is closed")
    assert (tmp_path / "rec" / "record.json").is_file()


def test_a_refusal_up_front_with_stdout_closed_is_one_sentence(tmp_path):
    """The address-space refusal said its sentence, then failed on ``sys.stdout.fileno()`` of a
    closed stdout with a traceback."""
    res = subprocess.run(
        [*GEOCON, "synth", "C1", "--out", "s", *SMALL],
        cwd=tmp_path, stderr=subprocess.PIPE, text=True, timeout=120, preexec_fn=_closed(1, address_space=1 << 30),
    )  # fmt: skip
    _one_sentence(res, "address space")


def test_closed_standard_streams_are_not_handed_to_the_command_s_files(tmp_path):
    """With stdin and stderr closed (``<&- 2>&-``) the command still runs, and its descriptors 0
    and 2 are the null device: the first file it opened took descriptor 0, and a native library's
    message meant for stderr would have gone into the next one."""
    read, write = os.pipe()
    script = f"""
        import os, sys
        sys.argv = ["geocon", "synth", "C1", "--out", "s", "--frames", "4", "--size", "64x64"]
        from geocon_viewer import cli
        from geocon_viewer.cli import commands_synth
        real = commands_synth.render_plans
        def render_plans(*args, **kwargs):
            with open("probe.txt", "w") as f:  # the first file the command opens
                os.write({write}, str(f.fileno()).encode())
            return real(*args, **kwargs)
        commands_synth.render_plans = render_plans
        cli.main()
    """

    def close_std() -> None:
        for fd in (0, 2):
            os.close(fd)

    proc = subprocess.Popen([sys.executable, "-c", textwrap.dedent(script)], cwd=tmp_path, pass_fds=(write,),
                            stdout=subprocess.DEVNULL, preexec_fn=close_std)  # fmt: skip
    os.close(write)
    with os.fdopen(read) as pipe:
        fd = pipe.read()
    assert proc.wait(timeout=120) == 0
    assert fd and int(fd) > 2, f"the command's file took descriptor {fd}"
    assert (tmp_path / "s" / "c1_static.mp4").is_file()


def test_a_failed_synth_bench_leaves_no_empty_folders(tmp_path):
    """A file-size limit stops ``synth-bench`` in its first clip: no ``ds/clean/C1-seed0``
    folders are left behind (the full disk's sentence is tested in test_resources)."""
    import resource

    def cap() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (20 << 10, 20 << 10))

    res = subprocess.run(
        [*GEOCON, "synth-bench", "--out", "ds", "--scenes", "1", "--families", "C1", "--frames", "24",
         "--size", "320x180"],
        cwd=tmp_path, capture_output=True, text=True, timeout=120, preexec_fn=cap,
    )  # fmt: skip
    assert res.returncode == 1 and "Traceback" not in res.stderr, res.stderr
    assert not (tmp_path / "ds").exists(), sorted(str(p) for p in (tmp_path / "ds").rglob("*"))


@pytest.mark.parametrize("home", ["", "relative"])
def test_an_empty_or_relative_home_is_no_footage_cache_at_the_root(tmp_path, home):
    """``HOME=`` made ``~/.cache/geocon/footage`` the folder ``/.cache/geocon/footage`` (and a
    relative HOME one under the current folder); the user database's home is used instead."""
    import pwd

    env = {k: v for k, v in os.environ.items() if k != "GEOCON_FOOTAGE"} | {"HOME": home}
    res = subprocess.run([*GEOCON, "footage", "status"], cwd=tmp_path, capture_output=True, text=True, env=env,
                         timeout=120)  # fmt: skip
    expected = Path(pwd.getpwuid(os.getuid()).pw_dir) / ".cache" / "geocon" / "footage"
    assert res.returncode == 0, res.stderr
    assert f"footage cache {expected}:" in " ".join(res.stdout.split()), res.stdout
