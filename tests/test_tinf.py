"""t_inf of the classical pose backend against the exact truth of multi-depth synthetic scenes.

The truth (``geocon_core.synth``) scales the first->last translation by the mean distance of every
pixel of the first frame; the estimate triangulates the SIFT matches. Matched points crowd on the
textured near layers, so a plain mean over the points reads the scene too near and t_inf too high;
the backend weights each point by the image area it stands for (``PoseConfig.scale_area_grid``)."""

from __future__ import annotations

import dataclasses
import math

import cv2
import numpy as np
import pytest

from geocon_core.geometry import intrinsics_from_fov, make_matcher, relative_pose, rotation_xyz, t_inf_from_pose
from geocon_core.pose import ClassicalPose
from geocon_core.synth import Scene, build_scene, mean_scene_distance, pose_from_center, render_frame
from geocon_core.synth.families import _panel, _wall

W, H = 640, 360
T_TRUE = (0.02, 0.05, 0.12, 0.2)


def _last_pose(motion: str, t: float, dist: float) -> np.ndarray:
    """Camera T: a lateral truck, or an arc about the point at the mean distance on the axis."""
    if motion == "truck":
        return pose_from_center(np.eye(3), np.array([t * dist, 0.0, 0.0]))
    th = math.asin(t)
    centre = np.array([dist * math.sin(th), 0.0, dist * (1.0 - math.cos(th))])
    return pose_from_center(rotation_xyz(-math.degrees(th)), centre)


def _grey(rgb: np.ndarray, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    noisy = np.clip(rgb + rng.normal(0.0, 2.0, rgb.shape), 0, 255).astype(np.uint8)
    return cv2.cvtColor(noisy, cv2.COLOR_RGB2GRAY)


@pytest.mark.parametrize("family", ["C3", "C5"])
@pytest.mark.parametrize("motion", ["truck", "arc"])
def test_t_inf_within_15_percent_of_truth(family: str, motion: str) -> None:
    scene = build_scene(family, seed=0, width=W, height=H, num_frames=2)
    f0 = render_frame(scene, 0)
    dist = mean_scene_distance(f0.depth, scene.K)
    matcher, backend = make_matcher("sift"), ClassicalPose()
    full = np.ones((H, W), bool)
    a = matcher.extract(_grey(f0.rgb, 1), full, 0, 1.0)
    bad = []
    for i, t in enumerate(T_TRUE):
        sc = dataclasses.replace(scene, T_cam_world=np.stack([np.eye(4), _last_pose(motion, t, dist)]))
        truth = t_inf_from_pose(relative_pose(sc.T_cam_world[0], sc.T_cam_world[1]), dist)
        b = matcher.extract(_grey(render_frame(sc, 1).rgb, 10 + i), full, 1, 1.0)
        x0, x1 = matcher.match(a, b)
        est = backend.estimate(x0, x1, scene.K, seed=0)
        assert est.pose_present and est.method == "essential", f"t={truth:.3f}: {est.method} {est.reason}"
        if abs(est.t_inf / truth - 1.0) > 0.15:
            bad.append(f"truth {truth:.4f} estimate {est.t_inf:.4f} (ratio {est.t_inf / truth:.3f})")
    assert not bad, f"{family} {motion}: t_inf off by more than 15 %:\n" + "\n".join(bad)


def test_area_weights_follow_image_area() -> None:
    """Points on a regular lattice share the image equally; a cluster in one corner shares about
    half of it, and a lone point opposite owns the other half (a plain mean gives it 1/51)."""
    from geocon_core.pose.classical import area_weights

    extent = (np.zeros(2), np.full(2, 100.0))
    lattice = np.stack(np.meshgrid(np.arange(10.0, 100, 20), np.arange(10.0, 100, 20)), axis=-1).reshape(-1, 2)
    assert np.array_equal(area_weights(lattice, extent, 50), np.full(25, 100.0))
    rng = np.random.default_rng(0)
    xy = np.vstack([rng.uniform(0, 10, (50, 2)), [[90.0, 90.0]]])
    w = area_weights(xy, extent, 50)
    assert w.sum() == 50 * 50
    assert 0.4 < w[-1] / w.sum() < 0.6
    assert np.array_equal(area_weights(xy, extent, 0), np.ones(len(xy)))


def _plain_far_wall_scene(seed: int) -> Scene:
    """A far wall of half contrast behind a slanted side panel and three richly textured boxes:
    SIFT finds most of its features on the boxes, while the wall covers much of the image."""
    rng = np.random.default_rng([seed, 77])
    K = intrinsics_from_fov(W, H, 60.0)
    planes = [
        _wall(rng, K, W, H, 12.0 + rng.uniform(-1, 1), 20, 3.0, contrast=0.5),
        _panel(rng, "side", K, (-2.6, 0.2, 5.5), (7.0, 2.5), yaw=50, contrast=0.5),
    ]
    for i, (x, y, z, s) in enumerate([(-1.4, 0.3, 2.6, 1.0), (1.2, 0.0, 3.5, 1.3), (0.1, -0.6, 5.0, 1.6)]):
        centre = (x + rng.uniform(-0.2, 0.2), y, z + rng.uniform(-0.3, 0.3))
        planes.append(_panel(rng, f"box{i}", K, centre, (s, 0.8 * s), yaw=rng.uniform(-25, 25)))
    return Scene(
        family="C3",
        seed=seed,
        width=W,
        height=H,
        fps=24.0,
        K=K,
        T_cam_world=np.stack([np.eye(4)] * 2),
        background=tuple(planes),
        objects=(),
        fov_x_deg=60.0,
        notes={},
    )


def test_features_crowding_near_layers_do_not_bias_t_inf() -> None:
    """With a plain far wall the matched points crowd on the near boxes: weighted equally they read
    t_inf 14-25 % high; weighted by image area the estimate comes back within 15 %."""
    scene = _plain_far_wall_scene(1)
    f0 = render_frame(scene, 0)
    dist = mean_scene_distance(f0.depth, scene.K)
    matcher = make_matcher("sift")
    full = np.ones((H, W), bool)
    a = matcher.extract(_grey(f0.rgb, 1), full, 0, 1.0)
    for i, t in enumerate((0.02, 0.05, 0.12)):
        sc = dataclasses.replace(scene, T_cam_world=np.stack([np.eye(4), _last_pose("truck", t, dist)]))
        truth = t_inf_from_pose(relative_pose(sc.T_cam_world[0], sc.T_cam_world[1]), dist)
        x0, x1 = matcher.match(a, matcher.extract(_grey(render_frame(sc, 1).rgb, 10 + i), full, 1, 1.0))
        area = ClassicalPose().estimate(x0, x1, scene.K, seed=0)
        points = ClassicalPose(scale_area_grid=0, trim=0.05).estimate(x0, x1, scene.K, seed=0)
        assert area.pose_present and points.pose_present
        print(f"truck {truth:.3f}: area-weighted {area.t_inf / truth:.3f}, points {points.t_inf / truth:.3f}")
        assert abs(area.t_inf / truth - 1.0) <= 0.15, f"t={truth:.3f}: ratio {area.t_inf / truth:.3f}"
        assert points.t_inf > area.t_inf
