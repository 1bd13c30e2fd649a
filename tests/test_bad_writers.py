"""The bad-writer catalogue: outputs that would land on what the command does not own.

One rule holds for every writer (:func:`geocon_core.files.claim`): a command writes only the files
it owns in this run, and replaces a file only when it is its own kind made by GeoCon for the same
input. Refused, in one sentence before any work, are outputs that land on a part of another GeoCon
output (a record's ``record.json``, ``matches.npz``, ``overlays/``, ``audit.rrd``; a results
folder's ``bench.json``, ``clips/``, ``tables/``, its report; anything in a report folder; a
validation's reports and cases; a planted clip's ground truth), on a user's file that is not the
output's own kind made by GeoCon (``--rrd notes.txt``, ``view --save`` onto a PNG or an MP4,
``pose-log --out`` onto a file that is no pose log, ``dataset --write --force`` over a sidecar
written by hand), and GeoCon's own kind made for another input (the record of another clip, the
clean twin of another source). Outputs of several files are checked whole before the first one
moves and committed together. Re-running a command on the same input replaces its own earlier
output (the cases ending in ``-again``).

The cases use the framework of :mod:`tests.test_bad_input`: a refusal is exit 2 with one
``error:`` line and nothing changed or left behind; a valid run changes nothing outside ``out/``.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import pytest

from geocon_core.files import (
    FOLDER_KINDS,
    OutPathError,
    check_targets,
    claim,
    commit_together,
    folder_kind,
    held,
    stamp_png,
)

from .bad_inputs import pan_frames, snapshot
from .test_bad_input import FAST, Case, Ctx, Outcome, assets, build_all, ctx, nothing, run_case, score  # noqa: F401
from .test_bad_outputs import benched, dust3r_scene

W, H, N = 160, 90, 12
PLANT = ("--failure", "morph", "--severity", "low")
QUICK_VALIDATION = ("--report-only", "--quick", "--no-real")


# --- builders -------------------------------------------------------------------------------------


def invoked(*argv: str) -> Callable[[Ctx], None]:
    """A build step: ``geocon ARGV`` in the case's folder, which must succeed."""

    def build(c: Ctx) -> None:
        res = c.invoke(list(argv))
        assert res.code == 0, f"{argv}: {res.describe()}\n{res.stdout[-2000:]}"

    return build


def rec_a(c: Ctx) -> None:
    """``recA``: the record of the C4 clip, and ``b.mp4``, another clip."""
    c.record("recA")
    c.pan("b.mp4")


def recs_a_b(c: Ctx) -> None:
    """``recA`` and ``recB``: two record folders."""
    c.record("recA")
    c.record("recB")


def write(name: str, data: bytes | str) -> Callable[[Ctx], None]:
    return lambda c: c.write(name, data)


def users_png(name: str) -> Callable[[Ctx], None]:
    """A PNG image of the user's (a photo GeoCon did not make)."""

    def build(c: Ctx) -> None:
        c.tmp.joinpath(name).parent.mkdir(parents=True, exist_ok=True)
        assert cv2.imwrite(str(c.tmp / name), np.full((24, 32, 3), 90, np.uint8))

    return build


def other_recording(name: str) -> Callable[[Ctx], None]:
    """A Rerun recording made by another program (its own application id)."""

    def build(c: Ctx) -> None:
        import rerun as rr

        rec = rr.RecordingStream("somebody-else")
        rec.save(str(c.tmp / name))
        rec.log("points", rr.Points2D([[0.0, 0.0]]))
        rec.flush()
        rec.disconnect()

    return build


def pose_log(name: str, source: str | None) -> Callable[[Ctx], None]:
    log = {"format": "geocon-pose/1", "T_cam0_camT": np.eye(4).tolist(), "scale": "metric"}
    log.update(mean_scene_distance=2.0, pose_present=True)
    if source is not None:
        log["source"] = source
    return write(name, json.dumps(log, indent=1))


def reported(c: Ctx) -> None:
    """``res`` (``benched``) and its report ``res/report``."""
    benched(c)
    invoked("report", "res", "--bootstrap", "100")(c)


def validated(folder: str) -> Callable[[Ctx], None]:
    return invoked("validate", *QUICK_VALIDATION, "--out", folder)


def planted(source: str = "x/a.mp4", out: str = "pl", *more: str) -> Callable[[Ctx], None]:
    """``source`` (the pan clip) planted with a low morph into ``out``."""

    def build(c: Ctx) -> None:
        if not (c.tmp / source).exists():
            c.pan(source)
        invoked("plant", source, *PLANT, "--out", out, *more)(c)

    return build


def other_source(name: str = "y/a.mp4") -> Callable[[Ctx], None]:
    """Another clip with the same stem as ``x/a.mp4`` (other bytes)."""
    return lambda c: c.video(name, pan_frames(W, H, N, seed=7))


def synthed(out: str) -> Callable[[Ctx], None]:
    return invoked("synth", "C1", "--out", out, "--frames", "4", "--size", "64x48")


