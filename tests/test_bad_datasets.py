"""The bad-input catalogue of datasets, manifests and resumed benchmarks: what ``geocon dataset``
and ``geocon bench`` do with a clip replaced between two runs, an output folder of the other kind,
files a plain folder holds besides its clips, frame folders with gaps or with entries that are not
files, manifest paths outside the dataset, and malformed CSV and JSONL rows.

The cases use the framework of ``test_bad_input.py`` (:class:`Case`, :func:`judge`, the ``ctx``
fixture): each builds its inputs in the case's folder, runs one command line in-process (a FIFO
among frames: as a subprocess) and is judged the same way (exit code, one ``error:`` sentence
naming the file or option, nothing left behind by a refusal, inputs unchanged by a valid run)."""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path

import pytest

from . import test_bad_input as catalogue
from .bad_inputs import broken_bench_clip, pan_frames, write_pngs, write_video
from .test_bad_input import FAST, Case, Ctx, H, N, Outcome, W, nothing, record, run_case

assets = catalogue.assets
ctx = catalogue.ctx
"""The catalogue's fixtures, visible to the tests here: the shared inputs, the case's folder."""

NO_RRD = (*FAST, "--no-rrd")


def bench(dataset: str = "ds", out: str = "out", *more: str) -> tuple[str, ...]:
    """``bench DATASET --out OUT --preset fast --no-rrd MORE``."""
    return ("bench", dataset, "--out", out, *NO_RRD, *more)


def run_ok(ctx: Ctx, argv: tuple[str, ...]) -> Outcome:
    res = ctx.invoke(list(argv))
    assert res.code == 0, res.describe() + "\n" + res.stderr
    return res


def notes(res: Outcome, start: str) -> list[str]:
    """The lines of stderr that begin with ``start``."""
    return [line for line in res.stderr.splitlines() if line.startswith(start)]


# --- 1. a clip replaced between two runs of the same benchmark ------------------------------------


def two_clips(ctx: Ctx) -> None:
    """``ds/p/a.mp4`` and ``ds/p/b.mp4``: a plain folder of two clips of one platform."""
    ctx.pan("ds/p/a.mp4")
    ctx.video("ds/p/b.mp4", pan_frames(W, H, N, seed=5))


def benched_then_replaced(*, drop_fingerprint: bool = False):
    """``two_clips`` scored into ``out``, then ``a.mp4`` replaced by another clip of the same name
    (with ``drop_fingerprint``: as results written before statuses held the clip's fingerprint)."""

    def build(ctx: Ctx) -> None:
        two_clips(ctx)
        run_ok(ctx, bench())
        if drop_fingerprint:
            status = ctx.tmp / "out" / "clips" / "p-a" / "status.json"
            data = json.loads(status.read_text())
            assert data.pop("fingerprint")
            status.write_text(json.dumps(data))
        ctx.video("ds/p/a.mp4", pan_frames(W, H, N, seed=9, step=3))

    return build


def benched(ctx: Ctx) -> None:
    two_clips(ctx)
    run_ok(ctx, bench())


def rescored_a(ctx: Ctx, res: Outcome) -> None:
    """Only the replaced clip is scored again, its new record is of the new bytes, and one note
    names it."""
    from geocon_core.media import clip_fingerprint

    assert "2 clips: 2 scored, 0 failed (1 in this run, 1 finished earlier)" in res.stdout, res.stdout
    said = notes(res, "note: 1 clip file(s) changed since they were scored")
    assert len(said) == 1 and said[0].endswith(": p-a"), res.stderr
    new = record(ctx, "out/clips/p-a")["video"]["fingerprint"]
    assert new == clip_fingerprint(ctx.tmp / "ds" / "p" / "a.mp4")
    assert json.loads((ctx.tmp / "out/clips/p-a/status.json").read_text())["fingerprint"] == new


def nothing_rescored(_ctx: Ctx, res: Outcome) -> None:
    assert "(0 in this run, 2 finished earlier)" in res.stdout, res.stdout
    assert "changed since" not in res.stderr, res.stderr


RESUME = [
    Case("bench-resume-after-a-clip-was-replaced", benched_then_replaced(), bench(), 0, check=rescored_a),
    Case("bench-resume-old-results-after-a-clip-was-replaced", benched_then_replaced(drop_fingerprint=True), bench(),
         0, check=rescored_a),
    Case("bench-resume-with-nothing-changed", benched, bench(), 0, check=nothing_rescored),
]  # fmt: skip

# --- 2. a record folder and a results folder never become each other ------------------------------


def results_and_clip(ctx: Ctx) -> None:
    """``clip.mp4`` and ``res``, a results folder of ``geocon bench`` (its ``bench.json``)."""
    ctx.pan()
    ctx.write("res/bench.json", json.dumps({"format": "geocon-bench/1"}))
    (ctx.tmp / "res" / "clips" / "x").mkdir(parents=True)


def record_and_dataset(ctx: Ctx) -> None:
    """``rec``, a record folder of ``geocon score``, and ``ds``, a plain folder of one clip."""
    ctx.record("rec")
    ctx.pan("ds/p/a.mp4")


