"""Scoring speed and memory on synthetic clips.

    .venv/bin/python benchmarks/bench_score.py [--frames 120] [--size 1024x720] [--preset paper]
    .venv/bin/python benchmarks/bench_score.py --preset fast --repeats 5  # best of 5 runs
    .venv/bin/python benchmarks/bench_score.py --memory      # 120 vs 480 frames
    .venv/bin/python benchmarks/bench_score.py --matcher klt # another matcher than the preset's
    .venv/bin/python benchmarks/bench_score.py --rrd         # cost and size of the Rerun recording
    .venv/bin/python benchmarks/bench_score.py --rrd --family C3  # ... of a translation clip
    .venv/bin/python benchmarks/bench_score.py --multiview-cost --family C3  # audit with / without the check

Renders a C4 clip (static camera, two moving objects) once into a cache folder, then scores
it in a fresh process per measurement, without and with mask-first separation (built-in
motion segmentation, flow and AdaDFRC-W2), and prints frames per second end to end, the CPU
utilisation of the scoring ((user + system CPU time) / (wall time x cores)), seconds per stage
(summed over the worker threads, so they can exceed the wall time) and the peak resident
memory. With ``--rrd`` it scores the clip (paper preset, motion masks) without and with
the Rerun recording streamed while scoring (with the dense point clouds, as ``geocon score --rrd``
makes them), and prints the recording's size and the time it adds; ``--family`` picks another
synthetic family (C3: a translating camera, whose dense clouds are not empty).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CACHE = Path(tempfile.gettempdir()) / "geocon-bench"


def clip(frames: int, size: str, family: str = "C4") -> Path:
    """The rendered clip of ``family`` (its ``.gt.json`` beside it), cached under the temp folder."""
    from geocon_core.synth import ClipPlan, load_ground_truth, write_clip

    w, h = (int(v) for v in size.split("x"))
    folder = CACHE / (f"{size}-{frames}" if family == "C4" else f"{family}-{size}-{frames}")
    gts = sorted(folder.glob("*.gt.json"))
    if not gts:
        write_clip(ClipPlan(family), folder, width=w, height=h, num_frames=frames)
        gts = sorted(folder.glob("*.gt.json"))
    return folder / load_ground_truth(gts[0]).video_path


def measure(path: Path, preset_name: str, masks: str, matcher: str, rrd: str = "-") -> dict:
    from geocon_core.config import preset
    from geocon_core.files import tune_allocator
    from geocon_core.scoring import score_clip

    tune_allocator()  # as the command line does: its peak memory is what a user sees

    timings: dict[str, float] = {}
    sink = None
    if rrd != "-":
        from geocon_viewer.rerun.log import RrdSink

        sink = RrdSink(rrd)
    u0 = resource.getrusage(resource.RUSAGE_SELF)
    t0 = time.perf_counter()
    base, _, variant = preset_name.partition(":")
    cfg = preset(base).with_(masks=masks)
    if variant == "no-multiview":  # the preset without the multi-view check (its cost)
        from geocon_core.config import MultiViewConfig

        cfg = cfg.with_(multiview=MultiViewConfig())
    if matcher != "-":
        cfg = cfg.with_(matcher=matcher)
    dense = None
    if sink is not None:
        from geocon_core.reconstruction import DenseCloudConfig

        dense = DenseCloudConfig()
    record = score_clip(path, cfg, timings=timings, on_frame=sink, dense=dense)
    if sink is not None:
        sink.finish(record)
    wall = time.perf_counter() - t0
    u1 = resource.getrusage(resource.RUSAGE_SELF)
    cpu = (u1.ru_utime - u0.ru_utime) + (u1.ru_stime - u0.ru_stime)
    n = record.video.num_frames
    return {
        "preset": preset_name,
        "matcher": cfg.matcher,
        "masks": masks,
        "objects": len(record.objects),
        "frames": n,
        "wall_s": round(wall, 2),
        "fps": round(n / wall, 2),
        "cpu_share": round(cpu / (wall * (os.cpu_count() or 1)), 3),
        "stages_s": {k: round(v, 2) for k, v in sorted(timings.items())},
        "peak_rss_mib": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
        "ir": record.background.ir,
        "gate": record.gate.label,
        "rrd_mb": round(Path(rrd).stat().st_size / 1e6, 2) if sink is not None else None,
        "dense_points": [len(w.cloud) for w in record.dense],
    }


def _child(path: Path, preset_name: str, masks: str, matcher: str, rrd: str) -> dict:
    cmd = [sys.executable, __file__, "--child", str(path), preset_name, masks, matcher, rrd]
    return json.loads(subprocess.run(cmd, capture_output=True, text=True, check=True).stdout)


def rrd_overhead(path: Path, preset_name: str, matcher: str, repeats: int = 2) -> None:
    """Best of ``repeats`` runs each way, alternating, so that a busy moment hits both sides alike."""
    with tempfile.TemporaryDirectory() as tmp:
        plain, recorded = [], []
        for _ in range(repeats):
            plain.append(_child(path, preset_name, "motion", matcher, "-"))
            recorded.append(_child(path, preset_name, "motion", matcher, str(Path(tmp) / "bench.rrd")))
    a = min(plain, key=lambda r: r["wall_s"])
    b = min(recorded, key=lambda r: r["wall_s"])
    extra = b["wall_s"] / a["wall_s"] - 1.0
    print(
        f"{path.parent.name}: {a['frames']} frames, {preset_name} {a['matcher']} masks=motion ({a['objects']} objects)"
    )
    print(f"  scoring alone      {a['wall_s']:7.1f} s  ({a['fps']:.2f} frames/s, peak RSS {a['peak_rss_mib']:.0f} MiB)")
    print(f"  scoring + .rrd     {b['wall_s']:7.1f} s  ({b['fps']:.2f} frames/s, peak RSS {b['peak_rss_mib']:.0f} MiB)")
    print(f"  recording adds     {100 * extra:+.1f} % time; .rrd {b['rrd_mb']:.1f} MB (targets: <= 30 %, <= 15 MB)")
    pts = b["dense_points"]
    if pts:
        print(
            f"  dense clouds       first/last {pts[0]} points, {len(pts) - 1} windows of {min(pts[1:], default=0)}-"
            f"{max(pts[1:], default=0)} points (dense stage {b['stages_s'].get('dense', 0):.1f} s)"
        )


def multiview_cost(path: Path, repeats: int) -> None:
    """``audit`` without and with the multi-view check (motion masks, as ``geocon score``): the
    fastest of ``repeats`` runs each, the ratio of their wall times and both peak memories."""
    runs = {}
    for name in ("audit:no-multiview", "audit"):
        runs[name] = min(
            (_child(path, name, "motion", "-", "-") for _ in range(max(1, repeats))), key=lambda r: r["wall_s"]
        )
        r = runs[name]
        print(
            f"{path.parent.name}: {r['frames']} frames, {name:18} wall {r['wall_s']:6.1f} s  "
            f"{r['fps']:5.2f} frames/s  peak RSS {r['peak_rss_mib']:7.1f} MiB  stages {r['stages_s']}",
            flush=True,
        )
    ratio = runs["audit"]["wall_s"] / runs["audit:no-multiview"]["wall_s"]
    print(f"the multi-view check: {ratio:.2f}x the time of audit without it (target <= 1.3x)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=120)
    ap.add_argument("--size", default="1024x720")
    ap.add_argument(
        "--preset",
        default=None,
        help="paper, strict, audit or fast (default: paper, strict, fast); audit:no-multiview is audit "
        "without the multi-view check",
    )
    ap.add_argument(
        "--multiview-cost",
        action="store_true",
        help="audit with and without the multi-view check, side by side, and the ratio of their times",
    )
    ap.add_argument("--repeats", type=int, default=1, help="runs per measurement; the fastest is shown")
    ap.add_argument("--memory", action="store_true", help="compare peak memory at 120 and 480 frames")
    ap.add_argument("--matcher", default="-", help="replaces the preset's matcher (sift, orb, klt, klt_tracks)")
    ap.add_argument(
        "--rrd", action="store_true", help="time and size of the Rerun recording (paper preset, motion masks)"
    )
    ap.add_argument("--family", default="C4", help="synthetic family of the clip (C4: still camera, C3: translation)")
    ap.add_argument("--child", nargs=5, metavar=("CLIP", "PRESET", "MASKS", "MATCHER", "RRD"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        print(json.dumps(measure(Path(args.child[0]), *args.child[1:])))
        return
    if args.rrd:
        rrd_overhead(clip(args.frames, args.size, args.family), args.preset or "paper", args.matcher)
        return
    if args.multiview_cost:
        multiview_cost(clip(args.frames, args.size, args.family), args.repeats)
        return
    presets = [args.preset] if args.preset else ["paper", "strict", "fast"]
    lengths = [120, 480] if args.memory else [args.frames]
    for n in lengths:
        path = clip(n, args.size)
        for name in presets:
            for masks in ("none", "motion"):
                runs = [_child(path, name, masks, args.matcher, "-") for _ in range(max(1, args.repeats))]
                r = min(runs, key=lambda run: run["wall_s"])
                spread = f" (of {len(runs)}: {min(x['fps'] for x in runs):.2f}-{r['fps']:.2f})" if len(runs) > 1 else ""
                print(
                    f"{args.size} x {r['frames']} frames, {r['preset']:6} {r['matcher']} masks={masks:6} "
                    f"({r['objects']} objects): {r['fps']:6.2f} frames/s{spread}  wall {r['wall_s']:6.1f} s  "
                    f"CPU {100 * r['cpu_share']:3.0f}% of {os.cpu_count()} cores  "
                    f"peak RSS {r['peak_rss_mib']:7.1f} MiB  stages {r['stages_s']}",
                    flush=True,
                )


if __name__ == "__main__":
    main()
