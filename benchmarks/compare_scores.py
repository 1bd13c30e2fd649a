"""Scores unchanged? Score the same clips with the code at two git refs and compare every headline number.

    python benchmarks/compare_scores.py --before REF [--after REF|worktree] [--clips PATTERN ...]
        [--out DIR] [--max-frames N] [--cache DIR] [--jobs 2] [--preset paper]

Clips: the synthetic families C1..C6 (clean), C2 with breathing (also scored with the ``strict``
preset), C4 with an elastic object, C4 with its external masks, and every video in
``../shared/data`` (``.mp4``, ``.gif``, ``.avi``). Synthetic clips are rendered once by the BEFORE
code (small: 320x180, 24 frames) and both sides score the very same files. Clips longer than
``--max-frames`` are scored as a folder of their first N decoded frames (PNG, lossless), again the
same input for both sides.

Each side runs in its own Python subprocess with ``PYTHONPATH`` pointing at that code: a ref is
exported with ``git archive`` into a temporary folder, ``worktree`` is this checkout as it is on
disk. Scoring goes through the public API of each version (``geocon_core.score_clip`` where it
exists, else ``geocon_core.scorer.score_clip`` of older versions) and the record is written with ``write_record``.
The comparison reads ``record.json`` generically: background IR, GE and model; gate t_inf, label,
model and pose presence; category; per-object AdaDFRC and AdaP90 (every object); the per-frame
masked share. A table per clip says IDENTICAL or DIFFERENT for each field; the exit status is 1 if
anything differs or a clip failed on one side only.

BEFORE records are cached under ``--cache`` by commit hash and input content, so re-running the
comparison only scores the AFTER side (always scored afresh, also when it is a ref: comparing a ref
with itself checks that scoring is reproducible across processes).
"""

from __future__ import annotations

import argparse
import fnmatch
import hashlib
import json
import math
import os
import shutil
import subprocess
import sys
import tarfile
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
VIDEO_SUFFIXES = (".mp4", ".gif", ".avi")
SYNTH_SIZE = (320, 180)
SYNTH_FRAMES = 24
SYNTH_SEED = 7
# (name, family, failure, severity)
SYNTH_PLANS: tuple[tuple[str, str, str | None, float | None], ...] = (
    ("C1", "C1", None, None),
    ("C2", "C2", None, None),
    ("C3", "C3", None, None),
    ("C4", "C4", None, None),
    ("C5", "C5", None, None),
    ("C6", "C6", None, None),
    ("C2_breathing", "C2", "breathing", 3.0),
    ("C4_elastic", "C4", "elastic", 3.0),
)

# The scoring worker runs inside the code under test; it only uses names that are public at
# every version it may meet, trying the newer location first.
_WORKER = r"""
import importlib, json, sys
from pathlib import Path

def first(*candidates):
    for module, name in candidates:
        try:
            value = getattr(importlib.import_module(module), name, None)
        except ImportError:
            continue
        if value is not None:
            return value
    raise SystemExit(f"none of {candidates} exists in this version")

import geocon_core
task = json.loads(sys.argv[1])
print(json.dumps({"geocon_core": geocon_core.__file__}), flush=True)
if task["kind"] == "render":
    plan_cls = first(("geocon_core.synth", "ClipPlan"))
    write_clip = first(("geocon_core.synth", "write_clip"))
    gt = write_clip(plan_cls(task["family"], task["failure"], task["severity"]), task["out"], seed=task["seed"],
                    width=task["width"], height=task["height"], num_frames=task["frames"])
    print(json.dumps({"video": gt.video_path, "masks": gt.masks_path}))
else:
    score_clip = first(("geocon_core", "score_clip"), ("geocon_core.scorer", "score_clip"))
    preset = first(("geocon_core", "preset"), ("geocon_core.config", "preset"))
    write_record = first(("geocon_core", "write_record"), ("geocon_core.record", "write_record"))
    kwargs = {"masks": task["masks"]} if task["masks"] else {}
    record = score_clip(task["clip"], preset(task["preset"]), **kwargs)
    write_record(record, task["out"])
"""


@dataclass(frozen=True)
class Job:
    """One clip to score on both sides."""

    name: str
    clip: Path
    preset: str = "paper"
    masks: Path | None = None

    def key(self, max_frames: int | None) -> str:
        h = hashlib.sha256()
        h.update(f"{self.preset}|{max_frames}|".encode())
        for path in (self.clip, self.masks):
            h.update(content_hash(path).encode() if path else b"-")
        return h.hexdigest()[:16]


