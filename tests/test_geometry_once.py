"""The geometry functions shared by the pose backend and the motion segmentation: each formula
is defined once in :mod:`geocon_core.geometry`; clean two-view scenes give zero error and the
true decomposition."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from geocon_core.geometry import (
    apply_homography,
    cheirality_pose,
    epipolar_line_distance,
    fundamental_from_pose,
    in_front_least_squares,
    in_front_triangulated,
    intrinsics_from_fov,
    make_pose,
    rotation_from_axis_angle,
    rotation_xyz,
    sampson_distance,
    skew,
    triangulate_normalised,
)
from geocon_core.pose import default_intrinsics


def _scene(seed: int = 0, n: int = 200):
    """Points in front of camera 0, a camera 1 with X_1 = R X_0 + t, normalised coordinates."""
    rng = np.random.default_rng(seed)
    X = np.c_[rng.uniform(-2, 2, n), rng.uniform(-1.5, 1.5, n), rng.uniform(3, 9, n)]
    R = rotation_xyz(4.0, -2.0, 1.0).T
    t = np.array([0.6, -0.1, 0.2])
    X1 = X @ R.T + t
    return X, R, t, X[:, :2] / X[:, 2:], X1[:, :2] / X1[:, 2:]


def test_rotation_from_axis_angle_matches_opencv() -> None:
    for w in (np.array([0.1, -0.2, 0.3]), np.array([1e-14, 0.0, 0.0]), np.array([0.0, 2.5, 0.0])):
        expected = cv2.Rodrigues(w)[0]
        assert np.allclose(rotation_from_axis_angle(w), expected, atol=1e-12)


def test_sampson_signed_and_absolute_agree() -> None:
    _, R, t, n0, n1 = _scene()
    E = skew(t) @ R
    noisy = n1 + np.random.default_rng(1).normal(0, 1e-3, n1.shape)
    signed = sampson_distance(E, n0, noisy, signed=True)
    assert np.array_equal(np.abs(signed), sampson_distance(E, n0, noisy))
    assert (signed < 0).any() and (signed > 0).any()
    assert np.abs(sampson_distance(E, n0, n1)).max() < 1e-12


def test_epipolar_line_distance_is_zero_on_clean_matches() -> None:
    K = intrinsics_from_fov(640, 360, 60.0)
    X, R, t, _, _ = _scene()
    x0 = X @ K.T
    x0 = x0[:, :2] / x0[:, 2:]
    X1 = X @ R.T + t
    x1 = X1 @ K.T
    x1 = x1[:, :2] / x1[:, 2:]
    F = fundamental_from_pose(K, K, make_pose(R, t))
    assert epipolar_line_distance(F, x0, x1).max() < 1e-6
    moved = x1 + np.array([0.0, 3.0])
    assert epipolar_line_distance(F, x0, moved).min() > 0


def test_apply_homography_points_at_infinity() -> None:
    H = np.array([[1.0, 0, 0], [0, 1, 0], [1.0, 0, 0]])  # x = 0 maps to infinity
    x = np.array([[0.0, 5.0], [2.0, 3.0]])
    assert np.isnan(apply_homography(H, x)[0]).all()
    assert np.isinf(apply_homography(H, x, at_infinity=np.inf)[0]).all()
    assert np.allclose(apply_homography(H, x)[1], [1.0, 1.5])


@pytest.mark.parametrize("which", ["triangulated", "least_squares"])
def test_cheirality_pose_recovers_the_true_motion(which: str) -> None:
    X, R, t, n0, n1 = _scene()
    E = skew(t) @ R
    r0, r1 = np.c_[n0, np.ones(len(n0))], np.c_[n1, np.ones(len(n1))]

    def in_front(Rc: np.ndarray, tc: np.ndarray) -> np.ndarray:
        if which == "triangulated":
            return in_front_triangulated(n0, n1, Rc, tc)
        return in_front_least_squares(r0, r1, Rc, tc)

    best = cheirality_pose(E, in_front)
    assert best is not None
    Rb, tb, ok = best
    assert ok.all()
    assert np.allclose(Rb, R, atol=1e-9)
    assert np.allclose(tb / np.linalg.norm(tb), t / np.linalg.norm(t), atol=1e-9)
    Xt = triangulate_normalised(n0, n1, Rb, tb * np.linalg.norm(t) / np.linalg.norm(tb))
    assert np.allclose(Xt, X, atol=1e-6)


def test_default_intrinsics_is_the_fov_pinhole_shifted_to_the_content() -> None:
    K = default_intrinsics((10, 20, 650, 380), 60.0)
    K0 = intrinsics_from_fov(640, 360, 60.0)
    assert np.array_equal(K[:, :2], K0[:, :2])
    assert K[0, 2] == K0[0, 2] + 10 and K[1, 2] == K0[1, 2] + 20
