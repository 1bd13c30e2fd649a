"""Dense two-view clouds (``geocon_core.dense_cloud``) against rendered truth: on the synthetic
translation families the flow of the first/last pair, triangulated with the true pose, gives tens
of thousands of points whose depth matches the rendered depth; a breathing background turns far
more of a window's points into epipolar outliers than a rigid one; a camera that only rotates
gives an empty cloud that says why."""

from __future__ import annotations

import numpy as np
import pytest

from geocon_core.dense_cloud import KIND_OUTLIER, dense_cloud
from geocon_core.flow import make_flow_backend
from geocon_core.reader import iter_frames, probe_clip
from geocon_core.synth import ClipPlan, write_clip
from geocon_core.synth.families import build_scene
from geocon_core.synth.render import render_frame

W, H, N = 640, 360, 12


@pytest.fixture(scope="module")
def clips(tmp_path_factory):
    out = tmp_path_factory.mktemp("dense")
    found = {}
    for plan in (ClipPlan("C3"), ClipPlan("C5"), ClipPlan("C3", "breathing", 3.0), ClipPlan("C2")):
        gt = write_clip(plan, out, width=W, height=H, num_frames=N)
        frames = list(iter_frames(probe_clip(out / f"{gt.clip_id}.mp4")))
        found[gt.clip_id] = (plan, gt, frames)
    return found


def _cloud(gt, frames, a: int, b: int):
    T = gt.T_cam_world[a] @ np.linalg.inv(gt.T_cam_world[b])  # camera b in camera a's coordinates
    grays = [f.gray for f in frames[a : b + 1]]
    return dense_cloud(frames[a].rgb, grays, gt.K, T, make_flow_backend("dis"), content=frames[a].content)


@pytest.mark.parametrize("clip_id", ["c3_translation", "c5_complex"])
def test_first_last_cloud_is_dense_and_on_the_true_surfaces(clips, clip_id):
    plan, gt, frames = clips[clip_id]
    cloud = _cloud(gt, frames, 0, N - 1)
    assert len(cloud) >= 20_000
    depth = render_frame(build_scene(plan.family, seed=0, width=W, height=H, num_frames=N), 0).depth
    px = np.round(cloud.pixel).astype(int)
    truth = depth[px[:, 1], px[:, 0]]
    seen = np.isfinite(truth)
    assert seen.mean() > 0.99
    # the depth error along the ray bounds the distance to the true plane from above
    assert np.median(np.abs(cloud.xyz[seen, 2] - truth[seen]) / truth[seen]) <= 0.02


def test_a_breathing_background_is_marked_as_outliers(clips):
    _, gt, frames = clips["c3_translation"]
    _, gt_b, frames_b = clips["c3_translation__breathing-s3"]
    clean = _cloud(gt, frames, 0, N // 2).share(KIND_OUTLIER)
    breathing = _cloud(gt_b, frames_b, 0, N // 2).share(KIND_OUTLIER)
    assert clean < 0.01 and breathing >= 3 * max(clean, 0.005), (clean, breathing)


def test_a_rotating_camera_gives_an_empty_cloud_that_says_why(clips):
    _, gt, frames = clips["c2_rotation"]
    cloud = _cloud(gt, frames, 0, N - 1)
    assert len(cloud) == 0 and "no parallax" in cloud.note
