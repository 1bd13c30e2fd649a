"""Scoring speed on real footage: frames per second per clip, clips per minute and seconds per
stage, for the current code and, with ``--before REV``, for an earlier commit in the same run.

    .venv/bin/python benchmarks/bench_real.py                         # audit, the fixed set
    .venv/bin/python benchmarks/bench_real.py --before a6e86d6        # ... and that commit beside it
    .venv/bin/python benchmarks/bench_real.py --preset paper --frames 48 --json out.json

The fixed set (:data:`REAL_SET`) is real-camera footage of several sizes: two RealEstate10K
walk-throughs (384x256, 576x320), the SAM-2 demo clips (1280x720, a still camera with movers),
the 1280x720 ``evadb_yoga`` and the 1920x1080 ``mmaction2_two_people_room`` of ``real2``, and the
1920x1080 drone clip and the 640x360 crossing of the footage cache (``geocon validate
--footage``; skipped, and said, where the cache has not been fetched). Each clip is cut once to
its first ``--frames`` frames as PNG files (lossless: every run reads the same pixels) under the
temporary folder, then scored in a fresh process per clip and per code version, the versions
taking turns clip by clip, so that a busy moment of the machine hits both alike. The earlier
commit is checked out in a temporary git worktree and imported from there with the same
interpreter and packages.

Printed: per clip and version the canvas, wall time, frames/s, peak memory and seconds per stage
(summed over the scorer's threads, so they can exceed the wall time), then per version the clips
per minute over the set, the frames/s of the full-HD sources (one worker: each clip is scored in
a process of its own), the frames/s by working canvas, the peak memory over the set, and the
speed-up. Each child sets the allocator as the command line does (where its version has
:func:`geocon_core.files.tune_allocator`), so peak memory is that of ``geocon score``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"
FOOTAGE = Path(os.environ.get("GEOCON_FOOTAGE", Path.home() / ".cache" / "geocon" / "footage"))
CACHE = Path(tempfile.gettempdir()) / "geocon-bench-real"

REAL_SET: tuple[tuple[str, Path], ...] = (
    ("re10k_0c9b371cc6225682", SHARED / "data/real/realestate10k/0c9b371cc6225682.mp4"),
    ("re10k_0f47577ab3441480", SHARED / "data/real/realestate10k/0f47577ab3441480.mp4"),
    ("sam2_blocks", SHARED / "data/real/sam2/blocks.mp4"),
    ("sam2_dog", SHARED / "data/real/sam2/dog.mp4"),
    ("real2_evadb_yoga", SHARED / "real2/evadb_yoga.mp4"),
    ("real2_mmaction2_two_people_room", SHARED / "real2/mmaction2_two_people_room.mp4"),
    ("footage_videoonmap_drone_intersection", FOOTAGE / "real/videoonmap_drone_intersection.mp4"),
    ("footage_intel_hallway_walkers", FOOTAGE / "real/intel_hallway_walkers.gif"),
)
"""(name, source) of the fixed real-footage set."""

CHILD = r"""
import json, resource, sys, time
from geocon_core import preset, score_clip  # the public API, the same in every version
try:  # the allocator the command line sets (a version without it runs as its command line did)
    from geocon_core.files import tune_allocator
    tune_allocator()
except ImportError:
    pass
