"""Throughput of `geocon bench` (clips per minute) for 1 and 2 worker processes.

    .venv/bin/python benchmarks/bench_runner.py [--scenes 2] [--frames 24] [--workers 1,2]
        [--preset paper] [--working-size WxH]

Renders a synthetic benchmark (`geocon synth-bench`: families C1-C5, three platforms) once, then
scores it from scratch with each worker count (no recordings, tables included) and prints the
wall time and clips/min of each run.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from geocon_core.bench import run_bench
from geocon_core.config import preset
from geocon_core.synth.benchmark import plan_benchmark, write_benchmark


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", type=int, default=2)
    ap.add_argument("--frames", type=int, default=24)
    ap.add_argument("--workers", default="1,2")
    ap.add_argument("--preset", default="paper", help="paper, strict, audit or fast")
    ap.add_argument("--working-size", default=None, help="replaces the preset's canvas (WxH)")
    args = ap.parse_args()
    cfg = preset(args.preset)
    if args.working_size:
        cfg = cfg.with_(working_size=tuple(int(v) for v in args.working_size.split("x")))
    w, h = cfg.working_size
    with tempfile.TemporaryDirectory() as tmp:
        data = Path(tmp) / "data"
        clips = plan_benchmark(scenes=args.scenes)
        write_benchmark(data, clips, num_frames=args.frames)
        what = f"320x180 rendered, working size {w}x{h}, preset {args.preset}"
        print(f"{len(clips)} clips of {args.frames} frames ({what})")
        print(f"{'workers':>7} {'seconds':>8} {'clips/min':>10} {'speed-up':>9}")
        base = None
        for n in (int(v) for v in args.workers.split(",")):
            start = time.perf_counter()
            summary = run_bench(data, Path(tmp) / f"results-{n}", cfg, workers=n)
            seconds = time.perf_counter() - start
            assert summary.failed == 0, "a clip failed; see its status.json"
            rate = summary.total / seconds * 60
            base = base or rate
            print(f"{n:>7} {seconds:>8.1f} {rate:>10.1f} {rate / base:>8.2f}x")


if __name__ == "__main__":
    main()
