"""The machine's limits, not GeoCon's bugs: a full disk, a read-only file system and a closed
output end a command with one sentence (exit 1), never a traceback or a segfault, and what was
there before is unchanged. The full and read-only disks are small tmpfs mounts (skipped where this
machine does not allow mounting)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from .bad_inputs import pan_frames, snapshot, write_video


def _geocon(args: list[str], cwd: Path, stdout: int | None = subprocess.PIPE) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "geocon_viewer.cli", *args],
        cwd=cwd,
        stdout=stdout,
        stderr=subprocess.PIPE,
        text=True,
        timeout=120,
    )


def _mount(folder: Path, *options: str) -> None:
    folder.mkdir(exist_ok=True)
    res = subprocess.run(["mount", "-t", "tmpfs", "-o", ",".join(["size=1m", *options]), "tmpfs", str(folder)],
                         capture_output=True)  # fmt: skip
    if res.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here ({res.stderr.decode(errors='replace').strip()})")


@pytest.fixture()
def disk(tmp_path: Path):
    """(working folder with clip.mp4, a 1 MiB tmpfs ``disk`` inside it)."""
    write_video(tmp_path / "clip.mp4", pan_frames(160, 90, 12, seed=1))
    mount = tmp_path / "disk"
    _mount(mount)
    yield tmp_path, mount
    subprocess.run(["umount", "-l", str(mount)], capture_output=True)


def _fill(mount: Path, leave: int) -> None:
    """Fill the tmpfs until about ``leave`` bytes are free."""
    st = os.statvfs(mount)
    free = st.f_bavail * st.f_frsize
    with open(mount / "filler", "wb") as fh:
        fh.write(b"\0" * max(0, free - leave))


def _one_sentence(res: subprocess.CompletedProcess, words: str) -> None:
    lines = [line for line in res.stderr.splitlines() if line.strip() and "━" not in line and "frames" not in line]
    assert res.returncode == 1, res.stderr
    assert "Traceback" not in res.stderr and len(lines) == 1 and lines[0].startswith("error: "), res.stderr
    assert words in lines[0], lines[0]


@pytest.mark.full
def test_a_full_disk_keeps_the_previous_record(disk):
    work, mount = disk
    first = _geocon(["score", "clip.mp4", "--preset", "fast", "--out", str(mount / "rec")], work)
    assert first.returncode == 0, first.stderr
    before = snapshot(mount / "rec")
    _fill(mount, 4096)
    res = _geocon(["score", "clip.mp4", "--preset", "fast", "--out", str(mount / "rec"), "--fov", "70"], work)
    _one_sentence(res, "the disk is full")
    assert snapshot(mount / "rec") == before
    assert sorted(p.name for p in mount.iterdir()) == ["filler", "rec"]  # no staging folder left


def test_a_full_disk_stops_synth_without_a_partial_clip(disk):
    work, mount = disk
    _fill(mount, 64 * 1024)
    res = _geocon(["synth", "C1", "--out", str(mount / "s"), "--frames", "48"], work)
    _one_sentence(res, "the disk is full")
    assert not list((mount / "s").glob("*.mp4")) and not list((mount / "s").glob(".*.part*"))


def test_a_read_only_file_system_is_one_sentence(tmp_path):
    write_video(tmp_path / "clip.mp4", pan_frames(160, 90, 12, seed=1))
    mount = tmp_path / "ro"
    _mount(mount, "ro")
    try:
        res = _geocon(["score", "clip.mp4", "--preset", "fast", "--out", str(mount / "rec")], tmp_path)
        assert res.returncode in (1, 2) and "Traceback" not in res.stderr, res.stderr
        assert "read-only file system" in res.stderr, res.stderr
    finally:
        subprocess.run(["umount", "-l", str(mount)], capture_output=True)


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full")
def test_a_closed_or_full_stdout_is_one_sentence_and_the_record_is_kept(tmp_path):
    write_video(tmp_path / "clip.mp4", pan_frames(160, 90, 12, seed=1))
    with open("/dev/full", "w") as full:
        res = _geocon(
            ["score", "clip.mp4", "--preset", "fast", "--out", "rec", "--json"], tmp_path, stdout=full.fileno()
        )
    _one_sentence(res, "the disk is full")
    assert (tmp_path / "rec" / "record.json").is_file()


def test_an_address_space_too_small_for_the_native_libraries_is_refused_up_front(tmp_path):
    import resource

    write_video(tmp_path / "clip.mp4", pan_frames(160, 90, 12, seed=1))
    limit = 1536 << 20  # 1.5 GiB: OpenCV crashed in its worker threads here before the check

    def cap() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))

    res = subprocess.run(
        [sys.executable, "-m", "geocon_viewer.cli", "score", "clip.mp4", "--preset", "fast", "--out", "rec"],
        cwd=tmp_path, capture_output=True, text=True, timeout=60, preexec_fn=cap,
    )  # fmt: skip
    _one_sentence(res, "1.50 GiB of address space")
    assert not (tmp_path / "rec").exists()


@pytest.mark.full
def test_kill_during_scoring_leaves_the_previous_record_and_no_partial_files(tmp_path):
    """``kill`` (SIGTERM) stops a run as cleanly as Ctrl-C: exit 130 within the grace period, the
    previous record and its recording unchanged; a temporary folder left by a clean-up cut short is
    removed by the next run."""
    import signal
    import time

    from geocon_core.synth import ClipPlan, write_clip
    from geocon_viewer.cli import TERM_GRACE_S

    gt = write_clip(ClipPlan("C4"), tmp_path, seed=1, width=320, height=180, num_frames=48)
    args = [sys.executable, "-m", "geocon_viewer.cli", "score", gt.video_path, "--preset", "fast", "--out", "rec"]
    first = subprocess.run([*args, "--rrd", "rec.rrd"], cwd=tmp_path, capture_output=True, timeout=300)
    assert first.returncode == 0, first.stderr
    before = snapshot(tmp_path / "rec"), (tmp_path / "rec.rrd").read_bytes()
    proc = subprocess.Popen([*args, "--rrd", "rec.rrd", "--fov", "70"], cwd=tmp_path, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while not list(tmp_path.glob(".rec.part-*")) and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.02)  # until the run stages its record: scoring has started
    proc.send_signal(signal.SIGTERM)
    _, stderr = proc.communicate(timeout=TERM_GRACE_S + 20)
    assert proc.returncode == 130 and "Traceback" not in stderr, stderr
    assert (snapshot(tmp_path / "rec"), (tmp_path / "rec.rrd").read_bytes()) == before
    again = subprocess.run([*args, "--rrd", "rec.rrd"], cwd=tmp_path, capture_output=True, timeout=300)
    assert again.returncode == 0, again.stderr
    assert not [p.name for p in tmp_path.iterdir() if ".part" in p.name]


SHIM = """
import errno, pathlib, sys
real = pathlib.Path.write_bytes
def full(self, data):  # the disk fills up just as the record is written
    if self.name.startswith(".matches.npz"):
        raise OSError(errno.ENOSPC, "No space left on device", str(self))
    return real(self, data)
pathlib.Path.write_bytes = full
from geocon_viewer.cli import main
sys.argv = ["geocon", "score", "clip.mp4", "--preset", "fast", "--out", "rec", "--fov", "70"]
main()
"""


@pytest.mark.full
def test_a_disk_that_fills_while_the_record_is_written_keeps_the_previous_one(tmp_path):
    """The same promise where no tmpfs can be mounted: a file-system shim fails the record's write."""
    write_video(tmp_path / "clip.mp4", pan_frames(160, 90, 12, seed=1))
    first = _geocon(["score", "clip.mp4", "--preset", "fast", "--out", "rec"], tmp_path)
    assert first.returncode == 0, first.stderr
    before = snapshot(tmp_path / "rec")
    res = subprocess.run([sys.executable, "-c", SHIM], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    _one_sentence(res, "the disk is full")
    assert snapshot(tmp_path / "rec") == before
    assert not [p.name for p in tmp_path.iterdir() if ".part" in p.name]
