"""Throughput of `geocon bench` (clips per minute) for 1 and 2 worker processes, with the process
pool and with Ray (a private local instance with 1 and 2 CPUs; the distributed extra).

    .venv/bin/python benchmarks/bench_runner.py [--scenes 2] [--frames 24] [--workers 1,2]
        [--preset paper] [--working-size WxH] [--executors pool,ray]

Renders a synthetic benchmark (`geocon synth-bench`: families C1-C5, three platforms) once, then
scores it from scratch with each executor and worker count (no recordings, tables included) and
prints the wall time and clips/min of each run. For Ray it also prints the start and stop of the
local instance alone, and Ray's overhead per clip: (Ray's wall time - the pool's) / clips at the
same worker count, start-up included.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from geocon_core.bench import RayOptions, run_bench
from geocon_core.config import preset
from geocon_core.synth import plan_benchmark, write_benchmark


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", type=int, default=2)
    ap.add_argument("--frames", type=int, default=24)
    ap.add_argument("--workers", default="1,2")
    ap.add_argument("--preset", default="paper", help="paper, strict, audit or fast")
    ap.add_argument("--working-size", default=None, help="replaces the preset's canvas (WxH)")
    ap.add_argument("--executors", default="pool", help="pool, ray or pool,ray (Ray: the distributed extra)")
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
        executors = args.executors.split(",")
        if "ray" in executors:
            print(f"Ray local instance start + stop alone: {_ray_startup():.1f} s")
        print(f"{'executor':>8} {'workers':>7} {'seconds':>8} {'clips/min':>10} {'speed-up':>9} {'overhead/clip':>14}")
        base, pool_seconds = None, {}
        for executor in executors:
            for n in (int(v) for v in args.workers.split(",")):
                options = RayOptions(local_cpus=n) if executor == "ray" else None
                start = time.perf_counter()
                out = Path(tmp) / f"results-{executor}-{n}"
                summary = run_bench(data, out, cfg, workers=n, executor=executor, ray=options)
                seconds = time.perf_counter() - start
                assert summary.failed == 0, "a clip failed; see its status.json"
                rate = summary.total / seconds * 60
                base = base or rate
                if executor == "pool":
                    pool_seconds[n] = seconds
                extra = ""
                if executor != "pool" and n in pool_seconds:
                    extra = f"{(seconds - pool_seconds[n]) / summary.total:>+13.2f}s"
                print(f"{executor:>8} {n:>7} {seconds:>8.1f} {rate:>10.1f} {rate / base:>8.2f}x {extra:>14}")


def _ray_startup() -> float:
    """Seconds to start and stop a private local Ray instance, as `--executor ray` does."""
    import ray

    from geocon_core.bench.ray import _start_local

    start = time.perf_counter()
    reaper = _start_local(ray, 1)
    ray.shutdown()
    if reaper is not None:
        reaper.wait(timeout=10)
    return time.perf_counter() - start


if __name__ == "__main__":
    main()
