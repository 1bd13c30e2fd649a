"""Record folders change all at once: a run that fails part-way leaves the previous record byte
for byte, a successful one replaces every part (and drops a recording of the old record), other
files in the folder stay, and staging folders of killed runs are cleared."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from geocon_core.bench import staged_record


def _tree(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _write_record(folder: Path, tag: str, overlays: int) -> None:
    (folder / "overlays").mkdir(parents=True, exist_ok=True)
    for k in range(overlays):
        (folder / "overlays" / f"labels-{k:05d}.png").write_bytes(f"{tag}{k}".encode())
    (folder / "overlays" / "index.json").write_text(tag)
    (folder / "matches.npz").write_text(tag)
    (folder / "record.json").write_text(tag)


def test_a_failed_run_leaves_the_previous_record_byte_for_byte(tmp_path):
    out = tmp_path / "D"
    _write_record(out, "old", 3)
    (out / "notes.txt").write_text("mine")
    before = _tree(out)
    with pytest.raises(RuntimeError), staged_record(out) as stage:
        _write_record(stage, "new", 1)
        raise RuntimeError("scoring failed after the first frame")
    assert _tree(out) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["D"]  # no staging folder left


def test_a_finished_run_replaces_every_part_and_keeps_other_files(tmp_path):
    out = tmp_path / "D"
    _write_record(out, "old", 3)
    (out / "audit.rrd").write_text("recording of the old record")
    (out / "notes.txt").write_text("mine")
    with staged_record(out) as stage:
        _write_record(stage, "new", 1)
    assert _tree(out) == {
        "matches.npz": b"new",
        "notes.txt": b"mine",
        "overlays/index.json": b"new",
        "overlays/labels-00000.png": b"new0",
        "record.json": b"new",
    }
    assert sorted(p.name for p in tmp_path.iterdir()) == ["D"]


def test_staging_folders_of_killed_runs_are_cleared(tmp_path):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    stale = tmp_path / f".D.part-{int(dead.stdout)}"
    _write_record(stale, "half", 2)
    alive = tmp_path / f".D.part-{os.getppid()}"  # a running process's staging folder is not touched
    alive.mkdir()
    with staged_record(tmp_path / "D") as stage:
        _write_record(stage, "new", 1)
    assert not stale.exists() and alive.exists()
    assert (tmp_path / "D" / "record.json").read_text() == "new"


def test_a_signal_during_the_commit_waits_for_the_record_and_its_recording(tmp_path, monkeypatch):
    """Ctrl-C arriving while a record and its recording are moved into place is held until both
    are there, then delivered: the folder never pairs a new record with an old recording."""
    import signal

    import geocon_core.bench.staging as staging

    out, rrd, part = tmp_path / "D", tmp_path / "audit.rrd", tmp_path / ".audit.rrd.part"
    _write_record(out, "old", 2)
    rrd.write_text("old")
    real_commit = staging._commit

    def interrupted_commit(stage: Path, out_dir: Path) -> None:
        os.kill(os.getpid(), signal.SIGINT)  # arrives between the first rename and the last
        real_commit(stage, out_dir)

    monkeypatch.setattr(staging, "_commit", interrupted_commit)
    with pytest.raises(KeyboardInterrupt), staged_record(out, then=[lambda: part.replace(rrd)]) as stage:
        _write_record(stage, "new", 1)
        part.write_text("new")
    assert (out / "record.json").read_text() == "new" and (out / "matches.npz").read_text() == "new"
    assert rrd.read_text() == "new" and not part.exists()
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # the handler is given back
    with pytest.raises(RuntimeError), staged_record(out, then=[lambda: part.replace(rrd)]) as stage:
        _write_record(stage, "newer", 1)
        part.write_text("newer")
        raise RuntimeError("failed before the commit")
    assert (out / "record.json").read_text() == "new" and rrd.read_text() == "new"  # the old pair, whole