def score_out(out: str) -> tuple[str, ...]:
    return ("score", "clip.mp4", *FAST, "--out", out)


KINDS = [
    Case("score-out-is-a-bench-results-folder", results_and_clip, score_out("res"), 2, ("--out res", "bench.json")),
    Case("score-out-inside-a-bench-results-folder", results_and_clip, score_out("res/clips/x"), 2,
         ("--out res/clips/x", "bench.json")),
    Case("bench-out-is-a-record-folder", record_and_dataset, bench("ds", "rec"), 2, ("--out rec", "record.json")),
    Case("bench-out-inside-a-record-folder", record_and_dataset, bench("ds", "rec/results"), 2,
         ("--out rec/results", "record.json")),
]  # fmt: skip

# --- 3. what a plain folder holds besides its clips -----------------------------------------------


def remuxed_ts(ctx: Ctx, name: str) -> None:
    """``name``: the pan as an MPEG transport stream."""
    write_video(ctx.tmp / name, pan_frames(W, H, N, seed=1), container="mpegts")


def mixed_folder(ctx: Ctx) -> None:
    """``ds/p``: an .mp4, an .m4v and a .ts clip, a text file and a file of an unknown format."""
    ctx.pan("ds/p/a.mp4")
    ctx.video("ds/p/b.m4v", pan_frames(W, H, N, seed=4), container="mp4")
    remuxed_ts(ctx, "ds/p/c.ts")
    ctx.write("ds/p/notes.txt", "made on a Tuesday\n")
    ctx.write("ds/p/x.xyz", b"\x00\x01\x02")


SKIPPED_TWO = "note: skipped 2 files: p/notes.txt (not a clip), p/x.xyz (unknown format)"


def three_clips_listed(_ctx: Ctx, res: Outcome) -> None:
    for cid in ("p-a", "p-b", "p-c"):
        assert cid in res.stdout, res.stdout
    assert "3 clip(s)" in res.stdout, res.stdout
    assert notes(res, "note: skipped") == [SKIPPED_TWO], res.stderr


def three_clips_scored(_ctx: Ctx, res: Outcome) -> None:
    assert "3 clips: 3 scored, 0 failed" in res.stdout, res.stdout
    assert notes(res, "note: skipped") == [SKIPPED_TWO], res.stderr


def crowded_folder(ctx: Ctx) -> None:
    """One clip among 30 text files, 12 files of an unknown format and a hidden file."""
    ctx.pan("ds/p/a.mp4")
    for i in range(30):
        ctx.write(f"ds/p/notes_{i:02d}.txt", "x\n")
    for i in range(12):
        ctx.write(f"ds/p/f{i:02d}.xyz", "x\n")
    ctx.write("ds/p/.DS_Store", b"\x00")


def skipped_in_one_line(_ctx: Ctx, res: Outcome) -> None:
    said = notes(res, "note: skipped")
    assert len(said) == 1, res.stderr
    line = said[0]
    for words in ("skipped 43 files", "30 not a clip (p/notes_00.txt, p/notes_01.txt, ...)",
                  "12 unknown format (p/f00.xyz, p/f01.xyz, ...)", "1 hidden (p/.DS_Store)"):  # fmt: skip
        assert words in line, line
    assert len(line) < 300, line


def typescript_folder(ctx: Ctx) -> None:
    """A clip and a TypeScript source file (``.ts``, like an MPEG transport stream)."""
    ctx.pan("ds/p/a.mp4")
    ctx.write("ds/p/app.ts", "export const answer: number = 42;\n")


def typescript_skipped(_ctx: Ctx, res: Outcome) -> None:
    assert "1 clip(s)" in res.stdout, res.stdout
    assert notes(res, "note: skipped") == [
        "note: skipped 1 file: p/app.ts (not an MPEG transport stream: no sync byte)"
    ], res.stderr


FOLDERS = [
    Case("dataset-reads-m4v-and-ts-and-names-the-rest", mixed_folder, ("dataset", "ds"), 0, check=three_clips_listed),
    Case("bench-scores-m4v-and-ts-and-names-the-rest", mixed_folder, bench(), 0, check=three_clips_scored),
    Case("dataset-many-skipped-files-in-one-line", crowded_folder, ("dataset", "ds"), 0, check=skipped_in_one_line),
    Case("dataset-typescript-is-no-clip", typescript_folder, ("dataset", "ds"), 0, check=typescript_skipped),
]  # fmt: skip

# --- 4. frame folders: gaps, and entries that are not files ----------------------------------------


def frames(folder: str, drop: tuple[int, ...] = (), odd: str | None = None) -> Callable[[Ctx], None]:
    """``folder``: the pan as 12 numbered PNGs, less the frames ``drop``; ``odd`` replaces
    ``00005.png`` by something that is not an image file (``dir``, ``zero``: a link to /dev/zero,
    ``fifo``)."""

    def build(ctx: Ctx) -> None:
        path = ctx.tmp / folder
        write_pngs(path, pan_frames(W, H, N, seed=1))
        for t in drop:
            (path / f"{t:05d}.png").unlink()
        if odd is not None:
            (path / "00005.png").unlink()
            if odd == "dir":
                (path / "00005.png").mkdir()
            elif odd == "zero":
                os.symlink("/dev/zero", path / "00005.png")
            elif odd == "fifo":
                os.mkfifo(path / "00005.png")

    return build