def last_synth_clip_is_users(c: Ctx) -> None:
    """``syn/<last clip of synth all>.mp4``: a user's file with the name of the last clip."""
    from geocon_core.synth import plan_clips

    c.write(f"syn/{plan_clips('all', None, None)[-1].clip_id}.mp4", "mine\n")


def mkdir(name: str) -> Callable[[Ctx], None]:
    return lambda c: c.tmp.joinpath(name).mkdir(parents=True)


def manifest_dataset(root: str, prompt: str) -> Callable[[Ctx], None]:
    """``ROOT/p/a.mp4`` described by ``ROOT/manifest.csv`` (its prompt ``prompt``)."""

    def build(c: Ctx) -> None:
        c.pan(f"{root}/p/a.mp4")
        c.write(f"{root}/manifest.csv", f"clip_id,path,platform,prompt\na,p/a.mp4,p,{prompt}\n")

    return build


def moved(src: str, dst: str) -> Callable[[Ctx], None]:
    return lambda c: os.rename(c.tmp / src, c.tmp / dst)


def damaged_record(c: Ctx) -> None:
    """``c4.mp4`` and, in ``out``, a record of it whose ``record.json`` was cut short."""
    c.c4()
    c.record("out")
    text = (c.tmp / "out" / "record.json").read_text()
    (c.tmp / "out" / "record.json").write_text(text[: len(text) // 2])


# --- checks of valid runs -------------------------------------------------------------------------


def is_recording(name: str) -> Callable[[Ctx, Outcome], None]:
    def check(c: Ctx, _res: Outcome) -> None:
        there = held(c.tmp / name)
        assert there.kind == "recording" and there.geocon, there

    return check


def record_of(name: str, clip: str) -> Callable[[Ctx, Outcome], None]:
    def check(c: Ctx, _res: Outcome) -> None:
        doc = json.loads((c.tmp / name / "record.json").read_text())
        assert Path(doc["video"]["abs_path"]).name == clip, doc["video"]

    return check


def twin_named_by_every_truth(folder: str) -> Callable[[Ctx, Outcome], None]:
    """Every ground truth in ``folder`` names the clean twin's SHA-256 (none is left stale)."""

    def check(c: Ctx, _res: Outcome) -> None:
        sha = hashlib.sha256((c.tmp / folder / "a.clean.mp4").read_bytes()).hexdigest()
        truths = sorted((c.tmp / folder).glob("*.gt.json"))
        assert len(truths) >= 1
        for t in truths:
            assert json.loads(t.read_text())["clean"]["sha256"] == sha, t.name

    return check


def sidecar_says(path: str, key: str, value: object) -> Callable[[Ctx, Outcome], None]:
    def check(c: Ctx, _res: Outcome) -> None:
        assert json.loads((c.tmp / path).read_text())[key] == value

    return check


def unchanged_file(path: str, text: str) -> Callable[[Ctx, Outcome], None]:
    def check(c: Ctx, _res: Outcome) -> None:
        assert (c.tmp / path).read_text() == text

    return check


HAND_SIDECAR = (
    '{"clip_id": "a", "model": "p", "prompt": "my own words", "video": "a.mp4",\n'
    '  "model_version": null, "seed": null, "resolution": [160, 90], "fps": 24.0, "duration": 0.5,\n'
    '  "masks_path": null, "category": null, "scene_id": "a"}\n'
)
"""A complete sidecar written by hand (not laid out as GeoCon writes one)."""


# --- the catalogue --------------------------------------------------------------------------------

RRD = ("rerun",)

SCORE = [
    Case("score-rrd-onto-another-records-record-json", rec_a, score("b.mp4", "--rrd", "recA/record.json", out="recB"),
         2, ("--rrd recA/record.json", "record.json of recA")),
    Case("score-rrd-onto-another-records-matches", rec_a, score("b.mp4", "--rrd", "recA/matches.npz", out="recB"), 2,
         ("--rrd recA/matches.npz", "matches.npz of recA")),
    Case("score-rrd-into-another-records-overlays", rec_a,
         score("b.mp4", "--rrd", "recA/overlays/b.rrd", out="recB"), 2, ("--rrd", "overlays of recA")),
    Case("score-rrd-onto-another-records-recording", rec_a, score("b.mp4", "--rrd", "recA/audit.rrd", out="recB"), 2,
         ("--rrd", "audit.rrd of recA")),
    Case("score-rrd-onto-a-users-text-file", build_all(rec_a, write("notes.txt", "my notes\n")),
         score("b.mp4", "--rrd", "notes.txt"), 2, ("--rrd notes.txt", "not a Rerun recording")),
    Case("score-rrd-onto-another-video", build_all(rec_a, lambda c: c.pan("holiday.mp4")),
         score("b.mp4", "--rrd", "holiday.mp4"), 2, ("--rrd holiday.mp4", "a video")),
    Case("score-rrd-onto-another-programs-recording", build_all(rec_a, other_recording("theirs.rrd")),
         score("b.mp4", "--rrd", "theirs.rrd"), 2, ("--rrd theirs.rrd", "another program"), needs=RRD),
    Case("score-rrd-onto-a-bench-manifest", build_all(benched, lambda c: c.pan("b.mp4")),
         score("b.mp4", "--rrd", "res/bench.json"), 2, ("--rrd res/bench.json", "bench.json of res")),
    Case("score-rrd-into-bench-tables", build_all(benched, lambda c: c.pan("b.mp4")),
         score("b.mp4", "--rrd", "res/tables/b.rrd"), 2, ("--rrd", "tables of res")),
    Case("score-rrd-onto-a-bench-clip-status", build_all(benched, lambda c: c.pan("b.mp4")),
         score("b.mp4", "--rrd", "res/clips/p-a/status.json"), 2, ("--rrd", "clips of res")),
    Case("score-rrd-into-a-report", build_all(reported, lambda c: c.pan("b.mp4")),
         score("b.mp4", "--rrd", "res/report/b.rrd"), 2, ("--rrd", "res/report", "replaced whole")),
    Case("score-rrd-onto-a-plant-ground-truth", build_all(planted(), lambda c: c.pan("b.mp4")),
         score("b.mp4", "--rrd", "pl/a.morph-low-s0.gt.json"), 2, ("--rrd", "ground truth of a planted clip")),
    Case("score-rrd-through-a-link-onto-another-records-record-json",
         build_all(rec_a, lambda c: os.symlink("recA/record.json", c.tmp / "link.rrd")),
         score("b.mp4", "--rrd", "link.rrd", out="recB"), 2, ("--rrd link.rrd", "record.json")),
    Case("score-rrd-onto-a-pose-log", build_all(lambda c: c.pan("b.mp4"), pose_log("pose.json", "dust3r s.npz: x")),
         score("b.mp4", "--rrd", "pose.json"), 2, ("--rrd pose.json", "pose log")),
    Case("score-rrd-again-replaces-its-own-recording",
         build_all(lambda c: c.pan(), invoked(*score("clip.mp4", "--rrd", "out/a.rrd"))),
         score("clip.mp4", "--rrd", "out/a.rrd"), 0, check=is_recording("out/a.rrd"), needs=RRD),
    Case("score-out-is-another-clips-record", rec_a, score("b.mp4", out="recA"), 2,
         ("--out recA", "record of", "not of b.mp4")),
    Case("score-out-again-on-the-same-clip", build_all(lambda c: c.pan(), invoked(*score("clip.mp4"))),
         score("clip.mp4"), 0, check=record_of("out", "clip.mp4")),
    Case("score-out-again-after-record-and-clip-moved",
         build_all(lambda c: c.pan("pre/a.mp4"), invoked(*score("pre/a.mp4", out="pre/rec")), moved("pre", "out")),
         score("out/a.mp4", out="out/rec"), 0, check=record_of("out/rec", "a.mp4")),
    Case("score-out-a-damaged-record-is-scored-again", damaged_record, score("c4.mp4"), 0,
         check=record_of("out", "c4.mp4")),
    Case("score-out-holds-a-users-overlays-folder", build_all(lambda c: c.pan(), write("mine/overlays/keep.txt", "x")),
         score("clip.mp4", out="mine"), 2, ("--out mine", "overlays")),
    Case("score-out-is-a-report", build_all(reported, lambda c: c.pan("b.mp4")), score("b.mp4", out="res/report"), 2,
         ("--out res/report",)),
    Case("score-out-is-a-validation-folder", build_all(validated("v"), lambda c: c.pan("b.mp4")),
         score("b.mp4", out="v"), 2, ("--out v", "validation")),
]  # fmt: skip

VIEW = [
    Case("view-save-onto-another-records-record-json", recs_a_b,
         ("view", "recB", "--headless", "--save", "recA/record.json"), 2, ("--save recA/record.json", "recA"),
         needs=RRD),
    Case("view-save-onto-a-users-png", build_all(recs_a_b, users_png("shot.png")),
         ("view", "recA", "--headless", "--save", "shot.png"), 2, ("--save shot.png", "PNG image"), needs=RRD),
    Case("view-save-onto-a-users-mp4", build_all(recs_a_b, lambda c: c.pan("holiday.mp4")),
         ("view", "recA", "--headless", "--save", "holiday.mp4"), 2, ("--save holiday.mp4", "a video"), needs=RRD),
    Case("view-screenshot-onto-a-users-png", build_all(recs_a_b, users_png("photo.png")),
         ("view", "recA", "--headless", "--screenshot", "photo.png"), 2,
         ("--screenshot photo.png", "PNG image GeoCon did not make"), needs=RRD),
    Case("view-screenshot-onto-another-records-overlay", recs_a_b,
         ("view", "recA", "--headless", "--screenshot", "recB/overlays/shot.png"), 2,
         ("--screenshot", "overlays of recB"), needs=RRD),
    Case("view-save-into-bench-tables", benched, ("view", "res/clips/p-a", "--headless", "--save", "res/tables/a.rrd"),
         2, ("--save", "tables of res"), needs=RRD),
    Case("view-save-again-replaces-its-own-recording", build_all(lambda c: c.record("out"),
         invoked("view", "out", "--headless")), ("view", "out", "--headless"), 0, check=is_recording("out/audit.rrd"),
         needs=RRD),
]  # fmt: skip

POSE_LOGS = [
    Case("pose-log-out-onto-a-text-file", build_all(dust3r_scene, write("notes.txt", "mine\n")),
         ("pose-log", "scene.npz", "--out", "notes.txt"), 2, ("--out notes.txt", "not GeoCon's pose log")),
    Case("pose-log-out-onto-another-records-record-json", build_all(dust3r_scene, lambda c: c.record("recA")),
         ("pose-log", "scene.npz", "--out", "recA/record.json"), 2, ("--out recA/record.json", "record.json of recA")),
    Case("pose-log-out-onto-a-synthetic-ground-truth", build_all(dust3r_scene, synthed("syn")),
         ("pose-log", "scene.npz", "--out", "syn/c1_static.gt.json"), 2, ("--out", "ground truth of a synthetic clip")),
    Case("pose-log-out-onto-a-hand-written-pose-log", build_all(dust3r_scene, pose_log("p.json", None)),
         ("pose-log", "scene.npz", "--out", "p.json"), 2, ("--out p.json", "did not write")),
    Case("pose-log-out-onto-the-log-of-another-scene",
         build_all(dust3r_scene, pose_log("p.json", "dust3r other.npz: view 0 -> view 5")),
         ("pose-log", "scene.npz", "--out", "p.json"), 2, ("--out p.json", "dust3r other.npz", "dust3r scene.npz")),
    Case("pose-log-out-again-from-the-same-scene",
         build_all(dust3r_scene, invoked("pose-log", "scene.npz", "--out", "out/p.json")),
         ("pose-log", "scene.npz", "--out", "out/p.json"), 0),
]  # fmt: skip

BENCH = [
    Case("bench-out-holds-a-users-clips-folder",
         build_all(lambda c: c.pan("ds/p/a.mp4"), write("proj/clips/p-a/notes.txt", "keep me\n")),
         ("bench", "ds", "--out", "proj", *FAST, "--no-rrd"), 2, ("--out proj", "clips", "bench.json")),
    Case("bench-out-is-a-report", reported, ("bench", "ds", "--out", "res/report", *FAST, "--no-rrd"), 2,
         ("--out res/report",)),
    Case("bench-out-is-a-validation-folder", build_all(validated("v"), lambda c: c.pan("ds/p/a.mp4")),
         ("bench", "ds", "--out", "v", *FAST, "--no-rrd"), 2, ("--out v", "validation")),
    Case("bench-out-inside-another-results-tables", benched, ("bench", "ds", "--out", "res/tables/more", *FAST,
         "--no-rrd"), 2, ("--out res/tables/more", "tables of res")),
    Case("bench-again-resumes-its-own-results",
         build_all(lambda c: c.pan("ds/p/a.mp4"), invoked("bench", "ds", "--out", "out", *FAST, "--no-rrd")),
         ("bench", "ds", "--out", "out", *FAST, "--no-rrd"), 0),
]  # fmt: skip


def two_results(c: Ctx) -> None:
    """``res`` with its report and ``res2``, the results of another dataset."""
    reported(c)
    c.pan("ds2/q/b.mp4")
    invoked("bench", "ds2", "--out", "res2", *FAST, "--no-rrd")(c)


REPORTS = [
    Case("report-out-is-another-results-report", two_results, ("report", "res2", "--bootstrap", "100", "--out",
         "res/report"), 2, ("--out res/report", "report of res")),
    Case("report-out-inside-another-results-clips", two_results, ("report", "res2", "--bootstrap", "100", "--out",
         "res/clips/rep"), 2, ("--out res/clips/rep", "clips of res")),
    Case("report-out-a-folder-with-a-users-report-html",
         build_all(benched, write("mine/report.html", "<html>my own page</html>")),
         ("report", "res", "--bootstrap", "100", "--out", "mine"), 2, ("--out mine", "report.html")),
    Case("report-again-replaces-its-own-report",
         build_all(benched, moved("res", "out"), invoked("report", "out", "--bootstrap", "100")),
         ("report", "out", "--bootstrap", "100"), 0),
]  # fmt: skip

VALIDATE = [
    Case("validate-report-only-into-a-results-folder", benched, ("validate", *QUICK_VALIDATION, "--out", "res"), 2,
         ("--out res", "bench.json")),
    Case("validate-report-only-into-a-record-folder", lambda c: c.record("recA"),
         ("validate", *QUICK_VALIDATION, "--out", "recA"), 2, ("--out recA", "record.json")),
    Case("validate-report-only-into-a-report-folder", reported, ("validate", *QUICK_VALIDATION, "--out", "res/report"),
         2, ("--out res/report",)),
    Case("validate-report-only-over-a-users-validation-md", write("mine/validation.md", "# My notes\n"),
         ("validate", *QUICK_VALIDATION, "--out", "mine"), 2, ("--out mine", "validation.md")),
    Case("validate-out-with-a-users-cases-folder", write("mine/cases/holiday/notes.txt", "keep me\n"),
         ("validate", *QUICK_VALIDATION, "--out", "mine"), 2, ("--out mine", "cases")),
    Case("validate-cache-is-a-record-folder", lambda c: c.record("recA"),
         ("validate", *QUICK_VALIDATION, "--out", "v", "--cache", "recA"), 2, ("--cache recA", "record.json")),
    Case("validate-report-only-again", validated("out"), ("validate", *QUICK_VALIDATION, "--out", "out"), 0),
    Case("validate-shares-another-validations-cache", validated("v1"),
         ("validate", *QUICK_VALIDATION, "--out", "out", "--cache", "v1/cache"), 0),
    Case("validate-fit-over-a-users-clip-model", build_all(validated("v"), write("v/clip_model.json", '{"w": 1}')),
         ("validate", "--fit", "--no-real", "--out", "v"), 2, ("--out v/clip_model.json", "clip model")),
    Case("footage-fill-into-a-record-folder", build_all(lambda c: c.record("recA"), mkdir("clones")),
         ("footage", "fill", "--from", "clones", "--footage", "recA"), 2, ("--footage recA", "record.json")),
    Case("footage-fill-into-bench-clips", build_all(benched, mkdir("clones")),
         ("footage", "fill", "--from", "clones", "--footage", "res/clips/footage"), 2, ("--footage", "clips of res")),
]  # fmt: skip

DATASETS = [
    Case("dataset-write-force-over-a-hand-written-sidecar",
         build_all(manifest_dataset("ds", "a cat"), write("ds/p/a.meta.json", HAND_SIDECAR)),
         ("dataset", "ds/manifest.csv", "--write", "--force"), 2, ("--write", "a.meta.json", "by hand")),
    Case("dataset-write-force-over-a-file-that-is-no-sidecar",
         build_all(manifest_dataset("ds", "a cat"), write("ds/p/a.meta.json", "shopping list\n")),
         ("dataset", "ds/manifest.csv", "--write", "--force"), 2, ("--write", "a.meta.json", "GeoCon did not make")),
    Case("dataset-write-force-again-rewrites-its-own-sidecars",
         build_all(manifest_dataset("out", "a cat"), invoked("dataset", "out/manifest.csv", "--write"),
                   manifest_dataset("out", "a dog")),
         ("dataset", "out/manifest.csv", "--write", "--force"), 0, check=sidecar_says("out/p/a.meta.json", "prompt",
         "a dog")),
    Case("dataset-write-force-keeps-hand-written-sidecars-that-say-it",
         build_all(lambda c: c.pan("ds/p/a.mp4"), write("ds/p/a.meta.json", HAND_SIDECAR)),
         ("dataset", "ds", "--write", "--force"), 0, check=unchanged_file("ds/p/a.meta.json", HAND_SIDECAR)),
]  # fmt: skip

SYNTH = [
    Case("synth-out-is-a-record-folder", lambda c: c.record("recA"), ("synth", "C1", "--out", "recA", "--frames", "4"),
         2, ("--out recA", "record.json")),
    Case("synth-out-inside-bench-clips", benched, ("synth", "C1", "--out", "res/clips/syn", "--frames", "4"), 2,
         ("--out res/clips/syn", "clips of res")),
    Case("synth-over-a-users-clip-of-that-name", lambda c: c.pan("syn/c1_static.mp4"),
         ("synth", "C1", "--out", "syn", "--frames", "4", "--size", "64x48"), 2,
         ("syn/c1_static.mp4", "not an earlier rendering")),
    Case("synth-over-a-users-masks-folder", write("syn/c1_static.masks/mine.png", b"\x89PNG mine"),
         ("synth", "C1", "--out", "syn", "--frames", "4", "--size", "64x48"), 2, ("syn/c1_static.masks",)),
    Case("synth-where-the-clip-name-is-a-folder", write("syn/c1_static.mp4/keep.txt", "keep me\n"),
         ("synth", "C1", "--out", "syn", "--frames", "4", "--size", "64x48"), 2, ("syn/c1_static.mp4",)),
    Case("synth-all-checks-every-clip-before-the-first", last_synth_clip_is_users,
         ("synth", "all", "--out", "syn", "--frames", "4", "--size", "64x48"), 2, ("not an earlier rendering",)),
    Case("synth-again-replaces-its-own-clip", synthed("out"),
         ("synth", "C1", "--out", "out", "--frames", "4", "--size", "64x48", "--seed", "3"), 0),
    Case("synth-bench-out-is-a-results-folder", benched, ("synth-bench", "--out", "res", "--scenes", "1", "--families",
         "C1", "--frames", "4", "--size", "64x48"), 2, ("--out res", "bench.json")),
    Case("synth-bench-over-a-users-file", write("sb/clean/C1-seed0/c1_static.mp4", "not a clip\n"),
         ("synth-bench", "--out", "sb", "--scenes", "1", "--families", "C1", "--frames", "4", "--size", "64x48"), 2,
         ("c1_static.mp4", "not an earlier rendering")),
    Case("demo-out-is-a-record-folder", lambda c: c.record("recA"), ("demo", "--out", "recA"), 2,
         ("--out recA", "record.json")),
    Case("demo-out-holds-a-users-demo-rrd", write("dm/demo.rrd", "my own notes\n"), ("demo", "--out", "dm"), 2,
         ("--rrd dm/demo.rrd", "not a Rerun recording"), needs=RRD),
]  # fmt: skip

PLANTS = [
    Case("plant-clean-twin-over-a-users-file", build_all(lambda c: c.pan("x/a.mp4"), write("pl/a.clean.mp4", "mine\n")),
         ("plant", "x/a.mp4", *PLANT, "--out", "pl"), 2, ("pl/a.clean.mp4", "not the clean twin")),
    Case("plant-clean-twin-of-another-source-with-the-same-stem", build_all(planted(), other_source()),
         ("plant", "y/a.mp4", "--failure", "slide", "--severity", "low", "--out", "pl"), 2,
         ("pl/a.clean.mp4", "another clip", "a folder of its own")),
    Case("plant-clean-twin-path-is-a-folder", build_all(lambda c: c.pan("x/a.mp4"), write("pl/a.clean.mp4/k", "x")),
         ("plant", "x/a.mp4", *PLANT, "--out", "pl"), 2, ("pl/a.clean.mp4", "is a folder")),
    Case("plant-truth-path-is-a-folder",
         build_all(lambda c: c.pan("x/a.mp4"), write("pl/a.morph-low-s0.gt.json/k", "x")),
         ("plant", "x/a.mp4", *PLANT, "--out", "pl"), 2, ("a.morph-low-s0.gt.json", "is a folder")),
    Case("plant-over-a-users-file-of-the-planted-name",
         build_all(lambda c: c.pan("x/a.mp4"), write("pl/a.morph-low-s0.mp4", "mine\n")),
         ("plant", "x/a.mp4", *PLANT, "--out", "pl"), 2, ("pl/a.morph-low-s0.mp4", "not part of an earlier planting")),
    Case("plant-truth-of-another-source", build_all(planted(), other_source(), lambda c: (c.tmp / "pl/a.clean.mp4")
         .unlink()), ("plant", "y/a.mp4", *PLANT, "--out", "pl"), 2, ("a.morph-low-s0.gt.json", "another clip")),
    Case("plant-over-a-users-clean-sidecar",
         build_all(lambda c: c.pan("x/a.mp4"), write("pl/a.clean.meta.json", '{"clip_id": "mine"}')),
         ("plant", "x/a.mp4", *PLANT, "--out", "pl"), 2, ("pl/a.clean.meta.json", "not the clean twin")),
    Case("plant-same-source-other-frames", planted(), ("plant", "x/a.mp4", "--failure", "slide", "--severity", "low",
         "--out", "pl", "--frames", "8"), 2, ("pl/a.clean.mp4", "first 12 frames", "--frames 12")),
    Case("plant-out-is-a-record-folder", build_all(lambda c: c.pan("x/a.mp4"), lambda c: c.record("recA")),
         ("plant", "x/a.mp4", *PLANT, "--out", "recA"), 2, ("--out recA", "record.json")),
    Case("plant-again-replaces-its-own-planting", planted(out="out"), ("plant", "x/a.mp4", *PLANT, "--out", "out"), 0,
         check=twin_named_by_every_truth("out")),
    Case("plant-again-another-kind-shares-the-twin", planted(out="out"),
         ("plant", "x/a.mp4", "--failure", "slide", "--severity", "low", "--out", "out"), 0,
         check=twin_named_by_every_truth("out")),
]  # fmt: skip

SCREENSHOTS = [
    Case("serve-screenshot-onto-a-users-png", build_all(benched, users_png("photo.png")),
         ("serve", "res", "--port", "0", "--screenshot", "photo.png"), 2, ("--screenshot photo.png", "PNG image"),
         needs=("viser",)),
    Case("teach-screenshot-onto-another-records-record-json", lambda c: c.record("recA"),
         ("teach", "--port", "0", "--screenshot", "recA/record.json"), 2, ("--screenshot", "record.json of recA"),
         needs=("viser",)),
]  # fmt: skip

CASES = SCORE + VIEW + POSE_LOGS + BENCH + REPORTS + VALIDATE + DATASETS + SYNTH + PLANTS + SCREENSHOTS


def test_the_catalogue_is_complete():
    names = [c.name for c in CASES]
    assert len(names) == len(set(names)), "case names are unique"
    assert len(CASES) >= 45
    assert sum(c.code == 0 for c in CASES) >= 8, "re-running on the same input replaces its own output"


@pytest.mark.full
@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_bad_writer(case: Case, ctx: Ctx):  # noqa: F811
    run_case(case, ctx)


# --- the rule's one home --------------------------------------------------------------------------


def _record_folder(root: Path) -> Path:
    (root / "overlays").mkdir(parents=True)
    (root / "record.json").write_text('{"format": "geocon-record/1"}')
    return root


def test_what_a_path_holds_is_told_by_its_bytes(tmp_path: Path):
    (tmp_path / "p.json").write_text(json.dumps({"format": "geocon-pose/1", "source": "colmap m: a -> b"}))
    (tmp_path / "mine.json").write_text('{"a": 1}')
    (tmp_path / "notes.txt").write_text("x")
    (tmp_path / "v.md").write_text("# GeoCon validation report\n\nrows")
    (tmp_path / "n.md").write_text("# My notes\n")
    png = cv2.imencode(".png", np.zeros((4, 4), np.uint8))[1].tobytes()
    (tmp_path / "user.png").write_bytes(png)
    (tmp_path / "ours.png").write_bytes(stamp_png(png))
    (tmp_path / "ours.rrd").write_bytes(b"RRF2\x00)\x00\x00" + b"\x1a\x08\n\x06geocon" + b"\x00" * 32)
    (tmp_path / "theirs.rrd").write_bytes(b"RRF2\x00)\x00\x00" + b"\x1a\x08\n\x06others" + b"\x00" * 32)
    kinds = {n: (h.kind, h.geocon) for n in os.listdir(tmp_path) if (h := held(tmp_path / n))}
    assert kinds == {
        "p.json": ("json", True), "mine.json": ("json", False), "notes.txt": ("file", False),
        "v.md": ("markdown", True), "n.md": ("markdown", False), "user.png": ("png", False),
        "ours.png": ("png", True), "ours.rrd": ("recording", True), "theirs.rrd": ("recording", False),
    }  # fmt: skip
    assert held(tmp_path / "p.json").format == "geocon-pose/1"
    assert held(tmp_path / "missing").kind == "nothing"
    assert cv2.imdecode(np.frombuffer(stamp_png(png), np.uint8), cv2.IMREAD_UNCHANGED).shape == (4, 4)
    assert stamp_png(stamp_png(png)) == stamp_png(png)


def test_geocon_folders_are_told_by_their_markers(tmp_path: Path):
    _record_folder(tmp_path / "rec")
    (tmp_path / "res" / "clips").mkdir(parents=True)
    (tmp_path / "res" / "bench.json").write_text("{}")
    (tmp_path / "rep").mkdir()
    (tmp_path / "rep" / "report.html").write_text("<html><head><title>GeoCon benchmark report</title>")
    (tmp_path / "fake").mkdir()
    (tmp_path / "fake" / "report.html").write_text("<html>mine</html>")
    (tmp_path / "val" / "cases" / "c1").mkdir(parents=True)
    (tmp_path / "val" / "cases" / "c1" / "case.json").write_text("{}")
    got = {n: folder_kind(tmp_path / n) for n in ("rec", "res", "rep", "fake", "val", "missing")}
    assert got == {"rec": "record", "res": "results", "rep": "report", "fake": None, "val": "validation",
                   "missing": None}  # fmt: skip
    assert set(FOLDER_KINDS) == {"record", "results", "report", "validation"}


def test_claim_refuses_the_parts_of_another_output_and_lets_the_owner_in(tmp_path: Path):
    rec = _record_folder(tmp_path / "rec")
    for inside in (rec / "record.json", rec / "overlays" / "x.png", rec / "audit.rrd"):
        with pytest.raises(OutPathError, match="of rec|GeoCon never writes over"):
            claim("--rrd", inside, "recording")
    claim("--rrd", rec / "notes.rrd", "recording")  # a new file beside the parts is no part
    claim("--save", rec / "audit.rrd", "recording", own=[rec])  # the record's own recording, re-rendered
    (tmp_path / "res" / "clips").mkdir(parents=True)
    (tmp_path / "res" / "bench.json").write_text("{}")
    bench_record = _record_folder(tmp_path / "res" / "clips" / "a")
    claim("--save", bench_record / "audit.rrd", "recording", own=[bench_record])
    with pytest.raises(OutPathError, match="audit.rrd of"):
        claim("--rrd", bench_record / "audit.rrd", "recording", own=[rec])
    with pytest.raises(OutPathError, match="clips of"):
        claim("--rrd", bench_record / "new.rrd", "recording", own=[rec])


def test_claim_replaces_only_its_own_kind_for_the_same_input(tmp_path: Path):
    rec = _record_folder(tmp_path / "rec")
    with pytest.raises(OutPathError, match="holds the record of a.mp4"):
        claim("--out", rec, "record", mine=lambda _h: "the record of a.mp4, not of b.mp4")
    claim("--out", rec, "record", mine=lambda _h: None)
    with pytest.raises(OutPathError, match="it holds record.json"):
        claim("--out", rec, "results")
    (tmp_path / "mine" / "clips").mkdir(parents=True)
    with pytest.raises(OutPathError, match="holds clips"):
        claim("--out", tmp_path / "mine", "results")
    (tmp_path / "p.json").write_text(json.dumps({"format": "geocon-synth-gt/1"}))
    with pytest.raises(OutPathError, match="synthetic clip"):
        claim("--out", tmp_path / "p.json", "json:geocon-pose")
    (tmp_path / "p.json").write_text(json.dumps({"format": "geocon-pose/1"}))
    claim("--out", tmp_path / "p.json", "json:geocon-pose")


def test_commit_together_puts_everything_back_when_a_rename_fails(tmp_path: Path, monkeypatch):
    targets = [tmp_path / n for n in ("a.mp4", "a.gt.json", "a.meta.json")]
    targets[0].write_text("old a")
    targets[2].write_text("old meta")
    before = snapshot(tmp_path)
    parts = []
    for t in targets:
        parts.append(t.with_name(f".{t.name}.part"))
        parts[-1].write_text(f"new {t.name}")
    real = os.rename
    calls = []

    def flaky(src, dst):
        calls.append(dst)
        if len(calls) == 4:  # a.mp4 aside, into place; a.gt.json into place; then the meta's aside fails
            raise OSError(28, "No space left on device")
        real(src, dst)

    monkeypatch.setattr("geocon_core.files.commit.os.rename", flaky)
    with pytest.raises(OSError):
        commit_together(list(zip(parts, targets, strict=True)))
    monkeypatch.undo()
    assert snapshot(tmp_path) == before  # the parts are gone too
    for p, t in zip(parts, targets, strict=True):
        p.write_text(f"new {t.name}")
    commit_together(list(zip(parts, targets, strict=True)))
    assert [t.read_text() for t in targets] == ["new a.mp4", "new a.gt.json", "new a.meta.json"]
    assert sorted(os.listdir(tmp_path)) == ["a.gt.json", "a.meta.json", "a.mp4"]


def test_check_targets_refuses_a_folder_where_a_file_goes_and_two_outputs_on_one_path(tmp_path: Path):
    (tmp_path / "twin.mp4").mkdir()
    with pytest.raises(OutPathError, match="is a folder"):
        check_targets([(tmp_path / "a.gt.json", False), (tmp_path / "twin.mp4", False)])
    with pytest.raises(OutPathError, match="twice"):
        check_targets([(tmp_path / "x", False), (tmp_path / "x", False)])
    check_targets([(tmp_path / "twin.mp4", True)])


@pytest.mark.full
def test_a_plant_that_fails_midway_through_its_commit_leaves_the_folder_as_it_was(tmp_path, assets, monkeypatch):  # noqa: F811
    from geocon_core.plant import plant_clip

    shutil.copyfile(assets.pan, tmp_path / "a.mp4")
    plant_clip(tmp_path / "a.mp4", "morph", "low", 0, tmp_path / "pl")
    before = snapshot(tmp_path)
    real = os.rename
    calls = []

    def flaky(src, dst):
        calls.append(dst)
        if len(calls) == 5:
            raise OSError(28, "No space left on device")
        real(src, dst)

    monkeypatch.setattr("geocon_core.files.commit.os.rename", flaky)
    with pytest.raises(OSError):
        plant_clip(tmp_path / "a.mp4", "morph", "low", 1, tmp_path / "pl")
    assert calls[4] == tmp_path / "pl" / "a.clean.mp4"  # three new files placed, the twin set aside: then it failed
    assert snapshot(tmp_path) == before


def test_the_rules_table_names_what_each_owner_writes():
    """The folder kinds and formats the rule knows are those their writers use (one name each)."""
    from geocon_core import plant, pose, synth
    from geocon_core.bench import layout
    from geocon_core.files import FORMATS, PROTECTED_PARTS
    from geocon_core.record.clip import RECORD_FORMAT
    from geocon_core.record.overlays import OVERLAYS_FORMAT
    from geocon_core.signals.model import MODEL_FORMAT
    from geocon_core.validation.report import REPORT_JSON, REPORT_MD
    from geocon_core.validation.runner import CASES_DIR

    record, results = FOLDER_KINDS["record"], FOLDER_KINDS["results"]
    assert record.marker == layout.RECORD_NAME and set(PROTECTED_PARTS) | {layout.RRD_NAME} == set(record.parts)
    assert results.marker == layout.MANIFEST_NAME
    assert {layout.LOCK_NAME, layout.CLIPS_DIR, layout.TABLES_DIR} <= set(results.parts)
    assert {REPORT_MD, REPORT_JSON, CASES_DIR} <= set(FOLDER_KINDS["validation"].parts)
    formats = (RECORD_FORMAT, OVERLAYS_FORMAT, layout.BENCH_FORMAT, layout.STATUS_FORMAT, pose.POSE_LOG_FORMAT,
               synth.truth.GT_FORMAT, plant.PLANT_FORMAT, MODEL_FORMAT, "geocon-validation/1")  # fmt: skip
    assert {f.split("/")[0] for f in formats} == set(FORMATS)


def test_a_screenshot_is_saved_as_geocons_so_the_next_one_may_replace_it(tmp_path: Path):
    from geocon_viewer.capture.chromium import save_png

    png = cv2.imencode(".png", np.full((6, 8, 3), 40, np.uint8))[1].tobytes()
    (tmp_path / "photo.png").write_bytes(png)
    with pytest.raises(OutPathError, match="PNG image GeoCon did not make"):
        claim("--screenshot", tmp_path / "photo.png", "png")
    save_png(png, tmp_path / "shot.png")
    claim("--screenshot", tmp_path / "shot.png", "png")  # its own earlier screenshot
    save_png(png, tmp_path / "shot.png")
    assert held(tmp_path / "shot.png").geocon and sorted(os.listdir(tmp_path)) == ["photo.png", "shot.png"]
