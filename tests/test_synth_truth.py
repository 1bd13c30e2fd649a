"""The synthetic ground truth checked against the pixels: features are matched in the decoded
videos (or rendered frames) by OpenCV and compared with what the ground truth predicts."""

from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest

from geocon_core.bench import REQUIRED_FIELDS
from geocon_core.geometry import (
    fundamental_from_pose,
    homography_from_rotation,
    sampson_distance,
    symmetric_transfer_error,
)
from geocon_core.synth import ClipPlan, build_scene, load_ground_truth, make_failure, render_frame

from .conftest import read_video, sift_matches


def sample(field: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Bilinear samples of an (H, W, 2) field at (N, 2) pixel positions."""
    m = pts.astype(np.float32).reshape(-1, 1, 2)
    return cv2.remap(field.astype(np.float32), m[..., 0], m[..., 1], cv2.INTER_LINEAR).reshape(-1, 2)


def test_pure_rotation_is_explained_by_K_R_Kinv(synth_dir):
    gt = load_ground_truth(synth_dir / "c2_rotation.gt.json")
    frames = read_video(synth_dir / gt.video_path)
    assert len(frames) == gt.num_frames
    assert gt.t_inf == 0.0 and gt.expected_gate == "H" and gt.rotation_deg > 5
    for t in (6, gt.num_frames - 1):
        x0, xt = sift_matches(frames[0], frames[t])
        assert len(x0) > 300
        R_t0 = gt.T_camB_camA(0, t)[:3, :3]
        err = symmetric_transfer_error(homography_from_rotation(gt.K, R_t0), x0, xt)
        assert np.median(err) < 0.3, f"frame {t}: median transfer error {np.median(err):.3f} px"
        assert np.mean(err < 1.0) > 0.95


def test_translation_is_epipolar_but_not_a_homography(synth_dir):
    gt = load_ground_truth(synth_dir / "c3_translation.gt.json")
    frames = read_video(synth_dir / gt.video_path)
    assert gt.expected_gate == "F" and gt.t_inf > 0.05
    t = gt.num_frames - 1
    x0, xt = sift_matches(frames[0], frames[t])
    assert len(x0) > 300
    F = fundamental_from_pose(gt.K, gt.K, gt.T_camB_camA(0, t))
    d = sampson_distance(F, x0, xt)
    assert np.median(d) < 0.5, f"median Sampson {np.median(d):.3f} px"
    assert np.mean(d < 1.0) > 0.9
    # No single homography explains the background: even the best one (MAGSAC++ at 2 px)
    # leaves a large share of correct correspondences out.
    H, inl = cv2.findHomography(x0, xt, cv2.USAC_MAGSAC, 2.0, maxIters=5000, confidence=0.9999)
    good = d < 1.0
    h_ir = np.mean(symmetric_transfer_error(H, x0[good], xt[good]) <= 2.0)
    assert h_ir < 0.75, f"a homography explains {h_ir:.0%} of the true correspondences"


def test_t_inf_matches_a_two_view_reconstruction(synth_dir):
    """t_inf from the ground truth agrees with one recomputed from matches: relative pose from
    the essential matrix, triangulated points normalised to unit mean distance."""
    gt = load_ground_truth(synth_dir / "c3_translation.gt.json")
    frames = read_video(synth_dir / gt.video_path)
    x0, xt = sift_matches(frames[0], frames[-1])
    E, inl = cv2.findEssentialMat(x0, xt, gt.K, cv2.RANSAC, 0.999, 0.5)
    _, R, t, inl = cv2.recoverPose(E, x0, xt, gt.K, mask=inl)
    keep = inl.ravel() > 0
    P0 = gt.K @ np.hstack([np.eye(3), np.zeros((3, 1))])
    P1 = gt.K @ np.hstack([R, t])
    X = cv2.triangulatePoints(P0, P1, x0[keep].T, xt[keep].T)
    X = (X[:3] / X[3]).T
    center_T = -R.T @ t.ravel()  # last camera centre in first-camera coordinates, |t| = 1
    t_inf_est = np.max(np.abs(center_T)) / np.linalg.norm(X, axis=1).mean()
    assert t_inf_est == pytest.approx(gt.t_inf, rel=0.2)
    # and the direction of travel agrees with the ground-truth pose
    true_dir = gt.T_cam0_camT[:3, 3] / np.linalg.norm(gt.T_cam0_camT[:3, 3])
    assert float(center_T @ true_dir) > 0.99


def test_static_camera_frames_agree_outside_objects(synth_dir):
    gt = load_ground_truth(synth_dir / "c4_objects.gt.json")
    assert gt.t_inf == 0.0 and gt.expected_gate == "H"
    frames = read_video(synth_dir / gt.video_path)
    masks = [
        cv2.imread(str(synth_dir / gt.masks_path / f"{t:05d}.png"), cv2.IMREAD_UNCHANGED) for t in range(gt.num_frames)
    ]
    static = (masks[0] == 0) & (masks[-1] == 0)
    diff = np.abs(frames[0].astype(int) - frames[-1].astype(int)).max(axis=2)
    assert np.median(diff[static]) <= 2  # compression noise only
    assert np.median(diff[masks[-1] > 0]) > 10  # the objects moved


def test_object_masks_cover_the_rendered_objects(synth_dir):
    scene = build_scene("C4", seed=3, num_frames=24)
    gt = load_ground_truth(synth_dir / "c4_objects.gt.json")
    assert [o.object_id for o in gt.objects] == [1, 2] and all(o.rigid for o in gt.objects)
    for t in (0, 11, 23):
        with_obj = render_frame(scene, t)
        without = render_frame(scene, t, with_objects=False)
        changed = np.any(with_obj.rgb != without.rgb, axis=2)
        mask = with_obj.labels > 0
        iou = np.count_nonzero(changed & mask) / np.count_nonzero(changed | mask)
        assert iou > 0.97, f"frame {t}: IoU {iou:.3f}"
        on_disk = cv2.imread(str(synth_dir / gt.masks_path / f"{t:05d}.png"), cv2.IMREAD_UNCHANGED)
        np.testing.assert_array_equal(on_disk, with_obj.labels)
        assert gt.masked_share[t] == pytest.approx(mask.mean())
        for oid in (1, 2):
            assert (t in gt.objects[oid - 1].visible_frames) == bool(np.any(with_obj.labels == oid))


def test_breathing_moves_background_points_by_the_severity(synth_dir):
    gt = load_ground_truth(synth_dir / "c1_static__breathing-s3.gt.json")
    assert gt.failure is not None and gt.failure.kind == "breathing" and gt.failure.severity == 3.0
    scene = build_scene("C1", seed=3, num_frames=24)
    failure = make_failure("breathing", scene, 3.0)
    clean = read_video(synth_dir / "c1_static.mp4")
    warped = read_video(synth_dir / gt.video_path)
    t = 6  # sin(2 pi 6 / 24) = 1: the peak of the breathing cycle
    field = failure.displacement(t)
    assert np.linalg.norm(field, axis=2).max() == pytest.approx(3.0)
    xc, xw = sift_matches(clean[t], warped[t])
    measured = xw - xc
    # damaged pixel x shows the clean content of x - d(x): a point at xc appears at xw = xc + d(xw)
    predicted = sample(field, xw)
    err = np.linalg.norm(measured - predicted, axis=1)
    assert len(xc) > 300 and np.median(err) < 0.3
    mag = np.linalg.norm(measured, axis=1)
    assert 0.75 * 3.0 < np.percentile(mag, 99) < 1.1 * 3.0
    # frame 0 is unwarped
    x0c, x0w = sift_matches(clean[0], warped[0])
    assert np.median(np.linalg.norm(x0w - x0c, axis=1)) < 0.1


@pytest.mark.parametrize("severity", [2.0, 6.0])
def test_slide_moves_exactly_one_layer(severity):
    scene = build_scene("C3", seed=5, width=480, height=272, num_frames=12)
    failure = make_failure("slide", scene, severity)
    t = 11
    clean, slid = render_frame(scene, t), render_frame(scene, t, failure)
    layer = clean.surfaces.index(failure.layer)
    on_layer = (clean.surface == layer) & (slid.surface == layer)
    x1, x2 = sift_matches(clean.rgb, slid.rgb)
    at = clean.surface[np.round(x1[:, 1]).astype(int), np.round(x1[:, 0]).astype(int)]
    moved = x2 - x1
    assert np.allclose(np.median(moved[at == layer], axis=0), failure.shift(t), atol=0.15)
    assert np.linalg.norm(failure.shift(t)) == pytest.approx(severity)
    others = (at != layer) & (at >= 0)
    assert np.median(np.linalg.norm(moved[others], axis=1)) < 0.05
    assert on_layer.any()


def test_missing_parallax_makes_a_translating_view_one_homography():
    scene = build_scene("C3", seed=2, width=480, height=272, num_frames=12)
    flat = make_failure("missing_parallax", scene, 1.0)
    f0, fl = render_frame(scene, 0, flat), render_frame(scene, 11, flat)
    np.testing.assert_array_equal(f0.rgb, render_frame(scene, 0).rgb)
    x0, xt = sift_matches(f0.rgb, fl.rgb)
    H, _ = cv2.findHomography(x0, xt, cv2.USAC_MAGSAC, 1.0, maxIters=5000, confidence=0.9999)
    err = symmetric_transfer_error(H, x0, xt)
    assert np.mean(err < 1.0) > 0.9
    # the intact scene is not one homography (same matcher, same threshold)
    c0, ct = sift_matches(render_frame(scene, 0).rgb, render_frame(scene, 11).rgb)
    Hc, _ = cv2.findHomography(c0, ct, cv2.USAC_MAGSAC, 1.0, maxIters=5000, confidence=0.9999)
    assert np.mean(symmetric_transfer_error(Hc, c0, ct) < 1.0) < 0.75


def test_elastic_warp_moves_object_content_by_the_field():
    scene = build_scene("C4", seed=1, num_frames=24)
    failure = make_failure("elastic", scene, 5.0)
    t = 4  # sin(2 pi 4 / 16) = 1
    rigid, elastic = render_frame(scene, t), render_frame(scene, t, failure)
    field = failure.displacement(scene, t)
    obj = rigid.labels == failure.object_id
    assert np.linalg.norm(field[obj], axis=1).max() == pytest.approx(5.0, rel=0.05)
    x1, x2 = sift_matches(rigid.rgb, elastic.rgb, mask1=cv2.erode(obj.astype(np.uint8), np.ones((9, 9))) > 0)
    assert len(x1) > 10
    predicted = sample(field, x2)
    assert np.median(np.linalg.norm((x2 - x1) - predicted, axis=1)) < 0.5
    # densely: the elastic frame is the rigid frame re-sampled at x - d(x) inside the object
    gy, gx = np.mgrid[0 : scene.height, 0 : scene.width].astype(np.float32)
    resampled = cv2.remap(
        rigid.rgb, gx - field[..., 0].astype(np.float32), gy - field[..., 1].astype(np.float32), cv2.INTER_LINEAR
    )
    inner = (
        cv2.erode(
            ((rigid.labels == failure.object_id) & (elastic.labels == failure.object_id)).astype(np.uint8),
            np.ones((11, 11)),
        )
        > 0
    )
    warped_err = np.abs(resampled.astype(int) - elastic.rgb.astype(int))[inner].mean()
    unwarped_err = np.abs(rigid.rgb.astype(int) - elastic.rgb.astype(int))[inner].mean()
    assert warped_err < 2.0 and unwarped_err > 4 * warped_err, (warped_err, unwarped_err)
    # nothing else changes
    untouched = (rigid.labels != failure.object_id) & (elastic.labels != failure.object_id)
    np.testing.assert_array_equal(rigid.rgb[untouched], elastic.rgb[untouched])
    assert failure.non_rigid_object_ids() == {failure.object_id}


def test_boiling_changes_only_its_region_on_a_static_camera():
    scene = build_scene("C1", seed=4, width=320, height=180, num_frames=6)
    boil = make_failure("boiling", scene, 0.8)
    fa, fb = render_frame(scene, 2, boil), render_frame(scene, 3, boil)
    changed = np.any(fa.rgb != fb.rgb, axis=2)
    on_plane = fa.surface == fa.surfaces.index(boil.plane_name)
    x0, y0, x1, y1 = boil.image_box0
    inside = np.zeros_like(changed)
    inside[math.floor(y0) : math.ceil(y1), math.floor(x0) : math.ceil(x1)] = True
    assert changed[inside & on_plane].mean() > 0.9  # where the boiling surface is visible
    assert not changed[~cv2.dilate(inside.astype(np.uint8), np.ones((5, 5))).astype(bool)].any()


def test_letterbox_bars_are_black_and_excluded(synth_dir):
    gt = load_ground_truth(synth_dir / "c5_complex__letterbox-s0.1.gt.json")
    frames = read_video(synth_dir / gt.video_path)
    x0, y0, x1, y1 = gt.content_box
    assert (x0, x1) == (0, gt.width) and y0 == round(0.1 * gt.height) and y1 == gt.height - y0
    for f in (frames[0], frames[-1]):
        assert f[: y0 - 2].max() <= 16 and f[y1 + 2 :].max() <= 16  # 4:2:0 chroma bleeds 2 rows
        assert f[y0 + 2 : y1 - 2].mean() > 40


def test_ground_truth_round_trips_and_sidecar_has_spec_fields(synth_dir, tmp_path):
    gt = load_ground_truth(synth_dir / "c3_translation.gt.json")
    gt.write(tmp_path / "again.gt.json")
    again = load_ground_truth(tmp_path / "again.gt.json")
    np.testing.assert_array_equal(again.T_cam_world, gt.T_cam_world)
    np.testing.assert_array_equal(again.K, gt.K)
    assert again.t_inf == gt.t_inf and again.objects == gt.objects and again.failure == gt.failure
    meta = json.loads((synth_dir / "c3_translation.meta.json").read_text())
    for key in REQUIRED_FIELDS:
        assert key in meta, key
    assert meta["category"] == "C3" and meta["resolution"] == [640, 360] and meta["duration"] == pytest.approx(1.0)
    assert (synth_dir / meta["masks_path"]).is_dir()
    warped = json.loads((synth_dir / "c1_static__breathing-s3.meta.json").read_text())
    clean = json.loads((synth_dir / "c1_static.meta.json").read_text())
    assert warped["scene_id"] == clean["scene_id"] and warped["model"] != clean["model"]


def test_expected_gates_follow_the_families(synth_dir):
    expected = {"c1_static": "H", "c2_rotation": "H", "c3_translation": "F", "c4_objects": "H"}
    for cid, gate in expected.items():
        gt = load_ground_truth(synth_dir / f"{cid}.gt.json")
        assert gt.expected_gate == gate and gt.expected_gate_binary == gate
    # C5 moves the camera too; C6 is checked on a small render
    assert load_ground_truth(synth_dir / "c5_complex__letterbox-s0.1.gt.json").expected_gate == "F"


def test_plan_rejects_unknown_names_and_bad_severities():
    from geocon_core.synth import plan_clips

    with pytest.raises(ValueError, match="valid: C1"):
        plan_clips("C9")
    with pytest.raises(ValueError, match="valid: breathing"):
        plan_clips("C1", "melting")
    with pytest.raises(ValueError, match=r"must be in \(0, 1\]"):
        plan_clips("C3", "missing_parallax", 1.5)
    with pytest.raises(ValueError, match="needs one of the families"):
        plan_clips("C1", "elastic")
    assert ClipPlan("C4", "elastic", 4.0).clip_id == "c4_objects__elastic-s4"
    names = [p.clip_id for p in plan_clips("all")]
    assert len(names) == 14 and len(set(names)) == 14  # six families and eight failure variants
