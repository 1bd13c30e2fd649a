"""The bad-output catalogue: outputs that are devices, FIFOs or sockets, outputs that are the
command's own inputs, empty paths, and a recording that meets a full disk or a file-size limit.

The cases use the framework of :mod:`tests.test_bad_input` (a :class:`Case` per command line,
judged by :func:`judge`: a refusal is exit 2 with one ``error:`` line and nothing changed or
left behind). Device nodes are made privately in each case's folder (``os.mknod``, so these cases
need root; they are skipped without it): no test opens, renames or removes the machine's own
``/dev/null`` or ``/dev/full``. The null device is the node with its device numbers, wherever it
lies. A full disk is a 1 MiB tmpfs (skipped where mounting is not allowed), a file-size limit is
``ulimit -f`` set in the child process (Python ignores SIGXFSZ, so a write past it fails with
EFBIG); every such run is a subprocess with a time limit, so a run that hangs fails instead."""

from __future__ import annotations

import os
import socket
import stat
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from geocon_core.files import OutPathError, replace_dir, replace_file, special_file

from .bad_inputs import snapshot
from .test_bad_input import FAST, Case, Ctx, Outcome, assets, build_all, ctx, judge, nothing, run_case, score  # noqa: F401
from .test_resources import _fill, _mount

NULL = os.makedev(1, 3)
"""The null device's numbers on Linux (``/dev/null``)."""
FULL = os.makedev(1, 7)
"""The full device's numbers on Linux (``/dev/full``: every write fails with ENOSPC)."""
RUN_LIMIT_S = 120
"""A subprocess still running after this long hangs (it is killed and the test fails)."""


# --- builders -------------------------------------------------------------------------------------


def node(name: str, rdev: int) -> Callable[[Ctx], None]:
    """A character device node ``name`` with device numbers ``rdev`` (skipped without the right)."""

    def build(c: Ctx) -> None:
        try:
            os.mknod(c.tmp / name, stat.S_IFCHR | 0o666, rdev)
        except PermissionError:
            pytest.skip("making a device node needs root (CAP_MKNOD)")

    return build


def fifo(name: str) -> Callable[[Ctx], None]:
    return lambda c: os.mkfifo(c.tmp / name)


def unix_socket(name: str) -> Callable[[Ctx], None]:
    def build(c: Ctx) -> None:
        sock = socket.socket(socket.AF_UNIX)
        sock.bind(str(c.tmp / name))
        sock.close()  # the socket file stays

    return build


def link(name: str, target: str) -> Callable[[Ctx], None]:
    return lambda c: os.symlink(target, c.tmp / name)


def pan(c: Ctx) -> None:
    c.pan()


def record(c: Ctx) -> None:
    c.record("rec")


def dust3r_scene(c: Ctx) -> None:
    """``scene.npz``: a DUSt3R scene of three views (the last 0.5 to the side)."""
    poses = np.stack([np.eye(4)] * 3)
    poses[2, 0, 3] = 0.5
    points = np.random.default_rng(0).random((4, 5, 3)) + [0.0, 0.0, 2.0]
    np.savez(c.tmp / "scene.npz", poses=poses, pts3d=points)


def colmap_model(c: Ctx) -> None:
    c.write("model/images.txt", "# a COLMAP model\n")
    c.write("model/points3D.txt", "# a COLMAP model\n")


def device_kept(name: str, rdev: int) -> Callable[[Ctx, Outcome], None]:
    """A check: ``name`` is still the character device ``rdev``."""

    def check(c: Ctx, _res: Outcome) -> None:
        st = os.lstat(c.tmp / name)
        assert stat.S_ISCHR(st.st_mode) and st.st_rdev == rdev, f"{name} is no longer the device it was"

    return check


def record_here(c: Ctx, _res: Outcome) -> None:
    assert (c.tmp / "record.json").is_file() and (c.tmp / "matches.npz").is_file()


# --- the catalogue --------------------------------------------------------------------------------