def content_hash(path: Path) -> str:
    """SHA-256 of a file, or of a folder's files (names and bytes, in sorted order)."""
    h = hashlib.sha256()
    files = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
    for f in files:
        h.update(str(f.relative_to(path)).encode() if path.is_dir() else b"")
        h.update(f.read_bytes())
    return h.hexdigest()


def git(*args: str) -> str:
    return subprocess.run(["git", "-C", str(ROOT), *args], check=True, capture_output=True, text=True).stdout.strip()


def export_ref(ref: str, dest: Path) -> Path:
    """The tree of commit ``ref`` written into ``dest`` (``git archive``; the repository is not touched)."""
    dest.mkdir(parents=True)
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", ref], check=True, capture_output=True).stdout
    tar_path = dest.with_suffix(".tar")
    tar_path.write_bytes(archive)
    with tarfile.open(tar_path) as tar:
        tar.extractall(dest, filter="data")
    tar_path.unlink()
    return dest


def run_worker(tree: Path, task: dict[str, Any]) -> str:
    """Run the worker with ``tree`` first on the path; returns its stdout, raises on failure."""
    env = dict(os.environ, PYTHONPATH=str(tree), PYTHONHASHSEED="0")
    proc = subprocess.run(
        [sys.executable, "-c", _WORKER, json.dumps(task)], cwd=tree, env=env, capture_output=True, text=True
    )
    if proc.returncode != 0:
        raise RuntimeError(proc.stderr.strip().splitlines()[-1] if proc.stderr.strip() else f"exit {proc.returncode}")
    loaded = Path(json.loads(proc.stdout.splitlines()[0])["geocon_core"]).resolve()
    if not loaded.is_relative_to(tree.resolve()):
        raise RuntimeError(f"worker imported {loaded}, not the code in {tree}")
    return proc.stdout


def render_synthetic(tree: Path, commit: str, cache: Path) -> list[Job]:
    """Render the synthetic clips with the code in ``tree`` (cached per commit)."""
    w, h = SYNTH_SIZE
    folder = cache / "inputs" / f"synth-{commit[:12]}-{w}x{h}-{SYNTH_FRAMES}-s{SYNTH_SEED}"
    jobs = []
    for name, family, failure, severity in SYNTH_PLANS:
        out = folder / name
        done = out / "done.json"
        if not done.exists():
            shutil.rmtree(out, ignore_errors=True)
            task = dict(kind="render", family=family, failure=failure, severity=severity, out=str(out), seed=SYNTH_SEED)
            task.update(width=w, height=h, frames=SYNTH_FRAMES)
            written = json.loads(run_worker(tree, task).splitlines()[-1])
            done.write_text(json.dumps(written))
        written = json.loads(done.read_text())
        clip = out / written["video"]
        jobs.append(Job(f"synth/{name}", clip))
        if name == "C2_breathing":
            jobs.append(Job(f"synth/{name}[strict]", clip, preset="strict"))
        if name == "C4" and written.get("masks"):
            jobs.append(Job(f"synth/{name}[external masks]", clip, masks=out / written["masks"]))
    return jobs


def real_jobs(data: Path) -> list[Job]:
    """Every video under ``data`` (sorted)."""
    clips = sorted(p for p in data.rglob("*") if p.suffix.lower() in VIDEO_SUFFIXES and p.is_file())
    return [Job(str(p.relative_to(data)), p) for p in clips]


def cap_frames(job: Job, max_frames: int, cache: Path) -> Job:
    """``job`` with a clip longer than ``max_frames`` replaced by a PNG folder of its first frames."""
    import cv2

    folder = cache / "inputs" / f"capped-{content_hash(job.clip)[:16]}-{max_frames}"
    if not (folder / "done").exists():
        shutil.rmtree(folder, ignore_errors=True)
        cap = cv2.VideoCapture(str(job.clip))
        frames = []
        ok, frame = cap.read()
        while ok and len(frames) <= max_frames:
            frames.append(frame)
            ok, frame = cap.read()
        cap.release()
        if len(frames) <= max_frames:
            return job
        folder.mkdir(parents=True)
        for i, frame in enumerate(frames[:max_frames]):
            cv2.imwrite(str(folder / f"frame_{i:05d}.png"), frame)
        (folder / "done").touch()
    frame_dir = folder
    return Job(job.name + f"[first {max_frames} frames]", frame_dir, job.preset, job.masks)


