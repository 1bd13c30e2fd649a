"""GeoCon against the tool a user would otherwise write: pycolmap two-view geometry.

    bash scripts/bootstrap.sh peers && .venv/bin/python benchmarks/bench_peers.py
    .venv/bin/python benchmarks/bench_peers.py --frames 24          # a shorter run, same per-frame work

Speed, on two rendered 1024x720 clips (the ``bench_score.py`` clip: static camera, two moving
objects; and a lateral truck with parallax, C3), ``--frames`` frames each:

- **GeoCon**: ``score_clip`` end to end (decode to record) with each ``--presets`` preset, built-in
  motion masks, the default two worker threads;
- **pycolmap** (the ``peers`` extra, not a dependency of the package): its SIFT (4000 features),
  exhaustive descriptor matching with its ratio and cross check, and ``estimate_two_view_geometry``
  on every adjacent pair, each step with 2 threads, frames decoded by OpenCV.

Frames per second of each and GeoCon's ratio to pycolmap are printed.

Regime, on the synthetic families C1-C6 (640x360, 24 frames, seed 0, known truth): GeoCon's gate
label against the expected one, and pycolmap's configuration of the first-last pair
(``PLANAR``, ``PANORAMIC`` or ``PLANAR_OR_PANORAMIC`` read as H; ``CALIBRATED`` or ``UNCALIBRATED``
as F; anything else, or too few matches, as no answer). Gray-zone families (truth U) are shown,
not counted.

The GVGC keep rate (``--gvgc [CLIP ...]``), the simplest published metric of generated-video
geometry (:mod:`geocon_core.validation.peer`: 854x480 SIFT, FLANN ratio 0.85, F-RANSAC at 1 px,
F inliers / matches), beside GeoCon's clip score and verdict (``audit``) on each clip, with the
seconds of each; without clips, on the synthetic C1-C6 clips (640x360, 24 frames). ``geocon
validate`` reports the two side by side on the annotated real and generated footage (AUC rows).

    .venv/bin/python benchmarks/bench_peers.py --gvgc                 # synthetic families
    .venv/bin/python benchmarks/bench_peers.py --gvgc clip1.mp4 clip2.gif
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import cv2
import numpy as np
from bench_score import clip  # the same rendered clips (this folder is on sys.path when run)

H_CONFIGS = {"PLANAR", "PANORAMIC", "PLANAR_OR_PANORAMIC"}
F_CONFIGS = {"CALIBRATED", "UNCALIBRATED"}
THREADS = 2


def render(family: str, size: str, frames: int) -> tuple[Path, str]:
    """(clip path, expected gate label) of a rendered clip (``bench_score.py``'s cache)."""
    from geocon_core.synth import load_ground_truth

    path = clip(frames, size, family)
    return path, load_ground_truth(next(path.parent.glob("*.gt.json"))).expected_gate


def grey_frames(path: Path) -> list[np.ndarray]:
    cap = cv2.VideoCapture(str(path))
    out = []
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        out.append(cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY))
    cap.release()
    if not out:
        raise SystemExit(f"{path}: no frames decoded")
    return out


class Colmap:
    """pycolmap's SIFT, matcher and two-view geometry, 2 threads each, on the CPU."""

    def __init__(self, max_features: int = 4000) -> None:
        import pycolmap

        self.pc = pycolmap
        ext = pycolmap.FeatureExtractionOptions()
        ext.sift.max_num_features = max_features
        ext.num_threads = THREADS
        self.extractor = pycolmap.FeatureExtractor.create(ext, device=pycolmap.Device.cpu)
        match = pycolmap.FeatureMatchingOptions()
        match.num_threads = THREADS
        self.matcher = pycolmap.FeatureMatcher.create(match, device=pycolmap.Device.cpu)

    def features(self, grey: np.ndarray):
        kp, desc = self.extractor.extract_from_uint8_array(np.ascontiguousarray(grey))
        return np.array([(k.x, k.y) for k in kp], np.float64).reshape(-1, 2), desc

    def geometry(self, a, b, shape: tuple[int, int]) -> str:
        """The two-view configuration of features ``a`` -> ``b`` (name), or ``"none"``."""
        h, w = shape
        f = w / 2 / np.tan(np.deg2rad(30.0))  # GeoCon's default intrinsics: 60 degrees over the width
        cam = self.pc.Camera.create_from_model_name(0, "SIMPLE_PINHOLE", f, w, h)
        matches = self.matcher.match(None, a[1], None, b[1])
        if len(matches) < 15:
            return "none"
        geo = self.pc.estimate_two_view_geometry(cam, a[0], cam, b[0], np.asarray(matches, np.uint32))
        names = {int(v): k for k, v in self.pc.TwoViewGeometryConfiguration.__members__.items()}
        return names.get(int(geo.config), str(geo.config))


def colmap_speed(colmap: Colmap, path: Path) -> tuple[float, dict[str, int], str]:
    """Frames per second (decode, SIFT, matching and two-view geometry of every adjacent pair), the
    count of each configuration and the seconds of each step."""
    start = time.perf_counter()
    greys = grey_frames(path)
    decoded = time.perf_counter()
    feats = [colmap.features(g) for g in greys]
    extracted = time.perf_counter()
    configs: dict[str, int] = {}
    for a, b in zip(feats, feats[1:], strict=False):
        c = colmap.geometry(a, b, greys[0].shape)
        configs[c] = configs.get(c, 0) + 1
    end = time.perf_counter()
    steps = f"decode {decoded - start:.1f} s, SIFT {extracted - decoded:.1f} s, "
    steps += f"match + geometry {end - extracted:.1f} s"
    return len(greys) / (end - start), configs, steps