path, name = sys.argv[1], sys.argv[2]
timings = {}
start = time.perf_counter()
record = score_clip(path, preset(name), timings=timings)
wall = time.perf_counter() - start
n = record.video.num_frames
print(json.dumps({
    "frames": n, "size": list(record.video.working_size), "source": list(record.video.source_size),
    "wall_s": round(wall, 2), "fps": round(n / wall, 3),
    "peak_rss_mib": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
    "stages_s": {k: round(v, 2) for k, v in sorted(timings.items())},
    "consistent": record.background.consistent, "ir": record.background.ir, "ge": record.background.ge,
    "objects": len(record.objects),
}))
"""


def cut(name: str, src: Path, frames: int) -> Path | None:
    """The folder of the first ``frames`` frames of ``src`` as PNG files (made once), or None
    when ``src`` is missing."""
    import cv2

    if not src.is_file():
        return None
    folder = CACHE / f"{name}-{frames}"
    done = folder / ".done"
    if done.is_file():
        return folder
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True)
    cap = cv2.VideoCapture(str(src))
    kept = 0
    try:
        while kept < frames:
            ok, bgr = cap.read()
            if not ok:
                break
            if not cv2.imwrite(str(folder / f"{kept:05d}.png"), bgr):
                raise OSError(f"could not write a frame of {src} into {folder}")
            kept += 1
    finally:
        cap.release()
    if kept < 2:
        raise ValueError(f"{src}: fewer than two frames could be decoded")
    done.write_text(str(kept))
    return folder


def worktree(rev: str, where: Path) -> Path:
    """A checkout of ``rev`` in a temporary git worktree under ``where``."""
    path = where / f"before-{rev}"
    subprocess.run(["git", "-C", str(ROOT), "worktree", "prune"], check=True)  # those of an interrupted run
    subprocess.run(
        ["git", "-C", str(ROOT), "worktree", "add", "--detach", str(path), rev], check=True, capture_output=True
    )
    return path


def score(code: Path, clip: Path, preset_name: str) -> dict:
    """One clip scored in a fresh process importing the package from ``code``."""
    env = {**os.environ, "PYTHONPATH": str(code)}
    done = subprocess.run(
        [sys.executable, "-c", CHILD, str(clip), preset_name], cwd=code, env=env, capture_output=True, text=True
    )
    if done.returncode:
        raise RuntimeError(f"scoring {clip} with the code in {code} failed:\n{done.stderr[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--preset", default="audit")
    ap.add_argument("--frames", type=int, default=60, help="each clip cut to its first N frames")
    ap.add_argument("--before", default=None, help="an earlier commit, scored beside the current code")
    ap.add_argument("--clips", default=None, help="comma-separated names of REAL_SET to keep")
    ap.add_argument("--json", type=Path, default=None, help="also write every run here")
    args = ap.parse_args()
    chosen = set(args.clips.split(",")) if args.clips else None
    clips = []
    for name, src in REAL_SET:
        if chosen is not None and name not in chosen:
            continue
        folder = cut(name, src, args.frames)
        if folder is None:
            print(f"{name}: {src} is missing, skipped (the footage cache: `geocon validate --footage`)")
        else:
            clips.append((name, folder))
    if not clips:
        raise SystemExit("no clip of the fixed set was found")
    with tempfile.TemporaryDirectory() as tmp:
        versions = {"now": ROOT}
        if args.before:
            versions = {args.before: worktree(args.before, Path(tmp)), "now": ROOT}
        runs: dict[str, dict[str, dict]] = {v: {} for v in versions}
        try:
            for name, folder in clips:
                for version, code in versions.items():
                    r = runs[version][name] = score(code, folder, args.preset)
                    stages = "  ".join(f"{k} {v:.1f}" for k, v in sorted(r["stages_s"].items(), key=lambda kv: -kv[1]))
                    w, h = r["size"]
                    print(
                        f"{name:40} {version:>8} {w}x{h} {r['frames']:4d} frames {r['wall_s']:7.1f} s "
                        f"{r['fps']:5.2f} frames/s  RSS {r['peak_rss_mib']:6.0f} MiB  | {stages}",
                        flush=True,
                    )
        finally:
            if args.before:
                subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(versions[args.before])])
    print()
    rates = {}
    for version, by_clip in runs.items():
        wall = sum(r["wall_s"] for r in by_clip.values())
        fhd = [r for r in by_clip.values() if max(r.get("source", r["size"])) >= 1920]
        fhd_fps = sum(r["frames"] for r in fhd) / sum(r["wall_s"] for r in fhd) if fhd else float("nan")
        rates[version] = len(by_clip) / wall * 60
        canvases: dict[str, list[dict]] = {}
        for r in by_clip.values():
            canvases.setdefault("x".join(map(str, r["size"])), []).append(r)
        by_canvas = "; ".join(
            f"{c} {sum(r['frames'] for r in rs) / sum(r['wall_s'] for r in rs):.2f}"
            for c, rs in sorted(canvases.items(), key=lambda kv: -kv[1][0]["size"][0] * kv[1][0]["size"][1])
        )
        peak = max(r["peak_rss_mib"] for r in by_clip.values())
        stage_sum: dict[str, float] = {}
        for r in by_clip.values():
            for k, v in r["stages_s"].items():
                stage_sum[k] = stage_sum.get(k, 0.0) + v
        print(
            f"{version:>8}: {len(by_clip)} clips in {wall:.0f} s = {rates[version]:.2f} clips/min; "
            f"full-HD sources {fhd_fps:.2f} frames/s per worker; peak RSS {peak:.0f} MiB\n"
            f"          frames/s per worker by canvas: {by_canvas}\n"
            "          stages (s, summed over threads): "
            + ", ".join(f"{k} {v:.0f}" for k, v in sorted(stage_sum.items(), key=lambda kv: -kv[1]))
        )
    if args.before:
        print(
            f"speed-up: {rates['now'] / rates[args.before]:.2f}x clips/min ({args.preset}, {args.frames} frames a clip)"
        )
    if args.json:
        args.json.write_text(json.dumps({"preset": args.preset, "frames": args.frames, "runs": runs}, indent=1))


if __name__ == "__main__":
    main()
