"""The bad-reader catalogue: every file GeoCon reads where a file is expected, given as a FIFO, a
device, a socket or a file far past any real one; rows and fields of a manifest megabytes long;
and servers outside that accept a connection and never answer.

The rule (:mod:`geocon_core.files.bounded`): a regular file only, its size bounded before it is
read (the bound of its kind named in the refusal), and a time bound wherever something outside
answers (:mod:`geocon_core.files.answers`: a Rerun viewer, a Ray head; ``git`` in ``footage fill``).

The cases use the framework of :mod:`tests.test_bad_input` (:class:`Case`, :func:`run_case`, the
``ctx`` fixture): a refusal is exit 2 with one ``error:`` sentence naming the file and nothing
changed or left behind. Every case that could block a reader runs as a subprocess that is killed
after :data:`~tests.test_bad_input.SUBPROCESS_TIMEOUT_S`, so a case that hangs fails instead of
hanging the suite. Device nodes are private ``mknod`` nodes in the case's folder (these cases need
root and are skipped without it): no test opens the machine's own devices. Huge files are sparse:
nothing is written, and a reader that honours its bound reads nothing of them."""

from __future__ import annotations

import json
import os
import shutil
import socket
import stat
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from geocon_core.files import FileKind, ReadRefused, bounded, open_regular, read_bytes, read_text, regular_file

from .bad_inputs import snapshot
from .test_bad_input import (  # noqa: F401  (assets and ctx are fixtures)
    FAST,
    SUBPROCESS_TIMEOUT_S,
    Case,
    Ctx,
    Outcome,
    assets,
    build_all,
    ctx,
    nothing,
    run_case,
    score,
)

ZERO = os.makedev(1, 5)
"""The numbers of the zero device on Linux (``/dev/zero``: every read returns zeros, for ever)."""
MiB = 1 << 20
GiB = 1 << 30
NO_RRD = (*FAST, "--no-rrd")


# --- builders -------------------------------------------------------------------------------------


def fifo(name: str) -> Callable[[Ctx], None]:
    """``name`` made a FIFO (an existing file there is replaced)."""

    def build(c: Ctx) -> None:
        p = c.tmp / name
        p.parent.mkdir(parents=True, exist_ok=True)
        if p.exists() or p.is_symlink():
            p.unlink()
        os.mkfifo(p)

    return build


def zero_device(name: str) -> Callable[[Ctx], None]:
    """``name`` made a private node of the zero device (skipped without the right to make one)."""

    def build(c: Ctx) -> None:
        p = c.tmp / name
        p.parent.mkdir(parents=True, exist_ok=True)
        if p.exists():
            p.unlink()
        try:
            os.mknod(p, stat.S_IFCHR | 0o644, ZERO)
        except PermissionError:
            pytest.skip("making a device node needs root (CAP_MKNOD)")

    return build


def unix_socket(name: str) -> Callable[[Ctx], None]:
    def build(c: Ctx) -> None:
        p = c.tmp / name
        p.parent.mkdir(parents=True, exist_ok=True)
        if p.exists():
            p.unlink()
        sock = socket.socket(socket.AF_UNIX)
        sock.bind(str(p))
        sock.close()  # the socket file stays

    return build


def sparse(name: str, size: int, head: bytes = b"") -> Callable[[Ctx], None]:
    """``name`` made a sparse file of ``size`` bytes starting with ``head`` (nothing else written)."""

    def build(c: Ctx) -> None:
        p = c.tmp / name
        p.parent.mkdir(parents=True, exist_ok=True)
        with open(p, "wb") as f:
            f.write(head)
            f.truncate(size)

    return build


def pan(name: str = "clip.mp4") -> Callable[[Ctx], None]:
    return lambda c: c.pan(name)


def record(c: Ctx) -> None:
    """``rec``: the C4 clip's record (with overlays), its clip ``c4.mp4`` beside it."""
    c.record("rec")


def overlay_png(c: Ctx) -> str:
    """The first PNG the record's overlays index names."""
    index = json.loads((c.tmp / "rec" / "overlays" / "index.json").read_text())
    return next(e["labels"] for e in index["frames"].values() if e.get("labels"))


def overlay_fifo(c: Ctx) -> None:
    record(c)
    fifo(f"rec/overlays/{overlay_png(c)}")(c)


def overlay_huge(c: Ctx) -> None:
    record(c)
    sparse(f"rec/overlays/{overlay_png(c)}", 300 * MiB)(c)


def modelled(c: Ctx) -> None:
    """``rec``: a record scored with the default preset (its verdict is the clip model's), copied
    from a session asset."""

    def make(p: Path) -> None:
        from typer.testing import CliRunner

        from geocon_viewer.cli import app

        res = CliRunner().invoke(app, ["score", str(c.assets.pan), "--out", str(p)])
        assert res.exit_code == 0, res.output

    c.copy(c.assets._once("default-record", make), "rec")


