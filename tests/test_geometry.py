"""Pure geometry functions against exact two-view scenes."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from geocon_core.geometry import (
    apply_homography,
    fundamental_from_pose,
    homography_from_plane,
    intrinsics_from_fov,
    invert_pose,
    make_pose,
    project,
    relative_pose,
    rotation_angle_deg,
    rotation_xyz,
    sampson_distance,
    symmetric_transfer_error,
    t_inf_from_pose,
)
from geocon_core.scoring import binary_gate, hysteresis_gate

K = intrinsics_from_fov(640, 360, 60.0)
angles = st.floats(-20, 20)
shifts = st.floats(-0.5, 0.5)


def test_intrinsics_give_the_requested_field_of_view():
    assert K[0, 2] == pytest.approx(319.5) and K[1, 2] == pytest.approx(179.5)
    # the left and right image borders (x = -0.5 and 639.5) lie 30 degrees off axis
    assert np.degrees(np.arctan((639.5 - K[0, 2]) / K[0, 0])) == pytest.approx(30.0)
    with pytest.raises(ValueError):
        intrinsics_from_fov(640, 360, 180.0)


@settings(max_examples=50, deadline=None)
@given(angles, angles, angles, shifts, shifts, shifts)
def test_plane_homography_and_fundamental_are_exact(yaw, pitch, roll, tx, ty, tz):
    rng = np.random.default_rng(0)
    T_2_1 = make_pose(rotation_xyz(yaw, pitch, roll), (tx, ty, tz))
    n = np.array([0.2, -0.1, 1.0])
    n /= np.linalg.norm(n)
    d = 5.0
    # points on the plane n . X = d, in front of both cameras
    uv = rng.uniform(-1, 1, (50, 2))
    basis = np.linalg.svd(n[None])[2][1:]
    X = d * n + uv @ basis
    x1, x2 = project(K, np.eye(4), X), project(K, T_2_1, X)
    H = homography_from_plane(K, K, T_2_1, n / d)
    assert np.abs(symmetric_transfer_error(H, x1, x2)).max() < 1e-6
    if np.linalg.norm([tx, ty, tz]) > 1e-3:
        Xg = np.column_stack([rng.uniform(-2, 2, 50), rng.uniform(-1, 1, 50), rng.uniform(3, 9, 50)])
        F = fundamental_from_pose(K, K, T_2_1)
        assert sampson_distance(F, project(K, np.eye(4), Xg), project(K, T_2_1, Xg)).max() < 1e-6


def test_sampson_distance_is_first_order_geometric_distance():
    """Moving x2 off its epipolar line by delta (x1 fixed) gives a Sampson distance of
    delta * |l2| / sqrt(|l2|^2 + |l1|^2), which is delta / sqrt(2) for a rectified pair."""
    T = make_pose(np.eye(3), (-0.1, 0.0, 0.0))  # rectified stereo: epipolar lines are rows
    F = fundamental_from_pose(K, K, T)
    x1 = np.array([[100.0, 50.0], [300.0, 200.0]])
    for delta in (0.5, 2.0):
        x2 = x1 + np.array([[-20.0, delta], [-10.0, -delta]])
        np.testing.assert_allclose(sampson_distance(F, x1, x2), delta / np.sqrt(2), rtol=1e-9)
    # not squared, and invariant to the scale of F
    np.testing.assert_allclose(sampson_distance(7 * F, x1, x2), sampson_distance(F, x1, x2))


def test_pose_helpers():
    R = rotation_xyz(10, -5, 3)
    T = make_pose(R, (1, 2, 3))
    np.testing.assert_allclose(T @ invert_pose(T), np.eye(4), atol=1e-12)
    assert rotation_angle_deg(rotation_xyz(yaw_deg=12)) == pytest.approx(12)
    T0 = make_pose(np.eye(3), (0, 0, 0))
    T1 = invert_pose(make_pose(rotation_xyz(30), (0.3, -0.2, 0.5)))  # world->cam of a camera at (0.3,-0.2,0.5)
    np.testing.assert_allclose(relative_pose(T0, T1)[:3, 3], [0.3, -0.2, 0.5])
    assert t_inf_from_pose(relative_pose(T0, T1), 10.0) == pytest.approx(0.05)
    with pytest.raises(ValueError):
        t_inf_from_pose(T1, 0.0)
    pts = np.array([[1.0, 2.0]])
    np.testing.assert_allclose(apply_homography(np.eye(3), pts), pts)


@pytest.mark.parametrize(
    "t_inf, hyst, binary",
    [
        (0.0, "H", "H"),
        (0.03, "H", "H"),
        (0.0301, "U", "H"),
        (0.04, "U", "H"),
        (0.0401, "U", "F"),
        (0.05, "F", "F"),
        (0.3, "F", "F"),
    ],
)
def test_gate_thresholds(t_inf, hyst, binary):
    assert hysteresis_gate(t_inf) == hyst
    assert binary_gate(t_inf) == binary
