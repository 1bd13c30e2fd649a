"""The reward on planted pairs: preference accuracy, guards, and throughput.

    .venv/bin/python benchmarks/bench_reward.py preference PLANT_DIR [PLANT_DIR ...] [--split check] [--json out.json]
    .venv/bin/python benchmarks/bench_reward.py copies PLANT_DIR [...]        # frozen, slowed, blurred twins
    .venv/bin/python benchmarks/bench_reward.py throughput [--clips 24] [--workers 2]
    .venv/bin/python benchmarks/bench_reward.py plants OUT_DIR --split check  # make a plant folder

``plants``: every kind at low and middle severity (seed 0, the first 48 frames) planted into each
annotated real-camera clip of ``../shared/real2`` in the half, as ``geocon validate --planted``
chooses its sources, one folder per source (about a minute a source on one core; a rerun keeps
what is there).

A plant folder holds, per source clip, a folder with the clean twin (``<stem>.clean.mp4``) and the
planted clips (``<stem>.<kind>-<level>-s<seed>.mp4``), as ``geocon plant`` writes them. Every
clip is scored by the reward (``reward`` preset, in memory, frames decoded once), by the GVGC keep
rate and by Epipolar-DPO's mean Sampson distance (:mod:`geocon_core.validation.peer`), each on the
clip's first 48 frames, and each planted clip is compared with its clean twin: a pair counts as
preferring the clean twin when the clean clip's reading is strictly better (a clip the reward
cannot judge never counts as preferred, in either role). Rates with Wilson intervals, per kind
and severity, the three methods side by side. Scores are cached beside each clip
(``<clip>.reward.json``) so a rerun reads them back.

``copies``: for each clean twin and planted clip, a frozen copy (its first frame repeated), a
slowed copy (each of its first half's frames shown twice) and a blurred copy (Gaussian, sigma 3 px
of the source); each copy must never be preferred over the clip it was made from.

``throughput``: synthetic 48-frame 854x480 clips scored in memory, clips per minute with
``--workers`` threads, peak RSS, and the Epipolar-DPO metric's time on the same clips.
"""

from __future__ import annotations

import argparse
import json
import re
import resource
import sys
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from geocon_core.config import IndependentConfig, RewardConfig, preset  # noqa: E402
from geocon_core.intervals import wilson_interval  # noqa: E402
from geocon_core.reward import RewardScorer, decode_clip, sample_evenly  # noqa: E402
from geocon_core.scoring import score_frames  # noqa: E402
from geocon_core.validation.peer import epipolar_score, peer_keep_rate  # noqa: E402

FRAMES = 48
CACHE_VERSION = 6
EXPLORE_GAPS = (1, 4, 16)
"""The gaps the per-pair readings are cached at (the tune half compares subsets of them)."""
PLANTED = re.compile(r"^(?P<stem>.+)\.(?P<kind>slide|morph|redraw|breathing)-(?P<level>low|middle|high)-s\d+\.mp4$")


VARIANTS: dict[str, dict[str, Any]] = {
    "": {},
    "sift": {"matcher": "sift", "max_features": 8000, "ratio": 0.8},
    "unmasked": {"masks": "none", "independent": IndependentConfig(enabled=False)},
    "windows-H": {"reward": {"window_models": "H"}},
    "windows-F": {"reward": {"window_models": "F"}},
    "windows-gate": {"reward": {"window_models": "gate"}},
    "pairs": {"reward": {"reading": "pairs"}},
}
"""Candidate settings compared on the tune half (``--variant``): of the ``reward`` preset, or under
``"reward"`` of the reward's reading (:class:`~geocon_core.config.RewardConfig`)."""


def _scorer(variant: str) -> RewardScorer:
    settings = dict(VARIANTS[variant])
    reading = settings.pop("reward", {})
    return RewardScorer(config=preset("reward").with_(**settings), reward=RewardConfig(**reading), workers=1)