def colmap_regime(colmap: Colmap, path: Path) -> str:
    greys = grey_frames(path)
    c = colmap.geometry(colmap.features(greys[0]), colmap.features(greys[-1]), greys[0].shape)
    return "H" if c in H_CONFIGS else "F" if c in F_CONFIGS else "-"


def geocon_run(path: Path, preset_name: str) -> tuple[float, str, int]:
    """(frames per second end to end, gate label, frames) of ``score_clip`` with a preset."""
    from geocon_core.config import preset
    from geocon_core.scoring import score_clip

    start = time.perf_counter()
    record = score_clip(path, preset(preset_name), workers=THREADS)
    n = record.video.num_frames
    return n / (time.perf_counter() - start), record.gate.label, n


def gvgc(clips: list[Path], preset_name: str) -> None:
    """The peer's keep rate and GeoCon's finding on each clip, side by side."""
    from geocon_core.config import preset
    from geocon_core.scoring import score_clip
    from geocon_core.validation import PEER_NAME, peer_keep_rate

    print(f"{'clip':<34} {'keep rate':>9} {'1-keep':>7} {'s':>5}   {'clip score':>10} {'verdict':<13} {'s':>5}")
    for path in clips:
        peer = peer_keep_rate(path)
        start = time.perf_counter()
        record = score_clip(path, preset(preset_name), workers=THREADS)
        seconds = time.perf_counter() - start
        finding = record.finding()
        keep = "-" if peer.keep_rate is None else f"{peer.keep_rate:.3f}"
        score = "-" if finding.clip_score is None else f"{finding.clip_score:.3f}"
        one_minus = "-" if peer.score is None else f"{peer.score:.3f}"
        print(
            f"{path.name[:34]:<34} {keep:>9} {one_minus:>7} {peer.seconds:5.1f}   {score:>10} {finding.verdict:<13} "
            f"{seconds:5.1f}",
            flush=True,
        )
    print(f"peer: {PEER_NAME}; GeoCon: {preset_name} preset (clip score 0 sound .. 1 broken)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=120, help="frames of each speed clip (default 120)")
    ap.add_argument("--size", default="1024x720")
    ap.add_argument("--presets", default="paper,fast", help="GeoCon presets, comma-separated")
    ap.add_argument("--no-regime", action="store_true", help="skip the regime check on C1-C6")
    ap.add_argument(
        "--gvgc", nargs="*", type=Path, metavar="CLIP", help="the GVGC keep rate beside GeoCon's clip score (only)"
    )
    ap.add_argument("--gvgc-preset", default="audit", help="GeoCon's preset beside the keep rate (default audit)")
    args = ap.parse_args()
    if args.gvgc is not None:
        missing = [str(p) for p in args.gvgc if not p.exists()]
        if missing:
            raise SystemExit(f"no such clip: {', '.join(missing)}")
        families = ("C1", "C2", "C3", "C4", "C5", "C6")
        gvgc(args.gvgc or [render(f, "640x360", 24)[0] for f in families], args.gvgc_preset)
        return
    try:
        colmap = Colmap()
    except ImportError:
        raise SystemExit("pycolmap is not installed: bash scripts/bootstrap.sh peers") from None
    cv2.setNumThreads(THREADS)
    os.environ.setdefault("OMP_NUM_THREADS", str(THREADS))
    presets = [p.strip() for p in args.presets.split(",") if p.strip()]

    print(f"speed: {args.size}, {args.frames} frames, {THREADS} threads each", flush=True)
    print(f"{'clip':<22} {'tool':<16} {'frames/s':>9} {'GeoCon / pycolmap':>18}  note")
    for family, what in (("C4", "still camera, 2 movers"), ("C3", "lateral truck")):
        path, _ = render(family, args.size, args.frames)
        peer_fps, configs, steps = colmap_speed(colmap, path)
        print(f"{what:<22} {'pycolmap':<16} {peer_fps:9.2f} {'':>18}  {steps}; adjacent pairs: {configs}", flush=True)
        for name in presets:
            fps, label, _ = geocon_run(path, name)
            print(f"{what:<22} {'GeoCon ' + name:<16} {fps:9.2f} {fps / peer_fps:17.1f}x  gate {label}", flush=True)

    if args.no_regime:
        return
    print("\nregime (gate label) on C1-C6, 640x360, 24 frames; truth U is the gray zone, not counted")
    print(f"{'family':<8} {'truth':<6} {'pycolmap':<9} " + " ".join(f"{p:<8}" for p in presets))
    right = {k: 0 for k in ["pycolmap", *presets]}
    counted = 0
    for family in ("C1", "C2", "C3", "C4", "C5", "C6"):
        path, truth = render(family, "640x360", 24)
        peer = colmap_regime(colmap, path)
        labels = [geocon_run(path, p)[1] for p in presets]
        print(f"{family:<8} {truth:<6} {peer:<9} " + " ".join(f"{lab:<8}" for lab in labels), flush=True)
        if truth in ("H", "F"):
            counted += 1
            right["pycolmap"] += peer == truth
            for p, lab in zip(presets, labels, strict=True):
                right[p] += lab == truth
    print("right: " + ", ".join(f"{k} {v}/{counted}" for k, v in right.items()))


if __name__ == "__main__":
    sys.exit(main())