DEVICES = [
    Case("rrd-onto-the-null-device", build_all(pan, node("null", NULL)), score("clip.mp4", "--rrd", "null"), 2,
         ("--rrd", "null device"), check=device_kept("null", NULL)),
    Case("rrd-onto-the-full-device", build_all(pan, node("full", FULL)), score("clip.mp4", "--rrd", "full"), 2,
         ("--rrd", "full", "character device"), check=device_kept("full", FULL)),
    Case("rrd-onto-a-link-to-the-null-device", build_all(pan, node("null", NULL), link("nl.rrd", "null")),
         score("clip.mp4", "--rrd", "nl.rrd"), 2, ("--rrd", "null device")),
    Case("rrd-onto-a-fifo", build_all(pan, fifo("pipe.rrd")), score("clip.mp4", "--rrd", "pipe.rrd"), 2,
         ("--rrd", "FIFO"), runner="subprocess"),
    Case("rrd-onto-a-socket", build_all(pan, unix_socket("s.rrd")), score("clip.mp4", "--rrd", "s.rrd"), 2,
         ("--rrd", "socket")),
    Case("view-save-onto-a-character-device", build_all(record, node("full", FULL)),
         ("view", "rec", "--headless", "--save", "full"), 2, ("--save", "character device"),
         check=device_kept("full", FULL), needs=("rerun",)),
    Case("view-save-onto-a-fifo", build_all(record, fifo("pipe.rrd")),
         ("view", "rec", "--headless", "--save", "pipe.rrd"), 2, ("--save", "FIFO"), runner="subprocess",
         needs=("rerun",)),
    Case("view-screenshot-onto-the-null-device", build_all(record, node("null", NULL)),
         ("view", "rec", "--headless", "--screenshot", "null"), 2, ("--screenshot", "null device"),
         needs=("rerun",)),
    Case("pose-log-out-onto-the-null-device", build_all(dust3r_scene, node("null", NULL)),
         ("pose-log", "scene.npz", "--out", "null"), 2, ("--out", "null device"), check=device_kept("null", NULL)),
    Case("score-out-is-a-character-device", build_all(pan, node("full", FULL)), score("clip.mp4", out="full"), 2,
         ("--out", "not a folder")),
    Case("record-part-is-a-device", build_all(pan, lambda c: (c.tmp / "rec").mkdir(), node("rec/audit.rrd", FULL)),
         score("clip.mp4", out="rec"), 2, ("audit.rrd", "character device"), check=device_kept("rec/audit.rrd", FULL)),
    Case("synth-out-is-the-null-device", node("null", NULL), ("synth", "C1", "--out", "null", "--frames", "4"), 2,
         ("--out", "not a folder")),
    Case("synth-bench-out-is-a-file", lambda c: c.write("afile", "x"), ("synth-bench", "--out", "afile"), 2,
         ("--out", "afile")),
    Case("demo-out-is-a-file", lambda c: c.write("afile", "x"), ("demo", "--out", "afile"), 2, ("--out", "afile")),
    Case("validate-out-is-a-device", node("full", FULL), ("validate", "--out", "full", "--quick", "--no-real"), 2,
         ("--out", "full")),
]  # fmt: skip

INPUTS = [
    Case("pose-log-out-is-its-input", dust3r_scene, ("pose-log", "scene.npz", "--out", "scene.npz"), 2,
         ("--out", "scene.npz", "DUSt3R scene")),
    Case("pose-log-out-inside-the-colmap-model", colmap_model, ("pose-log", "model", "--out", "model/p.json"), 2,
         ("--out", "COLMAP model")),
    Case("bench-out-is-the-manifest", lambda c: c.write("m.csv", "clip_id,path\n"),
         ("bench", "m.csv", "--out", "m.csv", *FAST, "--no-rrd"), 2, ("--out", "m.csv", "manifest")),
    Case("validate-out-inside-the-data", lambda c: c.tmp.joinpath("data").mkdir(),
         ("validate", "--out", "data/v", "--data", "data", "--no-synthetic", "--no-peer"), 2, ("--out", "--data")),
    Case("validate-cache-is-the-out", nothing, ("validate", "--out", "v", "--cache", "v"), 2,
         ("--cache", "--out")),
    Case("footage-fill-into-its-clones", lambda c: c.tmp.joinpath("clones").mkdir(),
         ("footage", "fill", "--from", "clones", "--footage", "clones/cache"), 2, ("--footage", "--from")),
    Case("score-rrd-is-the-out", pan, score("clip.mp4", "--rrd", "rec", out="rec"), 2, ("--rrd", "--out")),
    Case("view-save-is-the-screenshot", record, ("view", "rec", "--headless", "--save", "a.png", "--screenshot",
         "a.png"), 2, ("--screenshot", "--save"), needs=("rerun",)),
]  # fmt: skip