def _scores(clip: Path, scorer: RewardScorer, peers: bool = True, variant: str = "") -> dict:
    cache = clip.with_name(clip.name + (f".reward-{variant}.json" if variant else ".reward.json"))
    saved: dict = {}
    if cache.is_file():
        saved = json.loads(cache.read_text())
        if saved.get("version") == CACHE_VERSION and (saved.get("gvgc_run") or not peers):
            return saved
    if not saved.get("gvgc_run"):
        saved = {}  # the peers' readings of an older cache are kept: they do not depend on the reward
    frames = decode_clip(clip)[:FRAMES]
    r = scorer.score(frames, name=clip.name, channel_order="bgr")
    pairs = {}
    if r.judged:  # the per-pair readings behind the score, for the tune half's comparisons
        bgr = np.ascontiguousarray(frames[sample_evenly(len(frames), scorer.reward.max_frames)])
        explore = scorer.config.with_(gaps=EXPLORE_GAPS)
        record = score_frames(bgr, explore, name=clip.name, channel_order="bgr", workers=1)
        fam = record.background.model
        m = record.matches
        res = m.h_res if fam == "H" else m.f_res_px
        own = m.h_ind if fam == "H" else m.f_ind
        rows = []
        for p in record.pairs:
            f = p.fit(fam)
            if p.skip is not None or f is None or not f.valid or f.ir is None:
                continue
            lo, hi = int(m.offsets[p.index]), int(m.offsets[p.index + 1])
            kept = res[lo:hi][~own[lo:hi]]
            kernels = [float(np.mean(1.0 / (1.0 + (kept / s) ** 2))) if len(kept) else None for s in (0.5, 1.0, 2.0)]
            rows.append([p.gap, p.n_matches, f.ir, f.ge, *kernels, float(np.median(kept)) if len(kept) else None])
        pairs = {"family": fam, "rows": rows}
    if saved:
        keep, epi, ran = saved["gvgc"], saved["epipolar"], True
    else:
        keep = peer_keep_rate(clip, FRAMES).keep_rate if peers else None
        epi, ran = epipolar_score(iter(frames)).sampson, peers
    row = {
        "version": CACHE_VERSION,
        "reward": r.score,
        "reason": r.reason,
        "gvgc": keep,
        "gvgc_run": ran,
        "epipolar": epi,
        "seconds": round(r.seconds, 2),
        "readings": {k: v for k, v in r.readings.items() if k != "guards"},
        "guards": r.readings.get("guards"),
        "pairs": pairs,
    }
    cache.write_text(json.dumps(row))
    return row


def _better(method: str, clean: float | None, planted: float | None) -> bool:
    if clean is None:
        return False
    if planted is None:
        return method != "reward"  # a planted clip a peer cannot read loses; the reward's unjudged clip is no win
    return clean < planted if method == "epipolar" else clean > planted


def _rate(k: int, n: int) -> str:
    if n == 0:
        return "-"
    iv = wilson_interval(k, n)
    return f"{k}/{n} ({k / n:.0%} [{iv.low:.0%}, {iv.high:.0%}])"


def _split(stem: str) -> str:
    """The half of the stick a real2 source belongs to (``geocon_core.validation.cases.split_of``)."""
    from geocon_core.media.decode import VIDEO_FILE_SUFFIXES
    from geocon_core.validation.cases import split_of

    real2 = ROOT.parent / "shared" / "real2"
    names = [p.name for p in real2.glob(f"{stem}.*") if p.suffix.lower() in VIDEO_FILE_SUFFIXES]
    return split_of(f"real2:{names[0]}") if names else "unknown"


def preference(
    dirs: list[Path], out: Path | None, split: str | None = None, peers: bool = True, variant: str = ""
) -> None:
    scorer = _scorer(variant)
    rows: dict[tuple[str, str], dict[str, list[bool]]] = {}
    unjudged = 0
    for d in dirs:
        for folder in sorted(p for p in d.iterdir() if p.is_dir()):
            clean = folder / f"{folder.name}.clean.mp4"
            if not clean.is_file() or (split is not None and _split(folder.name) != split):
                continue
            c = _scores(clean, scorer, peers, variant)
            unjudged += c["reward"] is None
            for clip in sorted(folder.glob("*.mp4")):
                m = PLANTED.match(clip.name)
                if m is None:
                    continue
                p = _scores(clip, scorer, peers, variant)
                cell = rows.setdefault((m["kind"], m["level"]), {"reward": [], "gvgc": [], "epipolar": []})
                for method in cell:
                    cell[method].append(_better(method, c[method], p[method]))
                print(f"{clip.name}: reward {c['reward']} vs {p['reward']}", flush=True)
    print("\n| kind | severity | pairs | GeoCon reward | GVGC keep rate | Epipolar-DPO |")
    print("|---|---|---|---|---|---|")
    table = {}
    for (kind, level), cell in sorted(rows.items()):
        n = len(cell["reward"])
        print(
            f"| {kind} | {level} | {n} | "
            + " | ".join(_rate(sum(cell[m]), n) for m in ("reward", "gvgc", "epipolar"))
            + " |"
        )
        table[f"{kind}/{level}"] = {m: [sum(v), len(v)] for m, v in cell.items()}
    print(f"\nclean twins the reward cannot judge: {unjudged}")
    if out is not None:
        out.write_text(json.dumps({"table": table, "clean_unjudged": unjudged}, indent=1))