GAP_WORDS = "frame numbers 3-4, 8 are missing from"


def gaps_warned(ctx: Ctx, res: Outcome) -> None:
    rec = record(ctx)
    assert rec["video"]["num_frames"] == N - 3, rec["video"]
    assert any(GAP_WORDS in w for w in rec["warnings"]), rec["warnings"]
    assert "3-4, 8" in res.stdout and "missing" in res.stdout, res.stdout


def gaps_in_status(ctx: Ctx, res: Outcome) -> None:
    status = json.loads((ctx.tmp / "out/clips/p-shot/status.json").read_text())
    assert any(GAP_WORDS in w for w in status["warnings"]), status["warnings"]


def no_gap_warning(ctx: Ctx, _res: Outcome) -> None:
    assert not [w for w in record(ctx)["warnings"] if "missing from" in w], record(ctx)["warnings"]


def every_other_frame(ctx: Ctx) -> None:
    """``frames``: 6 frames numbered 0, 2, 4, ... (exported every other frame: no gap)."""
    write_pngs(ctx.tmp / "frames", pan_frames(W, H, 6, seed=1))
    for t in reversed(range(6)):
        (ctx.tmp / "frames" / f"{t:05d}.png").rename(ctx.tmp / "frames" / f"f_{2 * t}.png")


FRAMES = [
    Case("score-frame-folder-with-gaps", frames("frames", drop=(3, 4, 8)), ("score", "frames", *FAST, "--out", "out"),
         0, check=gaps_warned),
    Case("bench-frame-folder-with-gaps", frames("ds/p/shot", drop=(3, 4, 8)), bench(), 0, check=gaps_in_status),
    Case("score-frame-folder-numbered-in-steps", every_other_frame, ("score", "frames", *FAST, "--out", "out"), 0,
         check=no_gap_warning),
    Case("score-frame-folder-holding-a-folder", frames("frames", odd="dir"), ("score", "frames", *FAST, "--out", "out"),
         2, ("00005.png", "a folder")),
    Case("score-frame-folder-holding-a-link-to-dev-zero", frames("frames", odd="zero"),
         ("score", "frames", *FAST, "--out", "out"), 2, ("00005.png", "a link to a device")),
    Case("score-frame-folder-holding-a-fifo", frames("frames", odd="fifo"), ("score", "frames", *FAST, "--out", "out"),
         2, ("00005.png", "FIFO"), runner="subprocess"),
    Case("dataset-frame-folder-holding-a-link-to-dev-zero", frames("ds/p/shot", odd="zero"), ("dataset", "ds"), 2,
         ("00005.png", "a link to a device")),
]  # fmt: skip

# --- 5. manifest paths, and a benchmark where every clip fails -------------------------------------


def manifest(name: str, text: str, *clips: str) -> Callable[[Ctx], None]:
    """``ds/<clips>`` (the pan) and the manifest ``ds/<name>`` holding ``text``."""

    def build(ctx: Ctx) -> None:
        for clip in clips or ("a.mp4",):
            ctx.pan(f"ds/{clip}")
        ctx.write(f"ds/{name}", text)

    return build


def clip_elsewhere(ctx: Ctx) -> None:
    """``elsewhere/x.mp4`` and a manifest ``ds/manifest.csv`` that names it by a relative path."""
    ctx.pan("elsewhere/x.mp4")
    ctx.write("ds/manifest.csv", "path,category\n../elsewhere/x.mp4,C1\n")


def text_masks(ctx: Ctx) -> None:
    """A manifest whose masks folder (inside the dataset) holds no masks."""
    manifest("manifest.csv", "path,masks_path\na.mp4,m\n")(ctx)
    ctx.write("ds/m/readme.txt", "masks to come\n")


def one_scored(_ctx: Ctx, res: Outcome) -> None:
    assert "1 clips: 1 scored, 0 failed" in res.stdout, res.stdout


def all_failed(ctx: Ctx, res: Outcome) -> None:
    last = res.stderr.strip().splitlines()[-1]
    assert last.startswith("error: every clip failed (1 of 1)") and "status.json" in last, res.stderr
    status = json.loads((ctx.tmp / "out/clips/broken-c1/status.json").read_text())
    assert status["status"] == "failed", status  # the failure is recorded, not dropped


def broken_only(ctx: Ctx) -> None:
    broken_bench_clip(ctx.tmp / "ds")


