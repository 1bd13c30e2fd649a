"""t_inf of the classical pose backend on synthetic layouts no threshold was chosen on.

    .venv/bin/python benchmarks/bench_tinf_layouts.py [--seeds 0:20] [--size 640x360]

Each seed draws a layout outside the six families: a textured far wall at 8-16 units with one to
three textured blocks between 2.5 units and the wall (size, place, yaw and contrast drawn too),
field of view 60 degrees. For each layout the camera moves from the identity by three motions
(a lateral truck, an arc around the scene's mean distance, a dolly with a sideways component) at
two true t_inf (0.07 and 0.15), and the first and last frames (seeded noise of 2 grey levels) go
through SIFT matching and :class:`~geocon_core.pose.ClassicalPose`, as the gate does. Prints the
ratio of measured to true t_inf per case, the share within 15% of the truth, the median and the
10th / 90th percentiles, and the worst case.
"""

from __future__ import annotations

import argparse
import dataclasses
import math

import cv2
import numpy as np

from geocon_core.geometry import intrinsics_from_fov, make_matcher, relative_pose, rotation_xyz, t_inf_from_pose
from geocon_core.pose import ClassicalPose
from geocon_core.synth import Scene, mean_scene_distance, pose_from_center, render_frame
from geocon_core.synth.families import _panel, _wall  # the families' plane builders, for new layouts

MOTIONS = ("truck", "arc", "dolly")
TRUE_T = (0.07, 0.15)


def layout(seed: int, w: int, h: int) -> Scene:
    """A far wall and one to three blocks, drawn from ``seed`` (a stream no family uses)."""
    rng = np.random.default_rng([seed, 2026])
    K = intrinsics_from_fov(w, h, 60.0)
    wall_z = rng.uniform(8, 16)
    planes = [_wall(rng, K, w, h, wall_z, 15, 2.5, contrast=rng.uniform(0.3, 1.0))]
    for i in range(int(rng.integers(1, 4))):
        z = rng.uniform(2.5, wall_z - 1.5)
        s = rng.uniform(0.6, 2.5) * z / 5
        centre = (rng.uniform(-0.4, 0.4) * z, rng.uniform(-0.2, 0.2) * z, z)
        size = (s, s * rng.uniform(0.6, 1.2))
        planes.append(
            _panel(rng, f"block{i}", K, centre, size, yaw=rng.uniform(-30, 30), contrast=rng.uniform(0.5, 1.0))
        )
    eye = np.stack([np.eye(4)] * 2)
    return Scene("layout", seed, w, h, 24.0, K, eye, tuple(planes), fov_x_deg=60.0)


def last_pose(motion: str, t: float, dist: float) -> np.ndarray:
    """The last camera of ``motion`` with a baseline of ``t`` times the mean scene distance."""
    if motion == "truck":
        return pose_from_center(np.eye(3), np.array([t * dist, 0.0, 0.0]))
    if motion == "dolly":
        return pose_from_center(np.eye(3), np.array([0.3 * t * dist, 0.0, t * dist]))
    theta = math.asin(t)  # an arc around the point at the mean distance, looking at it
    centre = np.array([dist * math.sin(theta), 0.0, dist * (1 - math.cos(theta))])
    return pose_from_center(rotation_xyz(-math.degrees(theta)), centre)


def grey(rgb: np.ndarray, seed: int) -> np.ndarray:
    noisy = rgb + np.random.default_rng(seed).normal(0, 2, rgb.shape)
    return cv2.cvtColor(np.clip(noisy, 0, 255).astype(np.uint8), cv2.COLOR_RGB2GRAY)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", default="0:20", help="first:end of the layout seeds")
    ap.add_argument("--size", default="640x360")
    args = ap.parse_args()
    first, end = (int(v) for v in args.seeds.split(":"))
    w, h = (int(v) for v in args.size.split("x"))
    full = np.ones((h, w), bool)
    cases: list[tuple[float, str]] = []
    for seed in range(first, end):
        scene = layout(seed, w, h)
        f0 = render_frame(scene, 0)
        dist = mean_scene_distance(f0.depth, scene.K)
        matcher = make_matcher("sift")
        a = matcher.extract(grey(f0.rgb, 1), full, 0, 1.0)
        line = []
        for motion in MOTIONS:
            for i, t in enumerate(TRUE_T):
                moved = dataclasses.replace(scene, T_cam_world=np.stack([np.eye(4), last_pose(motion, t, dist)]))
                truth = t_inf_from_pose(relative_pose(moved.T_cam_world[0], moved.T_cam_world[1]), dist)
                b = matcher.extract(grey(render_frame(moved, 1).rgb, 10 + i), full, 1, 1.0)
                x0, x1 = matcher.match(a, b)
                est = ClassicalPose().estimate(x0, x1, scene.K, seed=0)
                ratio = (est.t_inf or 0.0) / truth
                cases.append((ratio, f"seed {seed} {motion} {t}"))
                line.append(f"{motion[0]}{t}:{ratio:.2f}")
        print(
            f"seed {seed:3d}  wall {scene.background[0].origin[2]:4.1f}  blocks {len(scene.background) - 1}  "
            + " ".join(line)
        )
    ratios = np.array([r for r, _ in cases])
    worst = max(cases, key=lambda c: abs(c[0] - 1))
    p10, p90 = np.percentile(ratios, [10, 90])
    print(
        f"{len(ratios)} cases: {np.mean(np.abs(ratios - 1) <= 0.15):.0%} within 15% of the truth; "
        f"median {np.median(ratios):.2f}, p10 {p10:.2f}, p90 {p90:.2f}; worst {worst[0]:.2f} ({worst[1]})"
    )


if __name__ == "__main__":
    main()