EMPTY = [
    Case("score-out-empty", pan, score("clip.mp4", out=""), 2, ("--out", "empty path")),
    Case("score-out-equals-nothing", pan, ("score", "clip.mp4", *FAST, "--out="), 2, ("--out", "empty path")),
    Case("score-clip-empty", nothing, ("score", "", *FAST), 2, ("CLIP", "empty path")),
    Case("score-rrd-empty", pan, score("clip.mp4", "--rrd", ""), 2, ("--rrd", "empty path")),
    Case("score-masks-empty", pan, score("clip.mp4", "--masks", ""), 2, ("--masks", "empty path")),
    Case("view-save-empty", record, ("view", "rec", "--headless", "--save", ""), 2, ("--save", "empty path")),
    Case("pose-log-out-empty", dust3r_scene, ("pose-log", "scene.npz", "--out", ""), 2, ("--out", "empty path")),
    Case("bench-out-empty", lambda c: c.pan("ds/p/a.mp4"), ("bench", "ds", "--out", "", *FAST, "--no-rrd"), 2,
         ("--out", "empty path")),
    Case("bench-root-empty", lambda c: c.pan("ds/p/a.mp4"), ("bench", "ds", "--out", "r", "--root", ""), 2,
         ("--root", "empty path")),
    Case("report-out-empty", nothing, ("report", "res", "--out", ""), 2, ("--out", "empty path")),
    Case("synth-out-empty", nothing, ("synth", "C1", "--out", ""), 2, ("--out", "empty path")),
    Case("score-out-is-the-current-folder", pan, score("clip.mp4", out="."), 0, check=record_here),
]  # fmt: skip

# --- reports of results that are damaged, unfinished or still being written ----------------------


def benched(c: Ctx) -> None:
    """``ds/p/a.mp4`` scored by ``geocon bench`` into ``res`` (bench.json, clips/, tables/)."""
    c.pan("ds/p/a.mp4")
    res = c.invoke(["bench", "ds", "--out", "res", *FAST, "--no-rrd"])
    assert res.code == 0, res.describe()


def benched_then(path: str, data: bytes | None) -> Callable[[Ctx], None]:
    """``benched``, then ``res/<path>`` replaced by ``data`` (removed, a folder, when None)."""

    def build(c: Ctx) -> None:
        benched(c)
        target = c.tmp / "res" / path
        if data is None:
            import shutil

            shutil.rmtree(target)
        else:
            target.write_bytes(data)

    return build


HELD: list[object] = []
"""Locks the cases hold while their command runs (released by the next case that takes one)."""


def bench_running(c: Ctx) -> None:
    """``benched``, and its results folder's lock held, as a running ``geocon bench`` holds it."""
    from geocon_core.bench import lock_path
    from geocon_core.files import FolderLock

    benched(c)
    while HELD:
        HELD.pop().release()  # type: ignore[attr-defined]
    lock = FolderLock(lock_path(c.tmp / "res"))
    lock.acquire()
    HELD.append(lock)


def released(_c: Ctx, _res: Outcome) -> None:
    while HELD:
        HELD.pop().release()  # type: ignore[attr-defined]


LONG_NAME = "r" * 255
"""A folder name at the 255-byte limit of common file systems."""


def report_here(c: Ctx, _res: Outcome) -> None:
    assert (c.tmp / LONG_NAME / "report.html").is_file()
    assert not [n for n in os.listdir(c.tmp) if ".part" in n or ".old" in n]


