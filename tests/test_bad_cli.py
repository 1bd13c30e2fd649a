"""Command-line failures around GeoCon's inputs: a Rerun viewer URL that is malformed or answers
nowhere, too few open files, a bench worker killed mid-run, a terminal that shows ASCII only,
non-finite or repeated options, and out-of-memory advice. Each ends in one sentence (exit 2 for a
bad option, exit 1 for the machine or the network), never a traceback, and leaves nothing behind.

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

import pytest

from geocon_viewer.cli import RESOURCE_ERRORS, app

from . import test_bad_input as catalogue
from .bad_inputs import pan_frames, snapshot, write_video
from .test_bad_input import FAST, Case, Ctx, Outcome, dataset, judge, nothing

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
    for module in case.needs:
        pytest.importorskip(module)
    case.build(ctx)
    before = snapshot(ctx.tmp)
    res = ctx.invoke(list(case.argv)) if case.runner == "cli" else ctx.spawn(list(case.argv))
    problems = judge_all(case, ctx, res, before)
    assert not problems, f"{case.name}: {res.describe()}\n  - " + "\n  - ".join(problems)


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
    from geocon_viewer import processes, rerun_log

    ctx.record()
    before = snapshot(ctx.tmp)

    def severed(*_args: object, **_options: object) -> None:
        raise RuntimeError("gRPC connection severed")

    monkeypatch.setattr(processes, "check_viewer_url", lambda url, **_: ("127.0.0.1", 9876))
    monkeypatch.setattr(rerun_log, "write_rrd", severed)
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
                    if "multiprocessing" in " ".join(child.cmdline()):
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


@pytest.mark.parametrize(
    "argv",
    [("synth", "C1", "--out", "s", *SMALL), ("synth-failures",), ("presets",), ("doctor",)],
    ids=lambda argv: argv[0],
)
def test_an_ascii_terminal_gets_every_table(tmp_path, argv):
    _ascii_run(tmp_path, *argv)


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