def model_at(path: str) -> Callable[[Ctx], None]:
    """``rec`` (:func:`modelled`) whose configuration names ``path`` as its clip model."""

    def build(c: Ctx) -> None:
        modelled(c)
        file = c.tmp / "rec" / "record.json"
        d = json.loads(file.read_text())
        d["config"]["signals"]["model"] = str(c.tmp / path)
        file.write_text(json.dumps(d))

    return build


SIDECAR = {
    "clip_id": "p-a", "prompt": None, "model": "p", "model_version": None, "seed": None, "resolution": [160, 90],
    "fps": 24, "duration": None, "masks_path": None, "category": None, "scene_id": "p-a",
}  # fmt: skip


def sidecar(**fields: object) -> Callable[[Ctx], None]:
    """``ds/p/a.mp4`` and its sidecar ``ds/p/a.meta.json`` with ``fields`` changed."""

    def build(c: Ctx) -> None:
        c.pan("ds/p/a.mp4")
        c.write("ds/p/a.meta.json", json.dumps({**SIDECAR, **fields}))

    return build


def manifest(name: str, text: str) -> Callable[[Ctx], None]:
    """``ds/p/a.mp4`` and the manifest ``ds/NAME`` holding ``text``."""

    def build(c: Ctx) -> None:
        c.pan("ds/p/a.mp4")
        c.write(f"ds/{name}", text)

    return build