def score(tree: Path, job: Job, dest: Path) -> str | None:
    """Score ``job`` with the code in ``tree`` and keep its ``record.json`` at ``dest``; returns an error."""
    with tempfile.TemporaryDirectory(prefix="geocon-compare-") as tmp:
        task = dict(kind="score", clip=str(job.clip), preset=job.preset, out=tmp)
        task["masks"] = str(job.masks) if job.masks else None
        try:
            run_worker(tree, task)
        except RuntimeError as err:
            dest.parent.mkdir(parents=True, exist_ok=True)
            dest.with_suffix(".error").write_text(str(err))
            return str(err)
        dest.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(Path(tmp) / "record.json", dest)
        dest.with_suffix(".error").unlink(missing_ok=True)
    return None


# ---- reading records generically ------------------------------------------------------------------------------------


def lookup(d: Any, *paths: str) -> Any:
    """The value at the first dotted path that exists in ``d`` (``None`` if none does)."""
    for path in paths:
        node = d
        for part in path.split("."):
            if isinstance(node, dict) and part in node:
                node = node[part]
            else:
                break
        else:
            return node
    return None


def headline(record: dict[str, Any]) -> dict[str, Any]:
    """The compared fields of a parsed ``record.json``, whatever its exact layout."""
    category = lookup(record, "category.label", "category", "summary.category")
    out: dict[str, Any] = {
        "IR": lookup(record, "background.ir", "summary.background.ir"),
        "GE": lookup(record, "background.ge", "summary.background.ge"),
        "background model": lookup(record, "background.model", "summary.background.model"),
        "t_inf": lookup(record, "gate.t_inf", "summary.gate.t_inf"),
        "gate label": lookup(record, "gate.label", "summary.gate.label"),
        "gate model": lookup(record, "gate.model", "summary.gate.model"),
        "pose present": lookup(record, "gate.pose_present", "summary.gate.pose_present"),
        "category": category.get("label") if isinstance(category, dict) else category,
    }
    objects = lookup(record, "objects", "summary.objects") or []
    out["objects"] = [lookup(o, "object_id", "id") for o in objects]
    for o in objects:
        oid = lookup(o, "object_id", "id")
        out[f"object {oid} AdaDFRC"] = o.get("adadfrc")
        out[f"object {oid} AdaP90"] = o.get("adap90")
    out["masked share"] = lookup(record, "masked_share", "masks.masked_share")
    return out


def same(a: Any, b: Any) -> bool:
    """Exact equality, NaN equal to NaN, lists element by element."""
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return type(a) is type(b) and a == b


def show(value: Any) -> str:
    if isinstance(value, list) and value and all(isinstance(v, float) for v in value):
        finite = [v for v in value if not math.isnan(v)]
        mean = sum(finite) / len(finite) if finite else float("nan")
        return f"{len(value)} frames, mean {mean:.6g}"
    return repr(value)


def compare(name: str, before: Path, after: Path) -> bool:
    """Print the table of one clip; True when every field is identical."""
    print(f"\n== {name}")
    errors = [p.with_suffix(".error") for p in (before, after)]
    if any(e.exists() for e in errors):
        texts = [e.read_text() if e.exists() else "ok" for e in errors]
        status = "IDENTICAL" if texts[0] == texts[1] else "DIFFERENT"
        print(f"  {'error':<22} {texts[0][:45]:<48} {texts[1][:45]:<48} {status}")
        return status == "IDENTICAL"
    a = headline(json.loads(before.read_text()))
    b = headline(json.loads(after.read_text()))
    ok = True
    for field in list(a) + [f for f in b if f not in a]:
        x, y = a.get(field), b.get(field)
        status = "IDENTICAL" if same(x, y) else "DIFFERENT"
        ok &= status == "IDENTICAL"
        print(f"  {field:<22} {show(x)[:46]:<48} {show(y)[:46]:<48} {status}")
    return ok


# ---- main -----------------------------------------------------------------------------------------------------------


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--before", required=True, help="git ref of the reference code")
    p.add_argument("--after", default="worktree", help="git ref, or 'worktree' for this checkout on disk (default)")
    p.add_argument("--clips", nargs="*", default=None, help="only clips whose name matches one of these globs")
    p.add_argument("--out", type=Path, default=None, help="keep the records here (default: a temporary folder)")
    p.add_argument("--max-frames", type=int, default=48, help="score at most this many frames per clip (0: all)")
    p.add_argument("--cache", type=Path, default=Path.home() / ".cache" / "geocon" / "compare_scores")
    p.add_argument("--data", type=Path, default=DATA, help="real clips (default: ../shared/data)")
    p.add_argument("--jobs", type=int, default=2, help="clips scored at once")
    p.add_argument("--preset", default="paper", help="the preset every clip is scored with (default: paper)")
    return p.parse_args(argv)


