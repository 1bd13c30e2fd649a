"""Responsiveness of `geocon teach`: seconds from a slider move to the updated numbers on the page.

    .venv/bin/python benchmarks/bench_teach.py [--size 320x180] [--frames 16] [--rounds 1] [--target 2.0]

Starts the teaching app in process (127.0.0.1, any free port), waits for the first clip (imports
and warm-up, reported apart), then moves the sliders one at a time as a student would: each
slider to a new value and back (camera translation across the gate's band, rotation, breathing,
slide, elasticity, object speed), ``--rounds`` times. For each move it waits until the update is
on the page and reads the latency the app measured (from the slider's callback to the numbers
set on the page, debounce included) with its render and score times. Prints every move, then the
median and the maximum, and exits with status 1 when the maximum exceeds ``--target`` seconds.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

from geocon_viewer.teach.app import TeachApp, TeachParams

MOVES: tuple[tuple[str, float, float], ...] = (
    ("translation", 0.07, 0.02),
    ("rotation_deg", 4.0, 0.0),
    ("breathing_px", 10.0, 0.0),
    ("slide_px", 20.0, 0.0),
    ("elastic_px", 20.0, 0.0),
    ("object_speed", 1.0, 0.5),
)
"""(slider, value, back to) in the order moved."""


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", default="320x180", help="render size (one of the app's sizes)")
    ap.add_argument("--frames", type=int, default=16, help="frames per clip")
    ap.add_argument("--rounds", type=int, default=1, help="how many times to run the moves")
    ap.add_argument("--target", type=float, default=2.0, help="the most seconds a move may take")
    args = ap.parse_args()

    start = time.perf_counter()
    app = TeachApp(port=0, params=TeachParams(size=args.size, num_frames=args.frames))
    try:
        first = app.wait(timeout=300)
        print(
            f"first clip ({args.size} x {args.frames} frames, {os.cpu_count()} CPUs): on the page "
            f"{time.perf_counter() - start:.2f} s after start (imports and warm-up; render {first.render_s:.2f} s, "
            f"score {first.score_s:.2f} s)"
        )
        latencies = []
        for _ in range(args.rounds):
            for name, value, back in MOVES:
                for v in (value, back):
                    app.sliders[name].value = v  # runs the slider's callback, as a browser does
                    u = app.wait(timeout=120)
                    latencies.append(u.latency_s)
                    print(
                        f"  {name:>13} = {v:<5g} {u.latency_s:5.2f} s  (render {u.render_s:.2f} s, score "
                        f"{u.score_s:.2f} s)  gate {u.gate_label}  IR {u.ir:.3f}"
                    )
    finally:
        app.stop()
    median, worst = statistics.median(latencies), max(latencies)
    ok = worst <= args.target
    print(
        f"slider -> numbers over {len(latencies)} moves: median {median:.2f} s, max {worst:.2f} s "
        f"(target {args.target:g} s: {'met' if ok else 'MISSED'})"
    )
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
