"""Bad input to `geocon serve`, `geocon view` and the record readers gets one clear sentence and
nothing hangs: an impossible --port or --host is refused before anything starts, a busy port
says where it moved, a corrupt or pickled record is refused naming its file (and listed as
broken by the audit app, whose preload goes on), and --at is checked against the clip."""

from __future__ import annotations

import pickle
import shutil
import signal
import socket
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

from geocon_core.config import ScoreConfig
from geocon_core.record import MAX_RECORD_JSON_BYTES, RecordError, read_record, read_record_json
from geocon_core.scoring import load_residuals
from geocon_viewer.capture.processes import BindError, check_bind

GEOCON = [sys.executable, "-m", "geocon_viewer.cli"]
CLEAN, BREATHING, ELASTIC = "clean-c1_static-s0", "breathing-c1_static-s0", "elastic-c1_static-s0"


@pytest.fixture(scope="module")
def results(tmp_path_factory) -> Path:
    """Three short synthetic clips (C1: clean, breathing, elastic), scored by `geocon bench`."""
    from geocon_core.bench import run_bench
    from geocon_core.synth import plan_benchmark, write_benchmark

    data = tmp_path_factory.mktemp("bad-serve-data")
    write_benchmark(data, plan_benchmark(families=("C1",), scenes=1), width=320, height=180, num_frames=8)
    out = tmp_path_factory.mktemp("bad-serve-results") / "r"
    summary = run_bench(data, out, ScoreConfig(working_size=(320, 180)), workers=1)
    assert (summary.total, summary.failed) == (3, 0)
    return out


@pytest.fixture()
def damaged(results, tmp_path) -> Path:
    """A copy of ``results`` where the clean clip's record.json is cut mid-string and the elastic
    clip's matches.npz is truncated (the tables still list both as scored)."""
    out = tmp_path / "r"
    shutil.copytree(results, out)
    rec = out / "clips" / CLEAN / "record.json"
    rec.write_text(rec.read_text()[:200])
    npz = out / "clips" / ELASTIC / "matches.npz"
    npz.write_bytes(npz.read_bytes()[:300])
    return out


def _run(*args: str, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run([*GEOCON, *args], capture_output=True, text=True, timeout=timeout)


def _one_sentence(proc: subprocess.CompletedProcess, *names: str) -> str:
    """The exit code is 2 and stderr is a single `error: ...` line naming every one of ``names``."""
    assert proc.returncode == 2, (proc.returncode, proc.stderr)
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), proc.stderr
    assert "Traceback" not in proc.stderr
    for name in names:
        assert name in lines[0], (name, lines[0])
    return lines[0]


# --- serve: --host and --port -------------------------------------------------------------------


@pytest.mark.parametrize(
    "host, port, words",
    [
        ("127.0.0.1", -1, ("--port", "-1", "0 and 65535")),
        ("127.0.0.1", 70000, ("--port", "70000", "0 and 65535")),
        ("10.255.255.1", 0, ("--host", "10.255.255.1", "not an address of this machine")),
        ("localhostt", 0, ("--host", "localhostt", "resolves")),
        ("999.1.1.1", 0, ("--host", "999.1.1.1", "resolves")),
        ("", 0, ("--host", "empty")),
    ],
)
def test_check_bind_refuses_each_bad_option(host, port, words):
    with pytest.raises(BindError) as info:
        check_bind(host, port)
    message = str(info.value)
    assert all(w in message for w in words), message


@pytest.mark.parametrize("host", ["127.0.0.1", "localhost", "0.0.0.0"])
def test_check_bind_accepts_this_machine(host):
    assert check_bind(host, 0) == 0


@pytest.mark.parametrize(
    "args, option",
    [(("--port", "-1"), "--port"), (("--port", "70000"), "--port"), (("--host", "10.255.255.1"), "--host")],
)
def test_cli_serve_refuses_bad_port_or_host_at_once(results, args, option):
    """Used to hang forever (a server thread died unseen); now one sentence, exit 2, in seconds."""
    proc = _run("serve", str(results), *args, timeout=30)
    _one_sentence(proc, option, args[1])