PATHS = [
    Case("bench-manifest-masks-path-is-etc", manifest("manifest.csv", "path,masks_path\na.mp4,/etc\n"), bench(), 2,
         ("manifest.csv line 2", "masks_path /etc", "--root")),
    Case("dataset-jsonl-masks-path-climbs-out",
         manifest("manifest.jsonl", '{"path": "a.mp4", "masks_path": "../.."}\n'), ("dataset", "ds"), 2,
         ("manifest.jsonl line 1", "masks_path ../..")),
    Case("bench-manifest-clip-outside-the-dataset", clip_elsewhere, bench(), 2,
         ("manifest.csv line 2", "../elsewhere/x.mp4", "outside")),
    Case("bench-manifest-clip-under-a-given-root", clip_elsewhere, bench("ds", "out", "--root", "elsewhere"), 0,
         check=one_scored),
    Case("bench-manifest-masks-that-are-no-masks", text_masks, bench(), 2, ("manifest.csv line 2", "masks_path m")),
    Case("bench-every-clip-fails", broken_only, bench(), 1, check=all_failed),
]  # fmt: skip

# --- 6. and 7. malformed manifest rows --------------------------------------------------------------

DEEP = "[" * 100_000 + "]" * 100_000
ROWS = [
    Case("dataset-csv-unterminated-quote",
         manifest("manifest.csv", 'path,prompt,category\na.mp4,"a dolly shot,C3\nb.mp4,another,C1\n', "a.mp4", "b.mp4"),
         ("dataset", "ds"), 2, ("manifest.csv line 2", "quote")),
    Case("dataset-csv-quote-closed-rows-later",
         manifest("manifest.csv", 'path,prompt,category\na.mp4,"a dolly,C3\nb.mp4,another,C1"\n', "a.mp4", "b.mp4"),
         ("dataset", "ds"), 2, ("manifest.csv line 2", "quote")),
    Case("dataset-csv-text-after-a-closing-quote", manifest("manifest.csv", 'path,prompt\na.mp4,"a dolly" shot\n'),
         ("dataset", "ds"), 2, ("manifest.csv line 2", "quote")),
    Case("bench-csv-unterminated-quote-after-blank-lines",
         manifest("manifest.csv", 'path,prompt\na.mp4,fine\n\n\nb.mp4,"never closed\n', "a.mp4", "b.mp4"),
         bench(), 2, ("manifest.csv line 5", "quote")),
    Case("dataset-csv-quoted-multi-line-prompt-is-fine",
         manifest("manifest.csv", 'path,prompt,category\na.mp4,"a dolly shot\npast stalls",C3\n'),
         ("dataset", "ds"), 0),
    Case("dataset-jsonl-row-is-an-array", manifest("manifest.jsonl", '{"path": "a.mp4"}\n["b.mp4"]\n'),
         ("dataset", "ds"), 2, ("manifest.jsonl line 2", "JSON object")),
    Case("dataset-jsonl-row-is-a-number", manifest("manifest.jsonl", '{"path": "a.mp4"}\n7\n'),
         ("dataset", "ds"), 2, ("manifest.jsonl line 2", "JSON object")),
    Case("dataset-jsonl-row-nested-100000-deep", manifest("manifest.jsonl", '{"path": "a.mp4"}\n' + DEEP + "\n"),
         ("dataset", "ds"), 2, ("manifest.jsonl line 2", "nested")),
    Case("bench-jsonl-object-nested-100000-deep",
         manifest("manifest.jsonl", '{"path": "a.mp4", "x": ' + '{"a": ' * 100_000 + "1" + "}" * 100_001 + "\n"),
         bench(), 2, ("manifest.jsonl line 1", "nested")),
    Case("dataset-jsonl-prompt-is-an-object",
         manifest("manifest.jsonl", '{"path": "a.mp4", "prompt": {"en": "a dolly shot"}}\n'),
         ("dataset", "ds"), 2, ("manifest.jsonl line 1", "prompt")),
    Case("dataset-sidecar-nested-100000-deep", manifest("a.meta.json", DEEP), ("dataset", "ds"), 2,
         ("a.meta.json", "nested")),
]  # fmt: skip

# --- 8. manifests and sidecars written on other machines -------------------------------------------


def sidecar(name: str = "a", raw: str | None = None, **fields: object) -> Callable[[Ctx], None]:
    """``ds/<name>.mp4`` (the pan) and its sidecar ``ds/<name>.meta.json``: every field, ``fields``
    changed; ``raw`` replaces the JSON text whole (``{}`` in it stands for the fields it does not
    give itself)."""

    def build(ctx: Ctx) -> None:
        ctx.pan(f"ds/{name}.mp4")
        meta = {"clip_id": name, "prompt": "a pan", "model": "m", "model_version": None, "seed": 0,
                "resolution": [W, H], "fps": 24, "duration": 0.5, "masks_path": None, "category": "C1",
                "scene_id": name, **fields}  # fmt: skip
        if raw is not None:
            meta = {k: v for k, v in meta.items() if f'"{k}":' not in raw}
        text = json.dumps(meta) if raw is None else raw.replace("{}", json.dumps(meta)[1:-1])
        ctx.write(f"ds/{name}.meta.json", text)

    return build


def encoded_manifest(data: bytes, name: str = "manifest.csv") -> Callable[[Ctx], None]:
    """``ds/a.mp4`` and a manifest of these bytes."""

    def build(ctx: Ctx) -> None:
        ctx.pan("ds/a.mp4")
        ctx.write(f"ds/{name}", data)

    return build


