"""Scoring speed and memory on synthetic clips.

    .venv/bin/python benchmarks/bench_score.py [--frames 120] [--size 1024x720] [--preset paper]
    .venv/bin/python benchmarks/bench_score.py --memory      # 120 vs 480 frames
    .venv/bin/python benchmarks/bench_score.py --matcher klt # a faster matcher

Renders a C4 clip (static camera, two moving objects) once into a cache folder, then scores
it in a fresh process per measurement, without and with mask-first separation (built-in
motion segmentation, flow and AdaDFRC-W2), and prints frames per second end to end, seconds
per stage (summed over the worker threads, so they can exceed the wall time) and the peak
resident memory.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CACHE = Path(tempfile.gettempdir()) / "geocon-bench"


def clip(frames: int, size: str) -> Path:
    from geocon_core.synth import ClipPlan, write_clip

    w, h = (int(v) for v in size.split("x"))
    folder = CACHE / f"{size}-{frames}"
    path = folder / "c4_objects.mp4"
    if not path.exists():
        write_clip(ClipPlan("C4"), folder, width=w, height=h, num_frames=frames)
    return path


def measure(path: Path, preset_name: str, masks: str, matcher: str) -> dict:
    from geocon_core.config import preset
    from geocon_core.scorer import score_clip

    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    record = score_clip(path, preset(preset_name).with_(masks=masks, matcher=matcher), timings=timings)
    wall = time.perf_counter() - t0
    n = record.video["num_frames"]
    return {
        "preset": preset_name,
        "masks": masks,
        "objects": len(record.objects),
        "frames": n,
        "wall_s": round(wall, 2),
        "fps": round(n / wall, 2),
        "stages_s": {k: round(v, 2) for k, v in sorted(timings.items())},
        "peak_rss_mib": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
        "ir": record.background.ir,
        "gate": record.gate.label,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=120)
    ap.add_argument("--size", default="1024x720")
    ap.add_argument("--preset", default=None, help="paper or strict (default: both)")
    ap.add_argument("--memory", action="store_true", help="compare peak memory at 120 and 480 frames")
    ap.add_argument("--matcher", default="sift")
    ap.add_argument("--child", nargs=4, metavar=("CLIP", "PRESET", "MASKS", "MATCHER"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        print(json.dumps(measure(Path(args.child[0]), *args.child[1:])))
        return
    presets = [args.preset] if args.preset else ["paper", "strict"]
    lengths = [120, 480] if args.memory else [args.frames]
    for n in lengths:
        path = clip(n, args.size)
        for name in presets:
            for masks in ("none", "motion"):
                cmd = [sys.executable, __file__, "--child", str(path), name, masks, args.matcher]
                r = json.loads(subprocess.run(cmd, capture_output=True, text=True, check=True).stdout)
                print(f"{args.size} x {r['frames']} frames, {r['preset']:6} {args.matcher} masks={masks:6} ({r['objects']} objects): "
                      f"{r['fps']:6.2f} frames/s  wall {r['wall_s']:6.1f} s  peak RSS {r['peak_rss_mib']:7.1f} MiB  stages {r['stages_s']}",
                      flush=True)


if __name__ == "__main__":
    main()