@pytest.mark.full
def test_cli_serve_says_which_port_it_moved_to_and_why(results):
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        assert check_bind("127.0.0.1", port) > port
        proc = subprocess.Popen(
            [*GEOCON, "serve", str(results), "--port", str(port)],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        try:
            seen = []
            while not seen or "GeoCon audit app:" not in seen[-1]:
                line = proc.stdout.readline()
                assert line, "".join(seen)
                seen.append(line)
            note = next(line for line in seen if "in use" in line)
            moved = int(seen[-1].split("GeoCon audit app:", 1)[1].split()[0].rsplit(":", 1)[1])
            assert moved != port
            assert note.strip() == f"port {port} on 127.0.0.1 is in use: serving on port {moved} instead"
            proc.send_signal(signal.SIGTERM)
            proc.communicate(timeout=30)
            assert proc.returncode == 0
        finally:
            proc.kill()
            proc.wait()


# --- serve: broken clips ------------------------------------------------------------------------


def test_corrupt_record_and_truncated_matches_are_listed_broken(damaged):
    pytest.importorskip("viser")
    from geocon_viewer.audit.app import AuditApp

    app = AuditApp(damaged, port=0, preload=True)
    try:
        assert app._preload is not None
        app._preload.join(30)
        assert not app._preload.is_alive(), "the preload finished (it used to die on the truncated matches.npz)"
        by_id = app.index.by_id
        assert (by_id[CLEAN].status, by_id[ELASTIC].status, by_id[BREATHING].status) == ("broken", "broken", "ok")
        assert str(damaged / "clips" / CLEAN / "record.json") in by_id[CLEAN].error
        assert str(damaged / "clips" / ELASTIC / "matches.npz") in by_id[ELASTIC].error
        assert app.table_md.content.count("BROKEN") == 2
        for clip_id, file in ((CLEAN, "record.json"), (ELASTIC, "matches.npz")):
            app.clip.value = clip_id  # used to raise JSONDecodeError / BadZipFile
            assert app.view is None and "could not be read" in app.card_md.content
            assert str(damaged / "clips" / clip_id / file) in app.card_md.content
        app.number["tau_h"].value = 3.0  # re-gating skips the broken clips
        assert [r.state for r in app.rows] == ["error", "error", "passes"]
        app.clip.value = BREATHING
        assert app.view is not None and app.verdict is not None
    finally:
        app.stop()


def test_broken_records_found_on_selection_without_preload(damaged):
    pytest.importorskip("viser")
    from geocon_viewer.audit.app import AuditApp

    app = AuditApp(damaged, port=0, preload=False)
    try:
        assert app.index.by_id[ELASTIC].status == "ok"  # the tables list it; its matches were not read yet
        app.clip.value = ELASTIC
        assert app.index.by_id[ELASTIC].status == "broken" and "matches.npz" in app.card_md.content
        row = next(r for r in app.rows if r.clip_id == ELASTIC)
        assert row.state == "error" and row.verdict is None
    finally:
        app.stop()


def test_preload_and_listing_go_on_past_broken_records(damaged):
    from geocon_core.results import ResultsIndex

    index = ResultsIndex.open(damaged)
    seen = []
    index.preload(progress=lambda done, total: seen.append((done, total)))
    assert seen[-1] == (3, 3) and index.loaded() == 1
    assert {c.clip_id for c in index.clips if c.status == "broken"} == {CLEAN, ELASTIC}
    # with the tables out of date the records are read when listing: the broken one is listed as such
    (damaged / "tables" / "clips.parquet").unlink()
    index = ResultsIndex.open(damaged)
    clean = index.by_id[CLEAN]
    assert clean.status == "broken" and str(damaged / "clips" / CLEAN / "record.json") in clean.error
    assert [c.clip_id for c in index.clips] == sorted([CLEAN, BREATHING, ELASTIC])


# --- view ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("clip_id, file", [(CLEAN, "record.json"), (ELASTIC, "matches.npz")])
def test_view_of_a_corrupt_record_names_the_file(damaged, clip_id, file):
    pytest.importorskip("rerun")
    folder = damaged / "clips" / clip_id
    line = _one_sentence(_run("view", str(folder), "--headless"), str(folder / file))
    assert not (folder / "audit.rrd").exists()
    assert "score the clip again" in line


@pytest.mark.parametrize("at", ["-5", "100000", "8"])
def test_view_at_outside_the_clip_is_refused_before_rendering(results, tmp_path, at):
    if at != "-5":
        pytest.importorskip("rerun")
    rrd = tmp_path / "a.rrd"
    proc = _run("view", str(results / "clips" / CLEAN), "--headless", "--save", str(rrd), "--at", at)
    line = _one_sentence(proc, "--at", at)
    if at != "-5":
        assert "8 frames (0 to 7)" in line
    assert not rrd.exists()


# --- reading saved records: untrusted files -----------------------------------------------------


def test_an_absurdly_large_record_json_is_refused_unparsed(results, tmp_path):
    folder = tmp_path / "huge"
    shutil.copytree(results / "clips" / CLEAN, folder)
    with (folder / "record.json").open("r+b") as f:
        f.truncate(MAX_RECORD_JSON_BYTES + 1)  # sparse: nothing is written, nothing is read
    with pytest.raises(RecordError, match="larger than 512 MiB") as info:
        read_record_json(folder)
    assert str(folder / "record.json") in str(info.value)
    pytest.importorskip("rerun")
    _one_sentence(_run("view", str(folder), "--headless"), str(folder / "record.json"), "refusing to parse")


class _Boom:
    """Unpickling this would create ``marker`` (what a hostile pickle does, harmlessly)."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (Path.touch, (self.marker,))


def test_pickled_matches_are_refused_without_unpickling(results, tmp_path):
    folder = tmp_path / "pickled"
    shutil.copytree(results / "clips" / CLEAN, folder)
    npz = folder / "matches.npz"
    marker = tmp_path / "unpickled"
    npz.write_bytes(pickle.dumps({"x1": _Boom(marker)}, protocol=4))  # a whole-file pickle
    for read in (read_record, load_residuals):
        with pytest.raises(RecordError, match="pickle") as info:
            read(folder)
        assert str(npz) in str(info.value)
    # an object array inside an otherwise valid archive
    arrays = dict(np.load(results / "clips" / CLEAN / "matches.npz"))
    arrays["h_res"] = np.array([_Boom(marker)], dtype=object)
    np.savez(npz, **arrays)
    for read in (read_record, load_residuals):
        with pytest.raises(RecordError, match="'h_res' holds pickled Python objects, which GeoCon never loads") as info:
            read(folder)
        assert str(npz) in str(info.value)
    assert not marker.exists(), "nothing was unpickled"


def test_zip_errors_in_matches_name_the_file(results, tmp_path):
    folder = tmp_path / "zip"
    shutil.copytree(results / "clips" / CLEAN, folder)
    npz = folder / "matches.npz"
    good = npz.read_bytes()
    crc = bytearray(good)
    with zipfile.ZipFile(npz) as zf:
        info = zf.getinfo("h_res.npy")
    crc[info.header_offset + 30 + len(info.filename) + 5] ^= 0xFF  # inside h_res's compressed bytes
    np.save(tmp_path / "one.npy", np.zeros(3))
    cases = {
        "truncated": good[: len(good) // 2],
        "empty": b"",
        "garbage": b"this is not an archive",
        "crc": bytes(crc),
        "npy": (tmp_path / "one.npy").read_bytes(),
    }
    for name, data in cases.items():
        npz.write_bytes(data)
        for read in (read_record, load_residuals):
            with pytest.raises(RecordError) as info:
                read(folder)
            assert str(info.value).startswith(f"{npz} "), (name, str(info.value))
    npz.unlink()
    with pytest.raises(RecordError, match="does not exist"):
        read_record(folder)


def test_a_record_json_lacking_fields_names_the_file(results, tmp_path):
    folder = tmp_path / "fields"
    shutil.copytree(results / "clips" / CLEAN, folder)
    (folder / "record.json").write_text('{"format": "geocon-record/1"}')
    with pytest.raises(RecordError, match="not a readable GeoCon record") as info:
        read_record(folder)
    assert str(folder / "record.json") in str(info.value)
    (folder / "record.json").write_bytes(b"\xff\xfe not utf-8")
    with pytest.raises(RecordError, match="not UTF-8") as info:
        read_record(folder)
    (folder / "record.json").write_text("[1, 2]")
    with pytest.raises(RecordError, match="not a GeoCon record"):
        read_record(folder)
