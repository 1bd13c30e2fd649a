"""Rendering speed and memory of `geocon synth`.

    .venv/bin/python benchmarks/bench_synth.py [--size 640x360] [--frames 48]

Prints seconds per frame (render only, and render + encode + masks) per family and the
peak resident memory of the process.
"""

from __future__ import annotations

import argparse
import resource
import tempfile
import time

from geocon_core.synth import FAMILIES, ClipPlan, build_scene, render_frame, write_clip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", default="640x360")
    ap.add_argument("--frames", type=int, default=48)
    args = ap.parse_args()
    w, h = (int(v) for v in args.size.split("x"))
    print(f"{'family':8} {'render s/frame':>15} {'write s/frame':>14}")
    with tempfile.TemporaryDirectory() as tmp:
        for code in FAMILIES:
            scene = build_scene(code, width=w, height=h, num_frames=args.frames)
            t0 = time.perf_counter()
            for t in range(scene.num_frames):
                render_frame(scene, t)
            render = (time.perf_counter() - t0) / scene.num_frames
            t0 = time.perf_counter()
            write_clip(ClipPlan(code), tmp, width=w, height=h, num_frames=args.frames)
            write = (time.perf_counter() - t0) / args.frames
            print(f"{code:8} {render:15.3f} {write:14.3f}")
    print(f"peak RSS: {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MiB")


if __name__ == "__main__":
    main()