def said_category(cat: str) -> Callable[[Ctx, Outcome], None]:
    def check(_ctx: Ctx, res: Outcome) -> None:
        assert f"│ {cat}" in res.stdout and "manifest" in res.stdout, res.stdout

    return check


def a_sidecar_dataset(_ctx: Ctx, res: Outcome) -> None:
    assert "a folder of clips with sidecars (*.meta.json), 1 clip(s)" in res.stdout, res.stdout


def sidecar_folder(ctx: Ctx) -> None:
    sidecar()(ctx)
    (ctx.tmp / "ds" / "x.meta.json").mkdir()


def sidecar_dangling(ctx: Ctx) -> None:
    sidecar()(ctx)
    os.symlink("nowhere.json", ctx.tmp / "ds" / "b.meta.json")


def a_clip_file(ctx: Ctx) -> None:
    ctx.pan("a.mp4")


ELSEWHERE = [
    Case("dataset-manifest-in-utf16", encoded_manifest("path,category\na.mp4,C1\n".encode("utf-16")),
         ("dataset", "ds"), 2, ("manifest.csv", "UTF-16", "save it as UTF-8"), forbids=("codec",)),
    Case("dataset-manifest-in-latin1", encoded_manifest("path,prompt\na.mp4,café au lait\n".encode("latin-1")),
         ("dataset", "ds"), 2, ("manifest.csv", "not UTF-8", "0xe9"), forbids=("codec",)),
    Case("dataset-manifest-separated-by-semicolons", encoded_manifest(b"path;category\na.mp4;C1\n"),
         ("dataset", "ds"), 2, ("manifest.csv", "separated by ';'")),
    Case("dataset-manifest-with-a-byte-order-mark", encoded_manifest(b"\xef\xbb\xbfpath,category\na.mp4,C3\n"),
         ("dataset", "ds"), 0, check=said_category("C3")),
    Case("dataset-sidecar-with-a-byte-order-mark", sidecar(raw="\ufeff{{}}"), ("dataset", "ds"), 0,
         check=a_sidecar_dataset),
    Case("dataset-sidecar-is-a-folder", sidecar_folder, ("dataset", "ds"), 2, ("x.meta.json", "is a folder")),
    Case("dataset-sidecar-is-a-link-to-nothing", sidecar_dangling, ("dataset", "ds"), 2,
         ("b.meta.json", "link to nothing")),
    Case("dataset-manifest-with-windows-paths",
         manifest("manifest.csv", "path\nvideos\\sora\\a.mp4\n", "videos/sora/a.mp4"), ("dataset", "ds"), 2,
         ("manifest.csv line 2", "as on Windows", "videos/sora/a.mp4")),
    Case("dataset-manifest-of-urls", manifest("manifest.csv", "path\nhttps://example.com/a.mp4\n"),
         ("dataset", "ds"), 2, ("manifest.csv line 2", "URL", "local files")),
    Case("bench-a-single-clip-file", a_clip_file, bench("a.mp4"), 2, ("a.mp4", "one clip", "geocon score a.mp4")),
]  # fmt: skip

# --- 9. clip ids, names and links ------------------------------------------------------------------

LONG = "a" * 247
"""A file stem that makes a legal 251-byte clip name (``.mp4``), too long for ``<stem>.meta.json``."""


def ids_are(*ids: str) -> Callable[[Ctx, Outcome], None]:
    def check(ctx: Ctx, _res: Outcome) -> None:
        assert sorted(os.listdir(ctx.tmp / "out" / "clips")) == sorted(ids), os.listdir(ctx.tmp / "out" / "clips")

    return check


def two_sidecars_one_id_in_two_cases(ctx: Ctx) -> None:
    sidecar("a", clip_id="Clip")(ctx)
    sidecar("b", clip_id="clip")(ctx)


def hard_linked(ctx: Ctx) -> None:
    ctx.pan("ds/p/a.mp4")
    os.link(ctx.tmp / "ds/p/a.mp4", ctx.tmp / "ds/p/b.mp4")


def unicode_platforms(ctx: Ctx) -> None:
    ctx.pan("ds/日本/a.mp4")
    ctx.video("ds/中国/a.mp4", pan_frames(W, H, N, seed=5))


def unicode_ids(_ctx: Ctx, res: Outcome) -> None:
    assert "│ a " in res.stdout and "│ a_2 " in res.stdout, res.stdout
    assert notes(res, "note: 日本/a.mp4: clip id a_2 (numbered"), res.stderr


