"""Does another preset say what ``paper`` says? Scores the same validation cases with two presets
and compares gate, verdict and t_inf case by case (a faster preset must keep them; a stricter one
shows where it departs).

    .venv/bin/python benchmarks/compare_presets.py                      # paper vs audit, default grid
    .venv/bin/python benchmarks/compare_presets.py --b strict --out /tmp/cmp -- --heights 256 --no-real

Each preset is run with ``geocon validate`` into ``OUT/<preset>`` (clean synthetic families at
heights 256 and 720 px, PNG and H.264 CRF 28, and every real clip of ``../shared/data``; anything
after ``--`` replaces those validate options), so a second run resumes and the clips are rendered
once into ``OUT/cache``. Then, over the cases both presets scored:

- **gate**: the same H / F label, counted outside the gray zone (cases whose expected gate, from
  the synthetic truth or the annotation, is H or F);
- **verdict**: the same consistent / inconsistent / not judged;
- **t_inf**: within 20 % of the first preset's where that is at least 0.03 (the lower gate
  threshold: there the value decides the gate); below it t_inf is a noise bound (a rotation reads
  parallax / f), so the absolute difference is reported instead;
- the wall time of each run (``seconds`` of its ``validation.json``).

The table is printed and written to ``OUT/compare.md``; the exit status is 0.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_GRID = ["--heights", "256,720", "--codecs", "png,crf28", "--failures", "none"]
REL_TOL = 0.2
T_DECIDES = 0.03


def run_validate(preset: str, out: Path, cache: Path, grid: list[str], jobs: int) -> dict:
    folder = out / preset
    cmd = [str(ROOT / ".venv" / "bin" / "geocon"), "validate", "--preset", preset, "--out", str(folder)]
    cmd += ["--cache", str(cache), "--jobs", str(jobs), *grid]
    print("$", " ".join(cmd), file=sys.stderr, flush=True)
    subprocess.run(cmd, check=True, cwd=ROOT, stdout=subprocess.DEVNULL)
    return json.loads((folder / "validation.json").read_text())


def compare(a: dict, b: dict, name_a: str, name_b: str) -> list[str]:
    cases_a = {c["case_id"]: c for c in a["cases"]}
    cases_b = {c["case_id"]: c for c in b["cases"]}
    both = [k for k in cases_a if k in cases_b and not cases_a[k]["error"] and not cases_b[k]["error"]]
    gate_n = gate_same = verdict_same = t_n = t_ok = 0
    noise_diff = 0.0
    rows = []
    for k in both:
        ca, cb = cases_a[k], cases_b[k]
        truth = ca.get("truth_gate")
        if truth in ("H", "F"):
            gate_n += 1
            gate_same += ca["gate"] == cb["gate"]
        verdict_same += ca["verdict"] == cb["verdict"]
        ta, tb = ca["t_inf"], cb["t_inf"]
        rel = None
        if ta is not None and tb is not None:
            if ta >= T_DECIDES:
                t_n += 1
                rel = abs(tb - ta) / ta
                t_ok += rel <= REL_TOL
            else:
                noise_diff = max(noise_diff, abs(tb - ta))
        if ca["gate"] != cb["gate"] or ca["verdict"] != cb["verdict"] or (rel is not None and rel > REL_TOL):
            rows.append(
                f"| {k} | {truth or '-'} | {ca['gate']} / {cb['gate']} | {ca['verdict']} / {cb['verdict']} | "
                f"{_num(ta)} / {_num(tb)} |"
            )
    n = len(both)
    sec_a, sec_b = a.get("score_seconds") or a["seconds"], b.get("score_seconds") or b["seconds"]
    lines = [
        f"# {name_b} against {name_a}: {n} cases scored by both",
        "",
        "| measure | agreement |",
        "|---|---|",
        f"| same gate, outside the gray zone | {_pct(gate_same, gate_n)} |",
        f"| same verdict | {_pct(verdict_same, n)} |",
        f"| t_inf within {REL_TOL:.0%} where {name_a}'s is >= {T_DECIDES} | {_pct(t_ok, t_n)} |",
        f"| largest t_inf difference where {name_a}'s is below {T_DECIDES} | {noise_diff:.4f} |",
        f"| scoring time, summed over cases | {name_a} {sec_a:.0f} s, {name_b} {sec_b:.0f} s "
        f"({sec_a / max(sec_b, 1e-9):.1f}x) |",
        "",
    ]
    if rows:
        lines += [
            f"Cases that differ ({name_a} / {name_b}):",
            "",
            "| case | expected gate | gate | verdict | t_inf |",
            "|---|---|---|---|---|",
            *rows,
        ]
    else:
        lines.append("No case differs.")
    return lines


def _pct(k: int, n: int) -> str:
    return f"{100 * k / n:.0f}% ({k}/{n})" if n else "- (0 cases)"


def _num(v: float | None) -> str:
    return "-" if v is None else f"{v:.4f}"


def main() -> None:
    argv = sys.argv[1:]
    grid = DEFAULT_GRID
    if "--" in argv:
        i = argv.index("--")
        argv, grid = argv[:i], argv[i + 1 :]
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--a", default="paper", help="the reference preset (default paper)")
    ap.add_argument("--b", default="audit", help="the preset compared with it (default audit)")
    ap.add_argument("--out", type=Path, default=Path("compare-presets"))
    ap.add_argument("--cache", type=Path, default=None, help="clip cache (default OUT/cache)")
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args(argv)
    cache = args.cache or args.out / "cache"
    a = run_validate(args.a, args.out, cache, grid, args.jobs)
    b = run_validate(args.b, args.out, cache, grid, args.jobs)
    text = "\n".join(compare(a, b, args.a, args.b))
    (args.out / "compare.md").write_text(text + "\n")
    print(text)


if __name__ == "__main__":
    main()