REPORTS = [
    Case("report-bench-json-is-an-array", benched_then("bench.json", b"[]"), ("report", "res", "--bootstrap", "100"),
         2, ("res/bench.json", "an array", "damaged")),
    Case("report-bench-json-not-utf8", benched_then("bench.json", b"\x98\x00\xff"),
         ("report", "res", "--bootstrap", "100"), 2, ("res/bench.json", "not UTF-8"), forbids=("codec", "again")),
    Case("report-of-a-damaged-parquet-table", benched_then("tables/clips.parquet", b"PAR1 and then nothing"),
         ("report", "res", "--bootstrap", "100"), 2, ("res/tables/clips.parquet", "Parquet", "geocon bench")),
    Case("report-of-results-without-tables", benched_then("tables", None), ("report", "res", "--bootstrap", "100"), 2,
         ("res/tables", "missing clips.parquet")),
    Case("report-while-a-bench-writes-the-results", bench_running, ("report", "res", "--bootstrap", "100"), 2,
         ("res", "running `geocon bench`", f"PID {os.getpid()}"), check=released),
    Case("report-out-with-a-255-byte-name", benched, ("report", "res", "--bootstrap", "100", "--out", LONG_NAME), 0,
         check=report_here),
    Case("bench-out-with-a-255-byte-name", lambda c: c.pan("ds/p/a.mp4"),
         ("bench", "ds", "--out", LONG_NAME, *FAST, "--no-rrd"), 0),
]  # fmt: skip

CASES = DEVICES + INPUTS + EMPTY + REPORTS


def test_the_catalogue_is_complete():
    names = [c.name for c in CASES]
    assert len(names) == len(set(names)), "case names are unique"


@pytest.mark.full
@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_bad_output(case: Case, ctx: Ctx):  # noqa: F811
    run_case(case, ctx)


# --- the rule's one home --------------------------------------------------------------------------


def test_the_null_device_is_told_by_its_numbers_not_its_path(tmp_path: Path):
    try:
        os.mknod(tmp_path / "somewhere", stat.S_IFCHR | 0o666, NULL)
        os.mknod(tmp_path / "null", stat.S_IFCHR | 0o666, FULL)
    except PermissionError:
        pytest.skip("making a device node needs root (CAP_MKNOD)")
    os.mkfifo(tmp_path / "fifo")
    (tmp_path / "file").write_bytes(b"x")
    assert special_file(tmp_path / "somewhere") == "the null device"
    assert special_file(tmp_path / "null") == "a character device"
    assert special_file(tmp_path / "fifo") == "a FIFO (named pipe)"
    assert [special_file(tmp_path / n) for n in ("file", "missing")] + [special_file(tmp_path)] == [None] * 3


def test_replace_file_never_renames_over_a_fifo(tmp_path: Path):
    os.mkfifo(tmp_path / "target")
    (tmp_path / "new").write_bytes(b"new")
    with pytest.raises(OutPathError, match="FIFO"):
        replace_file(tmp_path / "new", tmp_path / "target")
    assert stat.S_ISFIFO(os.lstat(tmp_path / "target").st_mode) and not (tmp_path / "new").exists()
    (tmp_path / "new").write_bytes(b"new")
    (tmp_path / "old").write_bytes(b"old")
    replace_file(tmp_path / "new", tmp_path / "old")
    assert (tmp_path / "old").read_bytes() == b"new" and not (tmp_path / "new").exists()


def test_replace_dir_never_replaces_a_file(tmp_path: Path):
    (tmp_path / "report").write_bytes(b"a file")
    with pytest.raises(OutPathError, match="not a folder"):
        with replace_dir(tmp_path / "report") as stage:
            (stage / "index.html").write_text("x")
    assert (tmp_path / "report").read_bytes() == b"a file" and sorted(os.listdir(tmp_path)) == ["report"]


# --- a recording that cannot be written -----------------------------------------------------------