IDS = [
    Case("bench-manifest-clip-id-dot-dot", manifest("manifest.csv", "path,clip_id\na.mp4,..\n"), bench(), 2,
         ("manifest.csv line 2", "'..'", "start with a letter or a digit")),
    Case("dataset-manifest-clip-id-dot", manifest("manifest.csv", "path,clip_id\na.mp4,.\n"), ("dataset", "ds"), 2,
         ("manifest.csv line 2", "'.'", "start with a letter or a digit")),
    Case("bench-sidecar-clip-id-ending-in-a-line-break", sidecar(clip_id="a\n"), bench(), 2,
         ("a.meta.json", "clip_id 'a\\n'")),
    Case("dataset-sidecar-clip-ids-differing-in-case", two_sidecars_one_id_in_two_cases, ("dataset", "ds"), 2,
         ("b.meta.json", "clip_id 'clip' is also used by a.meta.json")),
    Case("dataset-plain-folder-hard-link", hard_linked, ("dataset", "ds"), 2,
         ("p/b.mp4", "same file as p/a.mp4", "hard link"), forbids=("row",)),
    Case("bench-251-byte-clip-name", lambda c: c.pan(f"ds/p/{LONG}.mp4"), bench(), 0,
         check=ids_are(f"p-{LONG}"[:190])),
    Case("bench-manifest-200-character-clip-id", manifest("manifest.csv", f"path,clip_id\na.mp4,{'b' * 200}\n"),
         bench(), 0, check=ids_are("b" * 200)),
    Case("dataset-unicode-platforms-give-one-id-numbered", unicode_platforms, ("dataset", "ds"), 0,
         check=unicode_ids),
]  # fmt: skip

# --- 10. numbers JSON does not have ---------------------------------------------------------------

NUMBERS = [
    Case("bench-sidecar-fps-infinity", sidecar(raw='{{}, "fps": Infinity}'), bench(), 2,
         ("a.meta.json", "Infinity", "not a JSON number")),
    Case("bench-jsonl-extra-key-nan", manifest("manifest.jsonl", '{"path": "a.mp4", "weight": NaN}\n'), bench(), 2,
         ("manifest.jsonl line 1", "NaN")),
    Case("dataset-sidecar-duration-nan", sidecar(raw='{{}, "duration": NaN}'), ("dataset", "ds"), 2,
         ("a.meta.json", "NaN")),
]  # fmt: skip

# --- 11. --root and --write ------------------------------------------------------------------------


def long_named(ctx: Ctx) -> None:
    ctx.pan(f"ds/p/{LONG}.mp4")
    ctx.video("ds/p/b.mp4", pan_frames(W, H, N, seed=5))


def sidecars_read_back(ctx: Ctx, res: Outcome) -> None:
    names = sorted(n for n in os.listdir(ctx.tmp / "ds" / "p") if n.endswith(".meta.json"))
    assert len(names) == 2 and "b.meta.json" in names, names
    assert all(len(os.fsencode(n)) < 255 for n in names) and not [
        n for n in os.listdir(ctx.tmp / "ds/p") if ".part" in n
    ]
    from geocon_core.bench import scan_dataset

    again = scan_dataset(ctx.tmp / "ds")
    assert again.layout == "sidecars" and [e.clip_id for e in again.entries] == [f"p-{LONG}"[:190], "p-b"]
    assert again.entries[0].video.name == f"{LONG}.mp4"


ROOTS_AND_WRITES = [
    Case("dataset-root-that-does-not-exist", manifest("manifest.csv", "path\na.mp4\n"),
         ("dataset", "ds", "--root", "nowhere"), 2, ("--root nowhere", "not a folder")),
    Case("bench-root-that-is-a-file", manifest("manifest.csv", "path\na.mp4\n"),
         bench("ds", "out", "--root", "ds/a.mp4"), 2, ("--root ds/a.mp4", "not a folder")),
    Case("dataset-write-a-251-byte-clip-name", long_named, ("dataset", "ds", "--write"), 0, check=sidecars_read_back),
]  # fmt: skip

# --- 12. results edited, damaged or moved between two runs -----------------------------------------


def benched_then(change: Callable[[Ctx], None]) -> Callable[[Ctx], None]:
    """``two_clips`` scored into ``out``, then ``change``."""

    def build(ctx: Ctx) -> None:
        two_clips(ctx)
        run_ok(ctx, bench())
        change(ctx)

    return build


def write_to(path: str, data: bytes) -> Callable[[Ctx], None]:
    return lambda ctx: ctx.write(path, data)


def cut_to(path: str, size: int) -> Callable[[Ctx], None]:
    def cut(ctx: Ctx) -> None:
        p = ctx.tmp / path
        p.write_bytes(p.read_bytes()[:size])

    return cut


def removed(path: str) -> Callable[[Ctx], None]:
    return lambda ctx: (ctx.tmp / path).unlink()


def table_ids(ctx: Ctx) -> list[str]:
    import pandas as pd

    return list(pd.read_parquet(ctx.tmp / "out" / "tables" / "clips.parquet")["clip_id"])


def a_scored_again(ctx: Ctx, res: Outcome) -> None:
    """p-a is scored again (its damage named in a note), p-b kept; both are in the tables."""
    assert "2 clips: 2 scored, 0 failed (1 in this run, 1 finished earlier)" in res.stdout, res.stdout
    said = notes(res, "note: 1 finished clip(s) have a damaged status.json")
    assert len(said) == 1 and said[0].endswith(": p-a"), res.stderr
    assert table_ids(ctx) == ["p-a", "p-b"]
    assert json.loads((ctx.tmp / "out/clips/p-a/status.json").read_text())["status"] == "ok"