def resolve(ref: str) -> str:
    return git("rev-parse", "--verify", f"{ref}^{{commit}}")


def select_jobs(args: argparse.Namespace, before_tree: Path, before_commit: str, cache: Path) -> list[Job]:
    """The clips ``args`` asks for, with the preset and frame cap it gives."""
    jobs = render_synthetic(before_tree, before_commit, cache) + real_jobs(args.data)
    if args.clips:
        jobs = [j for j in jobs if any(fnmatch.fnmatch(j.name, pat) for pat in args.clips)]
    if args.preset != "paper":
        jobs = [replace(j, preset=args.preset) if j.preset == "paper" else j for j in jobs]
    if args.max_frames:
        jobs = [cap_frames(j, args.max_frames, cache) for j in jobs]
    return jobs


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    started = time.monotonic()
    before_commit = resolve(args.before)
    after_commit = None if args.after == "worktree" else resolve(args.after)
    cache = args.cache.resolve()
    with tempfile.TemporaryDirectory(prefix="geocon-compare-") as tmp_str:
        tmp = Path(tmp_str)
        before_tree = export_ref(before_commit, tmp / "before")
        after_tree = ROOT if after_commit is None else export_ref(after_commit, tmp / "after")
        out = args.out.resolve() if args.out else tmp / "records"

        jobs = select_jobs(args, before_tree, before_commit, cache)
        if not jobs:
            print("no clips selected", file=sys.stderr)
            return 2

        def before_path(job: Job) -> Path:
            return cache / "records" / before_commit / f"{job.key(args.max_frames)}.json"

        def after_path(job: Job) -> Path:
            return out / "after" / (job.name.replace("/", "__") + ".json")

        pending = [(before_tree, j, before_path(j)) for j in jobs if not before_path(j).exists()]
        pending += [(after_tree, j, after_path(j)) for j in jobs]
        pending.sort(key=lambda t: -_size(t[1].clip))
        after_name = after_commit[:12] if after_commit else "worktree"
        print(
            f"before {before_commit[:12]} (cached in {cache}), after {after_name}: "
            f"{len(jobs)} clips, {len(pending)} scoring runs",
            flush=True,
        )

        def run(item: tuple[Path, Job, Path]) -> None:
            tree, job, dest = item
            t0 = time.monotonic()
            err = score(tree, job, dest)
            side = "before" if tree == before_tree else "after"
            note = f" FAILED: {err}" if err else ""
            print(f"  {side:<6} {job.name}: {time.monotonic() - t0:.1f} s{note}", flush=True)

        pool = ThreadPoolExecutor(max_workers=args.jobs)
        try:
            list(pool.map(run, pending))
        except KeyboardInterrupt:  # compare what has finished
            print("interrupted: comparing the clips scored on both sides so far", flush=True)
            pool.shutdown(wait=False, cancel_futures=True)
        else:
            pool.shutdown()

        def scored(path: Path) -> bool:
            return path.exists() or path.with_suffix(".error").exists()

        results = {
            job.name: compare(job.name, before_path(job), after_path(job)) if scored(after_path(job)) else False
            for job in jobs
            if scored(before_path(job))
        }
        missing = [job.name for job in jobs if job.name not in results or not scored(after_path(job))]
        for job in jobs:  # the BEFORE records next to the AFTER ones, under readable names
            src = before_path(job)
            for path in (src, src.with_suffix(".error")):
                if path.exists():
                    target = out / "before" / (job.name.replace("/", "__") + path.suffix)
                    target.parent.mkdir(parents=True, exist_ok=True)
                    shutil.copyfile(path, target)
    differing = [name for name, ok in results.items() if not ok and name not in missing]
    print(f"\n{sum(results.values())}/{len(jobs)} clips IDENTICAL in every field ({time.monotonic() - started:.0f} s)")
    for name in differing:
        print(f"  DIFFERENT: {name}")
    for name in missing:
        print(f"  NOT SCORED on both sides: {name}")
    return 1 if differing or missing else 0


def _size(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*")) if path.is_dir() else path.stat().st_size


if __name__ == "__main__":
    sys.exit(main())