def _geocon(args: list[str], cwd: Path, fsize: int | None = None) -> subprocess.CompletedProcess:
    """``geocon ARGS`` in ``cwd``, with ``ulimit -f`` of ``fsize`` bytes; killed after :data:`RUN_LIMIT_S`."""
    import resource

    def limit() -> None:
        if fsize is not None:
            resource.setrlimit(resource.RLIMIT_FSIZE, (fsize, fsize))

    return subprocess.run(
        [sys.executable, "-m", "geocon_viewer.cli", *args], cwd=cwd, capture_output=True, text=True,
        timeout=RUN_LIMIT_S, preexec_fn=limit,
    )  # fmt: skip


def _one_sentence(res: subprocess.CompletedProcess, *words: str) -> None:
    lines = [line for line in res.stderr.splitlines() if line.strip() and "━" not in line and "frames" not in line]
    assert res.returncode == 1 and "Traceback" not in res.stderr, res.stderr
    assert len(lines) == 1 and lines[0].startswith("error: "), res.stderr
    for word in words:
        assert word in lines[0], lines[0]


def _parts(folder: Path) -> list[str]:
    return [p.name for p in folder.iterdir() if ".part" in p.name]


@pytest.fixture()
def scored(tmp_path: Path, assets) -> Path:  # noqa: F811
    """A folder with ``clip.mp4``, its record ``rec/`` and its recording ``a.rrd`` (a first run)."""
    pytest.importorskip("rerun")
    (tmp_path / "clip.mp4").write_bytes(assets.pan.read_bytes())
    first = _geocon(["score", "clip.mp4", *FAST, "--out", "rec", "--rrd", "a.rrd"], tmp_path)
    assert first.returncode == 0, first.stderr
    assert (tmp_path / "a.rrd").stat().st_size > 100_000  # so a 64 KiB limit stops it
    return tmp_path


def _score_again(work: Path, rrd: Path, fsize: int | None = None) -> subprocess.CompletedProcess:
    return _geocon(["score", "clip.mp4", *FAST, "--out", "rec", "--rrd", str(rrd), "--fov", "70"], work, fsize)


@pytest.mark.full
def test_a_file_size_limit_while_scoring_stops_with_one_sentence_and_keeps_the_recording(scored: Path):
    before = snapshot(scored)
    res = _score_again(scored, scored / "a.rrd", fsize=64 * 1024)
    _one_sentence(res, "a file grew past the file system's limit", "a.rrd")
    assert snapshot(scored) == before and not _parts(scored)


def test_a_file_size_limit_while_viewing_stops_with_one_sentence_and_keeps_the_recording(scored: Path):
    before = snapshot(scored)
    res = _geocon(["view", "rec", "--headless", "--save", "a.rrd"], scored, fsize=64 * 1024)
    _one_sentence(res, "a file grew past the file system's limit", "a.rrd")
    assert snapshot(scored) == before and not _parts(scored)


@pytest.mark.full
def test_a_full_disk_while_the_recording_is_written(scored: Path):
    """The record (on the working disk) and the recording (on a full one) are one unit: neither
    changes, and the full disk holds no partial file."""
    mount = scored / "disk"
    _mount(mount)
    try:
        first = _geocon(["score", "clip.mp4", *FAST, "--out", "rec", "--rrd", str(mount / "a.rrd")], scored)
        assert first.returncode == 0, first.stderr
        _fill(mount, 16 * 1024)
        before = snapshot(scored)
        res = _score_again(scored, mount / "a.rrd")
        _one_sentence(res, "the disk is full", "a.rrd")
        assert snapshot(scored) == before and not _parts(mount)
        view = _geocon(["view", "rec", "--headless", "--save", str(mount / "a.rrd")], scored)
        _one_sentence(view, "the disk is full", "a.rrd")
        assert snapshot(scored) == before and not _parts(mount)
    finally:
        subprocess.run(["umount", "-l", str(mount)], capture_output=True)