def b_left_out(ctx: Ctx, res: Outcome) -> None:
    assert "1 clips: 1 scored, 0 failed (0 in this run, 1 finished earlier)" in res.stdout, res.stdout
    said = notes(res, "note: 1 clip folder(s) in out/clips hold clips the dataset no longer has")
    assert len(said) == 1 and "p-b" in said[0], res.stderr
    assert table_ids(ctx) == ["p-a"] and (ctx.tmp / "out/clips/p-b/record.json").is_file()


def other_dataset(ctx: Ctx) -> None:
    ctx.video("ds2/q/c.mp4", pan_frames(W, H, N, seed=7))


def now_of_ds2(ctx: Ctx, res: Outcome) -> None:
    assert notes(res, f"note: out held the results of the dataset {ctx.tmp / 'ds'}; it holds those of ds2"), res.stderr
    assert notes(res, "note: 2 clip folder(s) in out/clips hold clips the dataset no longer has"), res.stderr
    assert table_ids(ctx) == ["q-c"]
    assert json.loads((ctx.tmp / "out/bench.json").read_text())["dataset"] == str(ctx.tmp / "ds2")


def project_moved(ctx: Ctx) -> None:
    """A plain folder ``first/ds`` scored into ``first/out``, then both moved here (a project
    folder moved or copied with its results)."""
    ctx.pan("first/ds/p/a.mp4")
    ctx.video("first/ds/p/b.mp4", pan_frames(W, H, N, seed=5))
    run_ok(ctx, bench("first/ds", "first/out"))
    for name in ("ds", "out"):
        (ctx.tmp / "first" / name).rename(ctx.tmp / name)


def nothing_scored_after_the_move(ctx: Ctx, res: Outcome) -> None:
    assert "2 clips: 2 scored, 0 failed (0 in this run, 2 finished earlier)" in res.stdout, res.stdout
    assert notes(res, f"note: out held the results of the dataset {ctx.tmp / 'first' / 'ds'}"), res.stderr
    assert json.loads((ctx.tmp / "out/bench.json").read_text())["dataset"] == str(ctx.tmp / "ds")
    assert table_ids(ctx) == ["p-a", "p-b"]


DAMAGED = [
    Case("bench-resume-status-json-is-an-array", benched_then(write_to("out/clips/p-a/status.json", b"[]")), bench(),
         0, check=a_scored_again),
    Case("bench-resume-status-json-not-utf8", benched_then(write_to("out/clips/p-a/status.json", b"\xff\xfe\x00")),
         bench(), 0, check=a_scored_again),
    Case("bench-resume-status-json-without-its-status",
         benched_then(write_to("out/clips/p-a/status.json", b'{"format": "geocon-bench-clip/1", "clip_id": "p-a"}')),
         bench(), 0, check=a_scored_again),
    Case("bench-resume-record-json-deleted", benched_then(removed("out/clips/p-a/record.json")), bench(), 0,
         check=a_scored_again),
    Case("bench-resume-record-json-cut-short", benched_then(cut_to("out/clips/p-a/record.json", 100)), bench(), 0,
         check=a_scored_again),
    Case("bench-resume-matches-npz-cut-short", benched_then(cut_to("out/clips/p-a/matches.npz", 100)), bench(), 0,
         check=a_scored_again),
    Case("bench-resume-bench-json-is-an-array", benched_then(write_to("out/bench.json", b"[]")), bench(), 2,
         ("out/bench.json", "an array", "--out")),
    Case("bench-resume-bench-json-not-utf8", benched_then(write_to("out/bench.json", b"\x98\x00\xff")), bench(), 2,
         ("out/bench.json", "not UTF-8", "--out")),
    Case("bench-resume-after-a-clip-was-removed", benched_then(removed("ds/p/b.mp4")), bench(), 0, check=b_left_out),
    Case("bench-another-dataset-into-the-same-out", benched_then(other_dataset), bench("ds2"), 0, check=now_of_ds2),
    Case("bench-resume-a-moved-project", project_moved, bench(), 0, check=nothing_scored_after_the_move),
]  # fmt: skip

# --- 13. validation options and annotation files ---------------------------------------------------

NO_WORK = ("--out", "out", "--no-real", "--no-peer")
ANNOTATION_HEADER = "clip,regime,gate,movers,static_camera,source,stable_scene,category,artifacts,note"


def nothing_met(ctx: Ctx, _res: Outcome) -> None:
    rows = json.loads((ctx.tmp / "out" / "validation.json").read_text())["metrics"]
    first = rows[0]
    assert first["metric"] == "cases scored" and first["n"] == 0 and first["ok"] is None, first


