"""Responsiveness of `geocon serve` (the Viser audit app) on a 500-clip results folder.

    .venv/bin/python benchmarks/bench_serve.py [--clips 500] [--frames 24] [--keep DIR | --results DIR]

Scores a small synthetic benchmark (families C1-C5, one scene, one platform: 15 clips), then
clones its clip folders under new ids and five platform names until the results hold ``--clips``
clips, and writes the tables as `geocon bench` does. It then measures:

- startup: `geocon serve RESULTS --port 0` as a user runs it, from launch to the printed address
  (Python start-up and imports included) and to the first HTTP 200 of the page; also without the
  tables (every record.json read instead);
- in process: opening the results, reading every clip's residuals (the app does it in the
  background), re-gating all clips at a new tau_H (cold: residuals read on demand; warm: after
  preloading), a filter change, and selecting a clip.

``--keep DIR`` leaves the results folder there to browse (`geocon serve DIR`); ``--results DIR``
measures such a kept folder again without rebuilding it.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
import urllib.request
from dataclasses import replace
from pathlib import Path

from geocon_core.bench import run_bench, write_tables
from geocon_core.config import ScoreConfig
from geocon_core.synth import plan_benchmark, write_benchmark

PLATFORMS = ("alpha", "bravo", "charlie", "delta", "echo")


def build_results(root: Path, n_clips: int, frames: int) -> Path:
    """A results folder of ``n_clips`` clips cloned from 15 scored synthetic clips."""
    data, results = root / "data", root / "results"
    plan = plan_benchmark(scenes=1, platforms=("clean",))
    write_benchmark(data, plan, num_frames=frames)
    summary = run_bench(data, results, ScoreConfig(working_size=(320, 180)), workers=2, tables=False)
    assert summary.failed == 0, "a clip failed; see its status.json"
    sources = sorted(p for p in (results / "clips").iterdir() if p.is_dir())
    for i in range(n_clips - len(sources)):
        src = sources[i % len(sources)]
        platform = PLATFORMS[i % len(PLATFORMS)]
        clip_id = f"{platform}-{src.name}-{i:04d}"
        dst = results / "clips" / clip_id
        dst.mkdir()
        for f in src.rglob("*"):
            target = dst / f.relative_to(src)
            if f.is_dir():
                target.mkdir(exist_ok=True)
            elif f.name != "status.json":
                os.link(f, target)  # the arrays are shared; only the sidecar differs
        status = json.loads((src / "status.json").read_text())
        status["clip_id"] = clip_id
        status["meta"] = {**status["meta"], "clip_id": clip_id, "model": platform}
        (dst / "status.json").write_text(json.dumps(status, indent=1))
    write_tables(results)
    return results


def time_cli(results: Path) -> tuple[float, float, str]:
    """Seconds from launching `geocon serve` to its printed address and to the page's first 200."""
    start = time.perf_counter()
    proc = subprocess.Popen(
        [sys.executable, "-m", "geocon_viewer.cli", "serve", str(results), "--port", "0"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        line = ""
        while "GeoCon audit app:" not in line:
            line = proc.stdout.readline()
            if not line:
                raise RuntimeError(f"geocon serve exited: {proc.stderr.read() if proc.stderr else ''}")
        ready = time.perf_counter() - start
        url = line.split("GeoCon audit app:", 1)[1].split()[0]
        with urllib.request.urlopen(url, timeout=30) as resp:
            assert resp.status == 200
            resp.read()
        page = time.perf_counter() - start
        return ready, page, line.strip()
    finally:
        proc.terminate()
        proc.wait(timeout=30)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--clips", type=int, default=500)
    ap.add_argument("--frames", type=int, default=24)
    group = ap.add_mutually_exclusive_group()
    group.add_argument("--keep", type=Path, default=None, help="Keep the results folder here.")
    group.add_argument(
        "--results", type=Path, default=None, help="Measure this results folder instead of building one."
    )
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        if args.results is not None:
            results = args.results
            print(f"results: {results}")
        else:
            t0 = time.perf_counter()
            results = build_results(Path(tmp), args.clips, args.frames)
            print(
                f"results: {args.clips} clips of {args.frames} frames (320x180) "
                f"built in {time.perf_counter() - t0:.0f} s"
            )

        ready, page, line = time_cli(results)
        print(f"geocon serve, with tables:    address printed after {ready:.2f} s, page served after {page:.2f} s")
        print(f"  {line}")
        tables = results / "tables"
        shutil.move(tables, Path(tmp) / "tables-aside")
        try:
            ready_nt, page_nt, _ = time_cli(results)
        finally:
            shutil.move(Path(tmp) / "tables-aside", tables)
        print(
            f"geocon serve, without tables: address printed after {ready_nt:.2f} s, page served after {page_nt:.2f} s"
        )

        from geocon_core.results import ResultsIndex
        from geocon_viewer.audit.app import AuditApp

        t = time.perf_counter()
        index = ResultsIndex.open(results)
        open_s = time.perf_counter() - t
        app = AuditApp(index, port=0, preload=False)
        try:
            steps: list[tuple[str, float]] = [("open the results", open_s)]

            def timed(name: str, action) -> None:
                t = time.perf_counter()
                action()
                steps.append((name, time.perf_counter() - t))

            timed("re-gate all clips at tau_H 3 (cold)", lambda: setattr(app.number["tau_h"], "value", 3.0))
            timed("re-gate all clips at tau_F 0.2 (cold)", lambda: setattr(app.number["tau_f"], "value", 0.2))
            timed("reset (recorded values, no re-gate)", app._reset_thresholds)
            timed("preload every clip's residuals", index.preload)
            timed("re-gate all clips at tau_H 1.5 (warm)", lambda: setattr(app.number["tau_h"], "value", 1.5))
            timed("change the report gates (no re-gate)", lambda: setattr(app.number["ge_gate"], "value", 0.05))
            timed("filter: one platform", lambda: setattr(app.platform, "value", PLATFORMS[2]))
            timed("select another clip", lambda: setattr(app.clip, "value", app.rows[-1].clip_id))
            print(f"in process ({len(index.clips)} clips, {sum(c.status == 'ok' for c in index.clips)} scored):")
            for name, s in steps:
                print(f"  {name:<42} {s * 1000:8.0f} ms")
            th = replace(index.recorded, tau_h=3.0)
            assert index.triage(th)[0].verdict is not None
        finally:
            app.stop()
        if args.keep is not None:
            shutil.copytree(results, args.keep)
            print(f"kept: {args.keep} (geocon serve {args.keep})")


if __name__ == "__main__":
    main()