def test_a_recording_written_by_the_pipe_reads_back_whole(scored: Path):
    """The recording is a single valid RRD stream with its footer: Rerun's reader finds the
    recording and the layout, and every frame of the clip."""
    from rerun.chunk import RrdReader

    reader = RrdReader(scored / "a.rrd")
    (store,) = reader.recordings()
    assert len(reader.blueprints()) == 1
    frames = set()
    for chunk in reader.stream(store=store):
        if chunk.entity_path == "/frame/matches/inliers":
            frames.update(chunk.to_record_batch().column("frame").to_pylist())
    assert frames == set(range(11)), sorted(frames)  # pairs (t, t+1) of the 12 frames


# --- benchmarks, reports and sidecars on a disk that fills or cannot be written --------------------


def _plain_dataset(work: Path, clips: int = 2, frames: int = 12, size: tuple[int, int] = (160, 90)) -> None:
    from .bad_inputs import pan_frames, write_video

    (work / "ds" / "p").mkdir(parents=True)
    for k in range(clips):
        write_video(work / "ds" / "p" / f"c{k}.mp4", pan_frames(*size, frames, seed=k + 1))


def _hidden(folder: Path) -> list[str]:
    """What a run left of its temporary files below ``folder``."""
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*") if ".part" in p.name or ".old-" in p.name)


def _machines_sentence(res: subprocess.CompletedProcess, words: str) -> None:
    """Exit 1 and, besides the notes on the dataset and the progress bar, one line: ``error: WORDS...``."""
    lines = [line for line in res.stderr.splitlines() if line.strip() and not line.startswith(("note: ", "benchmark"))]
    assert res.returncode == 1 and "Traceback" not in res.stderr, res.stderr
    assert len(lines) == 1 and lines[0].startswith(f"error: {words}"), res.stderr


@pytest.mark.full
def test_a_bench_on_a_full_disk_stops_records_no_failure_and_resumes(tmp_path: Path):
    """A full disk is the machine's failure, not the clip's: the run stops with one sentence,
    no clip is recorded as failed (a resumed run would keep that), nothing partial is left, and
    the same command finishes the benchmark once there is room."""
    _plain_dataset(tmp_path)
    mount = tmp_path / "disk"
    _mount(mount)
    try:
        _fill(mount, 64 * 1024)
        res = _geocon(["bench", "ds", "--out", str(mount / "res"), *FAST, "--no-rrd"], tmp_path)
        _machines_sentence(res, "the disk is full")
        assert "failed p-" not in res.stderr and not list(mount.rglob("status.json")) and not _hidden(mount)
        (mount / "filler").unlink()
        again = _geocon(["bench", "ds", "--out", str(mount / "res"), *FAST, "--no-rrd"], tmp_path)
        assert again.returncode == 0 and "2 clips: 2 scored, 0 failed" in again.stdout, again.stderr
    finally:
        subprocess.run(["umount", "-l", str(mount)], capture_output=True)


def test_a_bench_whose_disk_is_full_at_its_first_file_leaves_no_results_folder(tmp_path: Path):
    _plain_dataset(tmp_path, clips=1)
    mount = tmp_path / "disk"
    _mount(mount)
    try:
        _fill(mount, 4 * 1024)
        res = _geocon(["bench", "ds", "--out", str(mount / "res"), *FAST, "--no-rrd"], tmp_path)
        _machines_sentence(res, "the disk is full")
        assert sorted(p.name for p in mount.iterdir()) == ["filler"]
    finally:
        subprocess.run(["umount", "-l", str(mount)], capture_output=True)


@pytest.mark.full
def test_a_report_on_a_full_disk_is_the_machines_sentence_and_leaves_nothing(tmp_path: Path):
    _plain_dataset(tmp_path, clips=1)
    assert _geocon(["bench", "ds", "--out", "res", *FAST, "--no-rrd"], tmp_path).returncode == 0
    mount = tmp_path / "disk"
    _mount(mount)
    try:
        _fill(mount, 64 * 1024)
        res = _geocon(["report", "res", "--bootstrap", "100", "--out", str(mount / "rep")], tmp_path)
        lines = [line for line in res.stderr.splitlines() if not line.startswith(("report: ", "note: "))]
        assert res.returncode == 1 and len(lines) == 1 and lines[0].startswith("error: the disk is full"), res.stderr
        assert sorted(p.name for p in mount.iterdir()) == ["filler"]
    finally:
        subprocess.run(["umount", "-l", str(mount)], capture_output=True)