VALIDATION = [
    Case("validate-heights-100000", nothing, ("validate", *NO_WORK, "--heights", "100000"), 2,
         ("--heights", "at most 4608 px", "100000")),
    Case("validate-heights-zero", nothing, ("validate", *NO_WORK, "--heights", "0"), 2, ("--heights", "got 0")),
    Case("validate-heights-an-empty-list", nothing, ("validate", *NO_WORK, "--heights", ","), 2,
         ("--heights", "lists none")),
    Case("validate-codecs-an-empty-list", nothing, ("validate", *NO_WORK, "--codecs", ","), 2,
         ("--codecs", "lists none", "png")),
    Case("validate-annotations-missing", nothing, ("validate", *NO_WORK, "--annotations", "nope.csv"), 2,
         ("annotation file nope.csv", "does not exist"), forbids=("Errno",)),
    Case("validate-report-only-with-nothing-scored", nothing, ("validate", *NO_WORK, "--report-only"), 0,
         check=nothing_met),
    Case("footage-fill-from-a-folder-that-does-not-exist", nothing, ("footage", "fill", "--from", "nope"), 2,
         ("--from nope", "does not exist"), forbids=("--footage-from",)),
    Case("footage-fill-from-a-file", lambda c: c.write("afile", "x\n"), ("footage", "fill", "--from", "afile"), 2,
         ("--from afile", "a file")),
    Case("footage-status-of-a-cache-that-is-a-file", lambda c: c.write("afile", "x\n"),
         ("footage", "status", "--footage", "afile"), 2, ("--footage afile", "not a folder")),
    Case("footage-status-annotations-of-other-columns", lambda c: c.write("other.csv", "a,b\n1,2\n"),
         ("footage", "status", "--annotations", "other.csv"), 2, ("other.csv", "no columns clip", "annotation CSV")),
    Case("footage-status-annotations-empty", lambda c: c.write("empty.csv", ""),
         ("footage", "status", "--annotations", "empty.csv"), 2, ("empty.csv", "no columns")),
    Case("footage-status-annotations-a-folder", lambda c: (c.tmp / "adir").mkdir(),
         ("footage", "status", "--annotations", "adir"), 2, ("annotation file adir", "a folder"), forbids=("Errno",)),
    Case("footage-status-annotations-not-utf8", lambda c: c.write("bin.csv", b"\xff\xfe\x00"),
         ("footage", "status", "--annotations", "bin.csv"), 2, ("bin.csv", "not UTF-8"), forbids=("codec",)),
    Case("footage-status-annotations-row-short-of-cells",
         lambda c: c.write("short.csv", f"{ANNOTATION_HEADER}\nreal/x.gif,pan,H\n"),
         ("footage", "status", "--annotations", "short.csv"), 0),
    Case("footage-status-annotations-movers-not-a-number",
         lambda c: c.write("m.csv", f"{ANNOTATION_HEADER}\nreal/x.gif,pan,H,two,no,x,yes,C2,,\n"),
         ("footage", "status", "--annotations", "m.csv"), 2, ("m.csv row 2", "movers", "'two'")),
]  # fmt: skip

CASES = RESUME + KINDS + FOLDERS + FRAMES + PATHS + ROWS + ELSEWHERE + IDS + NUMBERS + ROOTS_AND_WRITES + DAMAGED
CASES += VALIDATION


def test_the_catalogue_is_complete():
    names = [c.name for c in CASES]
    assert len(names) == len(set(names)), "case names are unique"


@pytest.mark.full
@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_bad_dataset(case: Case, ctx: Ctx):
    run_case(case, ctx)


def test_skipped_files_are_listed_one_by_one_up_to_a_few():
    from geocon_core.bench.dataset import SKIPPED_LISTED, _skipped_note

    few = [(f"n{i}.txt", "not a clip") for i in range(SKIPPED_LISTED)]
    assert _skipped_note(few) == f"skipped {SKIPPED_LISTED} files: " + ", ".join(f"{n} (not a clip)" for n, _ in few)
    many = few + [("x.xyz", "unknown format")]
    assert _skipped_note(many) == (
        f"skipped {SKIPPED_LISTED + 1} files: {SKIPPED_LISTED} not a clip (n0.txt, n1.txt, ...); "
        "1 unknown format (x.xyz)"
    )


def test_frame_number_gaps_need_one_naming_scheme():
    from geocon_core.media.decode import frame_number_gaps

    def gaps(*names: str) -> tuple[str, ...]:
        return frame_number_gaps([Path(n) for n in names], "f")

    assert gaps("a1.png", "b3.png") == ()  # two schemes: no numbering to judge
    assert gaps("f01.png", "f1.png", "f3.png") == ()  # a number twice
    assert gaps("x.png", "y.png") == ()
    assert gaps("shot2_001.png", "shot2_002.png", "shot2_004.png") == (
        "frame number 3 is missing from f: the frames either side of a gap are scored as neighbours, one frame apart",
    )
    assert gaps(*(f"{i}.png" for i in range(5))) == ()
    (many,) = gaps(*(f"{i:03d}.png" for i in (0, 2, 4, 8, 12, 16, 20, 24, 28, 32, 36, 40, 100)))
    assert many.startswith("frame numbers 6, 10, 14, 18, 22, 26, 30, 34 and 2 more gaps (38 in all)"), many
    assert "(numbered in steps of 2)" in many, many