def copies(dirs: list[Path], split: str | None = None) -> None:
    scorer = RewardScorer(workers=1)
    wins: dict[str, list[bool]] = {"frozen": [], "slowed": [], "blurred": []}
    for d in dirs:
        for clip in sorted(d.glob("*/*.mp4")):
            if split is not None and _split(clip.parent.name) != split:
                continue
            frames = decode_clip(clip)[:FRAMES]
            own = scorer.score(frames, channel_order="bgr")
            n = len(frames)
            made = {
                "frozen": np.repeat(frames[:1], n, axis=0),
                "slowed": np.repeat(frames[: (n + 1) // 2], 2, axis=0)[:n],
                "blurred": np.stack([cv2.GaussianBlur(f, (0, 0), 3.0) for f in frames]),
            }
            for name, copy in made.items():
                got = scorer.score(copy, channel_order="bgr")
                won = got.score is not None and (own.score is None or got.score >= own.score)
                wins[name].append(won)
                if won:
                    print(f"{clip.name}: the {name} copy wins ({got.score} vs {own.score})", flush=True)
    for name, w in wins.items():
        print(f"{name} copies preferred over their clip: {sum(w)} of {len(w)}")


def _rss_now() -> float:
    """The process's resident memory now, MiB (Linux)."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def throughput(clips: int, workers: int) -> None:
    from geocon_core.synth import ClipPlan, write_clip

    tmp = Path("/tmp/geocon-bench-reward")
    tmp.mkdir(exist_ok=True)
    plans = [ClipPlan(f) for f in ("C2", "C3", "C4", "C5")]
    paths = []
    for plan in plans:
        before = set(tmp.glob("*.mp4"))
        write_clip(plan, tmp, seed=1, width=854, height=480, num_frames=48)
        paths += list(set(tmp.glob("*.mp4")) - before) or [p for p in tmp.glob(f"{plan.family.lower()}*.mp4")][:1]
    batch = [decode_clip(p)[:48] for p in sorted(set(paths))]
    batch = (batch * (clips // len(batch) + 1))[:clips]
    held = sum(f.nbytes for f in {id(f): f for f in batch}.values()) / 2**20
    rss_held = _rss_now()
    scorer = RewardScorer(workers=workers)
    scorer.score_batch(batch[:workers], channel_order="bgr")  # warm: imports, OpenCL probes
    start = time.perf_counter()
    results = scorer.score_batch(batch, channel_order="bgr")
    wall = time.perf_counter() - start
    start = time.perf_counter()
    for f in batch:
        epipolar_score(iter(f))
    epi = time.perf_counter() - start
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    judged = sum(r.judged for r in results)
    print(
        f"reward: {clips} clips of 48 frames at 854x480 in {wall:.1f} s with {workers} workers: "
        f"{60 * clips / wall:.1f} clips/min ({judged} judged); peak RSS {rss:.0f} MiB, of which "
        f"{rss_held:.0f} MiB held before scoring (interpreter, libraries and the batch's {held:.0f} MiB "
        f"of frames): the scorer adds {rss - rss_held:.0f} MiB at its peak"
    )
    print(f"Epipolar-DPO metric: {60 * clips / epi:.1f} clips/min on one thread ({epi / clips:.2f} s a clip)")


def plants(out: Path, split: str | None) -> None:
    from geocon_core.plant import plant_clip
    from geocon_core.validation.cases import ValidationPlan, planted_cases, read_annotations

    plan = ValidationPlan(planted=True, split=split or "all", real2=ROOT.parent / "shared" / "real2")
    cases = planted_cases(plan, read_annotations())
    sources = [
        Path(str(c.source)) for c in cases if c.failure is None and c.annotation and c.annotation.root == "real2"
    ]
    print(f"{len(sources)} sources into {out}", flush=True)
    for i, clip in enumerate(sources, 1):
        folder = out / clip.stem
        folder.mkdir(parents=True, exist_ok=True)
        for kind in ("breathing", "morph", "redraw", "slide"):
            for level in ("middle", "low"):
                if (folder / f"{clip.stem}.{kind}-{level}-s0.mp4").is_file():
                    continue
                try:
                    plant_clip(clip, kind, level, 0, folder, frames=FRAMES)
                except ValueError as exc:
                    print(f"{clip.stem}: {kind} at {level} not planted: {exc}", flush=True)
        print(f"[{i}/{len(sources)}] {clip.stem}", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("what", choices=("preference", "copies", "throughput", "plants"))
    ap.add_argument("dirs", nargs="*", type=Path)
    ap.add_argument("--json", type=Path)
    ap.add_argument(
        "--no-gvgc", action="store_true", help="leave the GVGC keep rate out (its 40,000 SIFT features dominate)"
    )
    ap.add_argument("--variant", choices=tuple(VARIANTS), default="", help="a candidate setting of the reward preset")
    ap.add_argument("--split", choices=("tune", "check"), help="only the sources of this half of the stick")
    ap.add_argument("--clips", type=int, default=24)
    ap.add_argument("--workers", type=int, default=2)
    a = ap.parse_args()
    if a.what == "plants":
        if len(a.dirs) != 1:
            ap.error("plants takes one folder to write into")
        plants(a.dirs[0], a.split)
    elif a.what == "throughput":
        throughput(a.clips, a.workers)
    elif a.what == "preference":
        preference(a.dirs, a.json, a.split, not a.no_gvgc, a.variant)
    else:
        copies(a.dirs, a.split)


if __name__ == "__main__":
    main()