def _dataset_lines(res: subprocess.CompletedProcess) -> list[str]:
    """stderr of ``geocon dataset`` less its notes on the dataset."""
    return [line for line in res.stderr.splitlines() if line.strip() and not line.startswith("note: ")]


def test_dataset_write_into_a_read_only_folder_is_the_machines_sentence(tmp_path: Path):
    _plain_dataset(tmp_path / "src", clips=1)
    ds = tmp_path / "ds"
    ds.mkdir()
    bound = subprocess.run(["mount", "--bind", str(tmp_path / "src" / "ds"), str(ds)], capture_output=True)
    if bound.returncode != 0:
        pytest.skip(f"cannot bind-mount here ({bound.stderr.decode(errors='replace').strip()})")
    try:
        subprocess.run(["mount", "-o", "remount,ro,bind", str(ds)], check=True, capture_output=True)
        before = snapshot(ds)
        res = _geocon(["dataset", "ds", "--write"], tmp_path)
        lines = _dataset_lines(res)
        assert res.returncode == 1 and len(lines) == 1, res.stderr
        assert lines[0].startswith("error: the file system is read-only") and "p/c0.meta.json" in lines[0], lines
        assert snapshot(ds) == before
    finally:
        subprocess.run(["umount", "-l", str(ds)], capture_output=True)


def test_dataset_write_on_a_full_disk_writes_every_sidecar_or_none(tmp_path: Path):
    """Room for one sidecar but not two: none is written (a dataset with one sidecar would read as
    a sidecar dataset without its other clip), and no temporary file is left."""
    mount = tmp_path / "disk"
    _mount(mount)
    try:
        _plain_dataset(mount, clips=2, frames=4, size=(32, 32))
        before = snapshot(mount / "ds")
        _fill(mount, 4096)  # one page of the tmpfs
        res = _geocon(["dataset", str(mount / "ds"), "--write"], tmp_path)
        lines = _dataset_lines(res)
        assert res.returncode == 1 and len(lines) == 1 and lines[0].startswith("error: the disk is full"), res.stderr
        assert snapshot(mount / "ds") == before and not _hidden(mount)
    finally:
        subprocess.run(["umount", "-l", str(mount)], capture_output=True)


@pytest.mark.full
def test_ctrl_c_during_a_bench_leaves_no_staging_folder_and_the_rerun_finishes(tmp_path: Path):
    """Ctrl-C (SIGINT to the process group) while clips are being scored: exit 130, the clips in
    flight leave nothing behind (neither their staging folders nor their clip folders), and the
    same command scores them."""
    import signal
    import time

    _plain_dataset(tmp_path, clips=3, frames=48, size=(320, 180))
    argv = [sys.executable, "-m", "geocon_viewer.cli", "bench", "ds", "--out", "res", *FAST, "--no-rrd"]
    proc = subprocess.Popen(argv, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)  # fmt: skip
    clips = tmp_path / "res" / "clips"
    deadline = time.monotonic() + RUN_LIMIT_S
    while not (clips.is_dir() and _hidden(clips)) and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)
    assert proc.poll() is None, "the run ended before a clip was in flight"
    os.killpg(proc.pid, signal.SIGINT)
    _out, err = proc.communicate(timeout=RUN_LIMIT_S)
    assert proc.returncode == 130 and "Traceback" not in err and "interrupted" in err, err
    assert not _hidden(tmp_path / "res")
    assert all((c / "status.json").is_file() for c in clips.iterdir()), sorted(os.listdir(clips))
    again = _geocon(["bench", "ds", "--out", "res", *FAST, "--no-rrd"], tmp_path)
    assert again.returncode == 0 and "3 clips: 3 scored, 0 failed" in again.stdout, again.stderr