def prompt_row(n: int, jsonl: bool = False) -> Callable[[Ctx], None]:
    """A manifest of one row whose prompt holds ``n`` characters of words."""
    prompt = ("a dog runs " * (n // 11 + 1))[:n]
    if jsonl:
        return manifest("manifest.jsonl", json.dumps({"path": "p/a.mp4", "prompt": prompt}) + "\n")
    return manifest("manifest.csv", f'path,prompt\np/a.mp4,"{prompt}"\n')


def plain(c: Ctx) -> None:
    c.pan("ds/p/a.mp4")


def benched(c: Ctx) -> None:
    """``ds/p/a.mp4`` scored by ``geocon bench`` into ``out``."""
    plain(c)
    res = c.invoke(["bench", "ds", "--out", "out", *NO_RRD])
    assert res.code == 0, res.describe()


def benched_then(*steps: Callable[[Ctx], None]) -> Callable[[Ctx], None]:
    return build_all(benched, *steps)


def masks_then(*steps: Callable[[Ctx], None]) -> Callable[[Ctx], None]:
    return build_all(lambda c: c.c4(), *steps)


def colmap(c: Ctx) -> None:
    c.write("model/cameras.txt", "1 PINHOLE 160 90 100 100 80 45\n")
    c.write("model/points3D.txt", "# none\n")
    fifo("model/images.txt")(c)


def frames_with_a_huge_one(c: Ctx) -> None:
    from .bad_inputs import pan_frames, write_pngs

    write_pngs(c.tmp / "frames", pan_frames(160, 90, 6, seed=1))
    sparse("frames/00003.png", 3 * GiB, b"\x89PNG\r\n\x1a\n")(c)


def scored_then_a_fifo(c: Ctx) -> None:
    """``clip.mp4`` scored into ``rec``, then the clip replaced by a FIFO."""
    c.pan()
    res = c.invoke(list(score("clip.mp4", out="rec")))
    assert res.code == 0, res.describe()
    fifo("clip.mp4")(c)


def warned_of_the_fifo(_c: Ctx, res: Outcome) -> None:
    assert "warning: clip.mp4: is a FIFO (named pipe), not a clip file, where this record's clip was" in res.stderr, (
        res.stderr
    )
    assert "the recording shows the scores without frames" in res.stderr


def annotated_fifo(c: Ctx) -> None:
    """``vd/x.mp4`` a FIFO, annotated in ``a.csv``."""
    fifo("vd/x.mp4")(c)
    header = "clip,regime,gate,movers,static_camera,source,stable_scene,category,artifacts,note"
    c.write("a.csv", f"{header}\nx.mp4,pan,H,0,no,real,yes,C2,,\n")


def scored_again(c: Ctx, res: Outcome) -> None:
    status = json.loads((c.tmp / "out" / "clips" / "p-a" / "status.json").read_text())
    assert status["status"] == "ok", status


def quick(limit_s: float) -> Callable[[Ctx, Outcome], None]:
    def check(_c: Ctx, res: Outcome) -> None:
        assert res.seconds < limit_s, f"took {res.seconds:.1f} s (at most {limit_s:g} s)"

    return check


def flat(text: str) -> str:
    """``text`` without white space and box-drawing characters (a table's folded cell, read whole)."""
    return "".join(ch for ch in text if not ch.isspace() and not 0x2500 <= ord(ch) <= 0x257F)


def shown_cut(_c: Ctx, res: Outcome) -> None:
    assert "...(65000characters)" in flat(res.stdout), res.stdout
    assert res.seconds < 20, f"took {res.seconds:.1f} s"


def victim_kept(c: Ctx, _res: Outcome) -> None:
    assert (c.tmp / "victim.txt").read_text() == "keep me\n"


# --- the catalogue --------------------------------------------------------------------------------

DATASETS = [
    Case("dataset-sidecar-is-a-fifo", build_all(sidecar(), fifo("ds/p/a.meta.json")), ("dataset", "ds"), 2,
         ("a.meta.json", "FIFO", "sidecar"), runner="subprocess"),
    Case("dataset-sidecar-is-a-device", build_all(sidecar(), zero_device("ds/p/a.meta.json")), ("dataset", "ds"), 2,
         ("a.meta.json", "character device"), runner="subprocess"),
    Case("dataset-sidecar-is-a-socket", build_all(sidecar(), unix_socket("ds/p/a.meta.json")), ("dataset", "ds"), 2,
         ("a.meta.json", "socket")),
    Case("dataset-sidecar-past-its-bound", build_all(sidecar(), sparse("ds/p/a.meta.json", 2 * MiB, b"{")),
         ("dataset", "ds"), 2, ("a.meta.json", "2 MiB", "1 MiB", "sidecar")),
    Case("dataset-sidecar-prompt-of-100000-characters", sidecar(prompt="word " * 20_000), ("dataset", "ds"), 2,
         ("a.meta.json", "prompt holds 100000 characters", "65536")),
    Case("dataset-sidecar-clip-is-a-fifo", build_all(sidecar(), fifo("ds/p/a.mp4")), ("dataset", "ds"), 2,
         ("a.mp4", "FIFO"), runner="subprocess"),
    Case("dataset-manifest-path-is-a-fifo", fifo("m.csv"), ("dataset", "m.csv"), 2, ("m.csv", "FIFO", "manifest"),
         runner="subprocess"),
    Case("dataset-manifest-in-the-folder-is-a-fifo", build_all(plain, fifo("ds/manifest.csv")), ("dataset", "ds"), 2,
         ("manifest.csv", "FIFO"), runner="subprocess"),
    Case("dataset-manifest-is-a-device", build_all(plain, zero_device("ds/manifest.jsonl")), ("dataset", "ds"), 2,
         ("manifest.jsonl", "character device"), runner="subprocess"),
    Case("dataset-manifest-past-its-bound", build_all(plain, sparse("ds/manifest.csv", 300 * MiB, b"path\n")),
         ("dataset", "ds"), 2, ("manifest.csv", "300 MiB", "256 MiB")),
    Case("dataset-path-is-a-fifo-named-as-a-clip", fifo("one.mp4"), ("dataset", "one.mp4"), 2, ("one.mp4", "FIFO"),
         runner="subprocess"),
    Case("dataset-only-clip-is-a-fifo", fifo("ds/p/a.mp4"), ("dataset", "ds"), 2,
         ("no clips found", "a.mp4 (not a regular file)"), runner="subprocess"),
    Case("dataset-jsonl-row-with-a-4-mb-prompt", prompt_row(4 * MiB, jsonl=True), ("dataset", "ds"), 2,
         ("manifest.jsonl line 1", "1048576", "65536"), check=quick(10), runner="subprocess"),
    Case("dataset-csv-row-with-a-1-mb-prompt", prompt_row(1 * MiB + 10), ("dataset", "ds"), 2,
         ("manifest.csv line 2", "1048576"), check=quick(10), runner="subprocess"),
    Case("dataset-csv-cell-of-200000-characters-over-lines",
         manifest("manifest.csv", 'path,prompt\np/a.mp4,"' + "a dog runs\n" * 20_000 + '"\n'), ("dataset", "ds"), 2,
         ("manifest.csv line 2", "a cell holds more than the 65536 characters")),
    Case("dataset-csv-prompt-of-100000-characters", prompt_row(100_000), ("dataset", "ds"), 2,
         ("manifest.csv line 2", "prompt holds 100000 characters", "65536")),
    Case("dataset-jsonl-prompt-of-100000-characters", prompt_row(100_000, jsonl=True), ("dataset", "ds"), 2,
         ("manifest.jsonl line 1", "prompt holds 100000 characters", "65536")),
    Case("dataset-csv-column-name-of-70000-characters", manifest("manifest.csv", f"path,{'x' * 70_000}\np/a.mp4,1\n"),
         ("dataset", "ds"), 2, ("manifest.csv line 1", "a field name of 70000 characters")),
    Case("dataset-prompt-of-65000-characters-is-shown-cut", prompt_row(65_000, jsonl=True), ("dataset", "ds"), 0,
         check=shown_cut, runner="subprocess"),
    Case("bench-sidecar-is-a-fifo", build_all(sidecar(), fifo("ds/p/a.meta.json")), ("bench", "ds", "--out", "out",
         *NO_RRD), 2, ("a.meta.json", "FIFO"), runner="subprocess"),
]  # fmt: skip

RESULTS = [
    Case("bench-resume-bench-json-is-a-fifo", benched_then(fifo("out/bench.json")),
         ("bench", "ds", "--out", "out", *NO_RRD), 2, ("out/bench.json", "FIFO"), runner="subprocess"),
    Case("bench-resume-bench-json-past-its-bound", benched_then(sparse("out/bench.json", 300 * MiB, b"{")),
         ("bench", "ds", "--out", "out", *NO_RRD), 2, ("out/bench.json", "300 MiB", "256 MiB")),
    Case("bench-resume-status-json-past-its-bound", benched_then(sparse("out/clips/p-a/status.json", 17 * MiB, b"{")),
         ("bench", "ds", "--out", "out", *NO_RRD), 0, check=scored_again),
    Case("bench-lock-file-is-a-fifo", benched_then(fifo("out/bench.lock")), ("bench", "ds", "--out", "out", *NO_RRD),
         2, ("out/bench.lock", "not a regular file"), runner="subprocess"),
    Case("bench-lock-file-is-a-link-to-a-file", benched_then(lambda c: c.write("victim.txt", "keep me\n"),
         lambda c: os.symlink("../victim.txt", c.tmp / "out" / "bench.lock")),
         ("bench", "ds", "--out", "out", *NO_RRD), 2, ("out/bench.lock", "link"), check=victim_kept),
    Case("report-bench-json-is-a-fifo", benched_then(fifo("out/bench.json")), ("report", "out", "--bootstrap", "100"),
         2, ("out/bench.json", "FIFO"), runner="subprocess"),
    Case("report-bench-json-past-its-bound", benched_then(sparse("out/bench.json", 300 * MiB, b"{")),
         ("report", "out", "--bootstrap", "100"), 2, ("out/bench.json", "256 MiB")),
    Case("report-table-is-a-fifo", benched_then(fifo("out/tables/clips.parquet")),
         ("report", "out", "--bootstrap", "100"), 2, ("clips.parquet", "FIFO", "geocon bench"), runner="subprocess"),
    Case("report-lock-file-is-a-fifo", benched_then(fifo("out/bench.lock")),
         ("report", "out", "--bootstrap", "100", "--out", "rep"), 0, runner="subprocess"),
    Case("serve-bench-json-is-a-fifo", benched_then(fifo("out/bench.json")), ("serve", "out", "--port", "0"), 2,
         ("out/bench.json", "FIFO"), runner="subprocess", needs=("viser",)),
    Case("serve-record-json-is-a-fifo", build_all(record, fifo("rec/record.json")), ("serve", "rec", "--port", "0"),
         2, ("rec/record.json", "FIFO"), runner="subprocess", needs=("viser",)),
]  # fmt: skip

RECORDS = [
    Case("view-record-json-is-a-fifo", build_all(record, fifo("rec/record.json")),
         ("view", "rec", "--headless", "--save", "v.rrd"), 2, ("rec/record.json", "FIFO"), runner="subprocess",
         needs=("rerun",)),
    Case("view-record-json-is-a-device", build_all(record, zero_device("rec/record.json")),
         ("view", "rec", "--headless", "--save", "v.rrd"), 2, ("rec/record.json", "character device"),
         runner="subprocess", needs=("rerun",)),
    Case("view-matches-npz-is-a-fifo", build_all(record, fifo("rec/matches.npz")),
         ("view", "rec", "--headless", "--save", "v.rrd"), 2, ("rec/matches.npz", "FIFO", "score the clip again"),
         runner="subprocess", needs=("rerun",)),
    Case("view-matches-npz-past-its-bound", build_all(record, sparse("rec/matches.npz", 9 * GiB, b"PK\x03\x04")),
         ("view", "rec", "--headless", "--save", "v.rrd"), 2, ("rec/matches.npz", "9 GiB", "8 GiB"),
         runner="subprocess", needs=("rerun",)),
    Case("view-overlays-index-is-a-fifo", build_all(record, fifo("rec/overlays/index.json")),
         ("view", "rec", "--headless", "--save", "v.rrd"), 2, ("index.json", "FIFO"), runner="subprocess",
         needs=("rerun",)),
    Case("view-overlays-index-past-its-bound", build_all(record, sparse("rec/overlays/index.json", 65 * MiB)),
         ("view", "rec", "--headless", "--save", "v.rrd"), 2, ("index.json", "64 MB")),
    Case("view-overlay-png-is-a-fifo", overlay_fifo, ("view", "rec", "--headless", "--save", "v.rrd"), 2,
         ("rec/overlays/", "FIFO", "score the clip again"), runner="subprocess", needs=("rerun",)),
    Case("view-overlay-png-past-its-bound", overlay_huge, ("view", "rec", "--headless", "--save", "v.rrd"), 2,
         ("rec/overlays/", "300 MiB", "256 MiB"), runner="subprocess", needs=("rerun",)),
    Case("view-record-clip-is-a-fifo", scored_then_a_fifo, ("view", "rec", "--headless", "--save", "v.rrd"), 0,
         check=warned_of_the_fifo, runner="subprocess", needs=("rerun",)),
    Case("view-clip-model-is-a-device", build_all(model_at("zero"), zero_device("zero")),
         ("view", "rec", "--headless", "--save", "v.rrd"), 2, ("clip model", "zero", "character device"),
         runner="subprocess", needs=("rerun",)),
    Case("view-clip-model-is-a-fifo", build_all(model_at("m.json"), fifo("m.json")),
         ("view", "rec", "--headless", "--save", "v.rrd"), 2, ("clip model", "m.json", "FIFO"), runner="subprocess",
         needs=("rerun",)),
    Case("view-clip-model-past-its-bound", build_all(model_at("m.json"), sparse("m.json", 20 * MiB, b"{")),
         ("view", "rec", "--headless", "--save", "v.rrd"), 2, ("clip model", "20 MiB", "16 MiB"), runner="subprocess",
         needs=("rerun",)),
]  # fmt: skip

INPUTS = [
    Case("score-clip-is-a-device", zero_device("clip.mp4"), score("clip.mp4"), 2, ("clip.mp4", "device"),
         runner="subprocess"),
    Case("score-clip-is-a-socket", unix_socket("clip.mp4"), score("clip.mp4"), 2, ("clip.mp4", "socket")),
    Case("score-clip-is-a-sparse-64-gib-file", sparse("clip.mp4", 64 * GiB), score("clip.mp4"), 2, ("clip.mp4",),
         check=quick(10), runner="subprocess"),
    Case("score-frame-past-its-bound", frames_with_a_huge_one, score("frames"), 2, ("00003.png", "3 GiB", "2 GiB"),
         runner="subprocess"),
    Case("score-pose-log-is-a-fifo", build_all(pan(), fifo("p.json")), score("clip.mp4", "--pose-log", "p.json"), 2,
         ("p.json",), runner="subprocess"),
    Case("score-pose-log-is-a-device", build_all(pan(), zero_device("p.json")),
         score("clip.mp4", "--pose-log", "p.json"), 2, ("p.json",), runner="subprocess"),
    Case("score-masks-npz-is-a-fifo", masks_then(fifo("m.npz")), score("c4.mp4", "--masks", "m.npz"), 2,
         ("m.npz", "FIFO"), runner="subprocess"),
    Case("score-masks-npz-past-its-bound", masks_then(sparse("m.npz", 17 * GiB, b"PK\x03\x04")),
         score("c4.mp4", "--masks", "m.npz"), 2, ("m.npz", "17 GiB", "16 GiB")),
    Case("score-masks-png-is-a-fifo", masks_then(fifo("c4.masks/00003.png")), score("c4.mp4", "--masks", "c4.masks"),
         2, ("00003.png", "FIFO"), runner="subprocess"),
    Case("pose-log-dust3r-scene-is-a-fifo", fifo("s.npz"), ("pose-log", "s.npz", "--out", "p.json"), 2,
         ("s.npz", "FIFO"), runner="subprocess"),
    Case("pose-log-colmap-images-is-a-fifo", colmap, ("pose-log", "model", "--out", "p.json"), 2,
         ("images.txt", "FIFO"), runner="subprocess"),
    Case("plant-source-is-a-fifo", fifo("src.mp4"), ("plant", "src.mp4", "--failure", "morph", "--severity", "low",
         "--out", "pl"), 2, ("src.mp4", "FIFO"), runner="subprocess"),
    Case("validate-real-clip-is-a-fifo", annotated_fifo, ("validate", "--out", "v", "--data", "vd", "--annotations",
         "a.csv", "--no-synthetic", "--no-peer"), 2, ("vd/x.mp4", "FIFO"), runner="subprocess"),
    Case("footage-status-annotations-is-a-fifo", fifo("a.csv"), ("footage", "status", "--annotations", "a.csv"), 2,
         ("annotation file a.csv", "FIFO"), runner="subprocess"),
    Case("footage-status-annotations-is-a-device", zero_device("a.csv"),
         ("footage", "status", "--annotations", "a.csv"), 2, ("annotation file a.csv", "character device"),
         runner="subprocess"),
    Case("footage-status-annotations-past-its-bound", sparse("a.csv", 65 * MiB, b"clip,"),
         ("footage", "status", "--annotations", "a.csv"), 2, ("annotation file a.csv", "65 MiB", "64 MiB")),
    Case("footage-status-with-the-projects-own-annotations", nothing, ("footage", "status", "--footage", "cache"), 0),
]  # fmt: skip

CASES = DATASETS + RESULTS + RECORDS + INPUTS


def test_the_catalogue_is_complete():
    names = [c.name for c in CASES]
    assert len(names) == len(set(names)), "case names are unique"
    assert len(CASES) >= 40


@pytest.mark.full
@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_bad_reader(case: Case, ctx: Ctx):  # noqa: F811
    run_case(case, ctx)


# --- the rule's one home: geocon_core.files.bounded -----------------------------------------------

SMALL = FileKind("a small file", 16, "check it")


def _within(seconds: float, call: Callable[[], object]) -> object:
    """``call()`` in a thread, which must end within ``seconds`` (a reader that blocks fails)."""
    out: list[object] = []

    def run() -> None:
        try:
            out.append(call())
        except BaseException as exc:  # noqa: BLE001  (handed to the test)
            out.append(exc)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    thread.join(seconds)
    assert not thread.is_alive(), f"still reading after {seconds:g} s"
    return out[0]


def test_a_fifo_is_refused_without_being_opened(tmp_path: Path):
    os.mkfifo(tmp_path / "a.json")
    exc = _within(5, lambda: read_bytes(tmp_path / "a.json", SMALL))
    assert isinstance(exc, ReadRefused) and exc.reason == "special"
    assert str(exc).startswith(f"{tmp_path / 'a.json'} is a FIFO (named pipe), not a regular file")
    assert "a small file" in str(exc) and "save it to a file" in str(exc)


def test_a_file_swapped_for_a_fifo_after_its_check_does_not_block(tmp_path: Path, monkeypatch):
    os.mkfifo(tmp_path / "a.json")
    monkeypatch.setattr(bounded, "regular_file", lambda *_a, **_k: None)  # the check saw a regular file
    exc = _within(5, lambda: open_regular(tmp_path / "a.json", SMALL))
    assert isinstance(exc, ReadRefused) and exc.reason == "special", exc


def test_a_file_larger_than_its_bound_is_refused_by_its_size_unread(tmp_path: Path, monkeypatch):
    sparse("big.json", 17)(Ctx(tmp_path, None))  # type: ignore[arg-type]
    monkeypatch.setattr(os, "open", lambda *_a, **_k: pytest.fail("a file past its bound was opened"))
    with pytest.raises(ReadRefused, match=r"big.json is 17 bytes, more than the 16 bytes GeoCon reads of a small "
                       r"file; check it$") as info:  # fmt: skip
        read_bytes(tmp_path / "big.json", SMALL)
    assert info.value.reason == "size"


def test_a_file_that_holds_more_than_its_size_says_is_cut_at_its_bound():
    # /proc files say they are empty and are not: a reader trusting the size alone would read on
    assert os.stat("/proc/self/maps").st_size == 0
    with pytest.raises(ReadRefused, match="more than the 16 bytes") as info:
        read_bytes("/proc/self/maps", SMALL)
    assert info.value.reason == "size"


def test_the_bounded_reader_reads_a_regular_file_and_its_text(tmp_path: Path):
    (tmp_path / "a.json").write_bytes(b"\xef\xbb\xbf{}")
    assert read_bytes(tmp_path / "a.json", SMALL) == b"\xef\xbb\xbf{}"
    assert read_text(tmp_path / "a.json", SMALL) == "{}"  # the byte-order mark dropped
    (tmp_path / "u16.csv").write_bytes("ab".encode("utf-16"))
    with pytest.raises(ReadRefused, match="is UTF-16 text, not UTF-8; save it as UTF-8"):
        read_text(tmp_path / "u16.csv", SMALL, "u16.csv")
    with pytest.raises(ReadRefused, match="^gone.json does not exist$"):
        regular_file(tmp_path / "nope", SMALL, "gone.json")
    os.symlink("nowhere", tmp_path / "dangling")
    with pytest.raises(ReadRefused, match=r"is a link to nothing \(nowhere\)"):
        regular_file(tmp_path / "dangling", SMALL)
    with pytest.raises(ReadRefused, match="is a folder, not a small file"):
        regular_file(tmp_path, SMALL)


def test_every_kind_of_file_has_a_bound_in_one_place_and_gives_what_to_do():
    kinds = {name: k for name, k in vars(bounded).items() if isinstance(k, FileKind)}
    assert set(kinds) <= set(bounded.__all__) and len(kinds) >= 20
    for name, kind in kinds.items():
        assert kind.limit >= 64 * 1024 and kind.what.startswith(("a ", "an ", "the ")), name
        assert kind.advice and not kind.advice.endswith("."), name


def test_the_bounds_hold_the_projects_own_inputs():
    from geocon_core.validation.cases import ANNOTATIONS_PATH, read_annotations

    assert len(read_annotations()) > 100  # the annotation file the package ships is read whole
    assert ANNOTATIONS_PATH.stat().st_size * 100 < bounded.ANNOTATIONS.limit
    assert bounded.RECORD_JSON.limit >= 400 * 1.2 * MiB  # a 480-frame clip's record.json: 1.1 MB (default preset)
    assert bounded.MATCHES.limit >= 300 * 27 * MiB  # ... and its matches.npz: 27 MB


def test_a_manifest_of_thousands_of_rows_is_read_at_once(tmp_path: Path):
    from geocon_core.bench.dataset import _manifest_rows

    prompt = "a cat walks on a roof at night, seen from the street below, " * 16  # about 1 KB
    rows = "".join(f'p/c{i}.mp4,"{prompt}"\n' for i in range(5000))
    (tmp_path / "m.csv").write_text("path,prompt\n" + rows)
    (tmp_path / "m.jsonl").write_text("".join(json.dumps({"path": f"p/c{i}.mp4", "prompt": prompt}) + "\n"
                                              for i in range(5000)))  # fmt: skip
    for name in ("m.csv", "m.jsonl"):
        start = time.perf_counter()
        found, problems = _manifest_rows(tmp_path / name, name)
        assert not problems and len(found) == 5000, problems[:3]
        assert time.perf_counter() - start < 5, f"{name}: {time.perf_counter() - start:.1f} s"


def test_the_dataset_table_shows_a_long_prompt_cut_and_at_once():
    from rich.console import Console

    from geocon_core.bench import ClipEntry, Dataset
    from geocon_viewer.cli.commands_dataset import SHOWN_CHARS, _table

    prompt = "a dog runs " * 5900  # 64,900 characters: within the bound, far past a terminal
    meta = {"clip_id": "p-a", "model": "p", "prompt": prompt, "category": None, "scene_id": "p-a"}
    entry = ClipEntry("p-a", Path("/d/p/a.mp4"), None, Path("/d/p/a.meta.json"), meta, {"prompt": "manifest"})
    console = Console(width=100, record=True, file=open(os.devnull, "w"))  # noqa: SIM115
    start = time.perf_counter()
    console.print(_table(Dataset(Path("/d"), "manifest", (entry,))))
    assert time.perf_counter() - start < 2
    text = console.export_text()
    assert f"...({len(prompt)}characters)" in flat(text)
    assert len(text) < SHOWN_CHARS * 20


def test_ground_truths_that_are_fifos_are_refused_at_once(tmp_path: Path):
    from geocon_core.plant import read_plant_truth
    from geocon_core.synth import load_ground_truth

    os.mkfifo(tmp_path / "x.gt.json")
    exc = _within(5, lambda: read_plant_truth(tmp_path / "x.gt.json"))
    assert isinstance(exc, ValueError) and "FIFO" in str(exc) and "ground truth" in str(exc), exc
    exc = _within(5, lambda: load_ground_truth(tmp_path / "x.gt.json"))
    assert isinstance(exc, ReadRefused) and "FIFO" in str(exc), exc


def test_a_status_json_that_is_a_fifo_is_no_status(tmp_path: Path):
    from geocon_core.bench import read_status

    folder = tmp_path / "p-a"
    folder.mkdir()
    os.mkfifo(folder / "status.json")
    assert _within(5, lambda: read_status(folder)) is None


# --- time bounds where something outside answers --------------------------------------------------


class Listener:
    """A server on 127.0.0.1 of one of these kinds: ``silent`` (accepts and never answers),
    ``http1`` (answers every request as an HTTP/1.1 server), ``stall`` (answers the HTTP/2 preface
    with its SETTINGS, then reads nothing more: a viewer that hangs once streaming began)."""

    def __init__(self, kind: str) -> None:
        self.kind = kind
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(16)
        self.port = self.sock.getsockname()[1]
        self.conns: list[socket.socket] = []
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        while True:
            try:
                conn, _ = self.sock.accept()
            except OSError:
                return
            self.conns.append(conn)
            if self.kind == "http1":
                conn.recv(1024)
                conn.sendall(b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\n\r\n")
            elif self.kind == "stall":
                conn.recv(64)
                conn.sendall(bytes.fromhex("000000040000000000"))

    def close(self) -> None:
        for conn in self.conns:
            conn.close()
        self.sock.close()


@pytest.fixture()
def listener() -> Iterator[Callable[[str], Listener]]:
    made: list[Listener] = []

    def make(kind: str) -> Listener:
        made.append(Listener(kind))
        return made[-1]

    yield make
    for one in made:
        one.close()


def test_http2_answer_tells_a_server_that_never_answers_from_one_that_does(listener):
    from geocon_core.files.answers import http2_answer

    def ask(port: int) -> str | None:
        return http2_answer(socket.AF_INET, ("127.0.0.1", port), 1.0)

    start = time.perf_counter()
    assert ask(listener("silent").port) == "no answer within 1 s"
    assert time.perf_counter() - start < 3
    assert ask(listener("http1").port) == "it answers, but not as an HTTP/2 (gRPC) server"
    assert ask(listener("stall").port) is None  # it answered the preface: an HTTP/2 server
    free = socket.socket()
    free.bind(("127.0.0.1", 0))
    port = free.getsockname()[1]
    free.close()
    assert ask(port) == "connection refused"


@pytest.mark.full
def test_view_connect_to_a_port_that_accepts_and_never_answers_is_refused_within_5_s(ctx: Ctx, listener):  # noqa: F811
    pytest.importorskip("rerun")
    port = listener("silent").port
    case = Case("view-connect-to-a-port-that-never-answers", record,
                ("view", "rec", "--connect", f"rerun+http://127.0.0.1:{port}/proxy"), 1,
                check=quick(SUBPROCESS_TIMEOUT_S - 2), runner="subprocess")  # fmt: skip
    res = run_case(case, ctx)
    assert f"the Rerun viewer at rerun+http://127.0.0.1:{port}/proxy cannot be reached (no answer within 5 s)" in (
        res.stderr
    ), res.stderr
    assert not (ctx.tmp / "rec" / "audit.rrd").exists()


@pytest.mark.full
def test_view_connect_to_a_server_of_another_protocol_is_refused(ctx: Ctx, listener):  # noqa: F811
    pytest.importorskip("rerun")
    port = listener("http1").port
    url = f"rerun+http://127.0.0.1:{port}/proxy"
    case = Case("view-connect-to-an-http1-server", record, ("view", "rec", "--connect", url), 1, runner="subprocess")
    res = run_case(case, ctx)
    assert "not as an HTTP/2 (gRPC) server" in res.stderr, res.stderr


@pytest.mark.full
def test_view_connect_to_a_viewer_that_stops_taking_the_recording_ends_with_one_sentence(ctx: Ctx, listener):  # noqa: F811
    pytest.importorskip("rerun")
    record(ctx)
    before = snapshot(ctx.tmp)
    url = f"rerun+http://127.0.0.1:{listener('stall').port}/proxy"
    patched = "import sys, geocon_viewer.rerun.log as log; log.STREAM_FLUSH_S = 2.0; from geocon_viewer.cli import main"
    cmd = [sys.executable, "-c", patched + "; sys.argv[0] = 'geocon'; main()", "view", "rec", "--connect", url,
           "--save", "v.rrd"]  # fmt: skip
    start = time.perf_counter()
    proc = subprocess.run(cmd, cwd=ctx.tmp, capture_output=True, text=True, timeout=60, stdin=subprocess.DEVNULL)
    assert proc.returncode == 1, proc.stderr
    assert f"the Rerun viewer at {url} stopped answering while the recording streamed" in proc.stderr, proc.stderr
    assert "within 2 s" in proc.stderr and "Traceback" not in proc.stderr
    assert time.perf_counter() - start < 40
    assert snapshot(ctx.tmp) == before  # no recording, no partial file


def test_a_ray_address_that_accepts_and_never_answers_is_refused_within_its_bound(listener, monkeypatch):
    from geocon_core.bench import ray as bench_ray
    from geocon_core.bench.clip import BenchError

    monkeypatch.setattr(bench_ray, "PROBE_S", 1.0)
    port = listener("silent").port
    start = time.perf_counter()
    with pytest.raises(BenchError, match=rf"--ray-address 127.0.0.1:{port}: no Ray cluster answers there \(no answer "
                       r"within 1 s\)"):  # fmt: skip
        bench_ray._probe(f"127.0.0.1:{port}")
    assert time.perf_counter() - start < 4
    with pytest.raises(BenchError, match="not as an HTTP/2"):
        bench_ray._probe(f"127.0.0.1:{listener('http1').port}")
    with pytest.raises(BenchError, match=rf"--ray-address ray://127.0.0.1:{port}: .*no answer within 1 s"):
        bench_ray._probe(f"ray://127.0.0.1:{port}")  # a Ray client's address speaks gRPC too


def test_footage_fill_stops_a_git_that_never_answers(tmp_path: Path, monkeypatch):
    from geocon_core.validation import Annotation, fill_footage
    from geocon_core.validation import footage as footage_mod

    if shutil.which("git") is None:
        pytest.skip("git is not installed")
    clone = tmp_path / "sources" / "someone+clips"
    subprocess.run(["git", "init", "-q", "--bare", str(clone)], check=True, capture_output=True)
    os.mkfifo(clone / "objects" / "info" / "alternates")  # git opens it, and waits for a writer
    monkeypatch.setattr(footage_mod, "GIT_TIMEOUT_S", 1.0)
    note = Annotation("real/a.mp4", "static", "H", 0, True, "real", True, "C1", "", "", root="footage",
                      repo="someone/clips", commit="0" * 40, path="v/a.mp4", sha256="")  # fmt: skip
    start = time.perf_counter()
    (item,) = fill_footage([note], tmp_path / "cache", tmp_path / "sources")
    assert time.perf_counter() - start < 10
    assert item.state == "not in clone" and "did not give v/a.mp4" in item.detail and "within 1 s" in item.detail
    assert not (tmp_path / "cache" / "real" / "a.mp4").exists()
