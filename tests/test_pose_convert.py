"""``geocon pose-log``: COLMAP models and DUSt3R scenes of a known geometry become pose logs with
the true relative pose on the unit mean scene distance, whatever the reconstruction's world frame
and units; a synthetic clip gated with such a log gets its true t_inf."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from typer.testing import CliRunner

from geocon_core.pose import PoseLog
from geocon_core.pose.convert import from_colmap, from_dust3r, rotation_from_quaternion
from geocon_viewer.cli import app


def _rigid(R: np.ndarray, t) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


def _scene(rng, mean_distance: float, n: int = 300) -> np.ndarray:
    """Points (n, 3) in first-camera coordinates, in front of it, whose mean distance from it is
    ``mean_distance`` exactly."""
    pts = np.column_stack([rng.uniform(-2, 2, n), rng.uniform(-1.5, 1.5, n), rng.uniform(3, 9, n)])
    return pts * (mean_distance / np.linalg.norm(pts, axis=1).mean())


def _write_colmap(folder: Path, T_world_cams: list[np.ndarray], world_pts: np.ndarray, seen_by_first: int) -> None:
    """A COLMAP text model: images named frame_000.png ... (the first observes the first
    ``seen_by_first`` points), every point in points3D.txt."""
    folder.mkdir(parents=True)
    (folder / "cameras.txt").write_text("# Camera list\n1 PINHOLE 640 360 500 500 320 180\n")
    lines = ["# Image list with two lines of data per image:"]
    for k, T_wc in enumerate(T_world_cams):
        T_cw = np.linalg.inv(T_wc)
        x, y, z, w = (float(v) for v in Rotation.from_matrix(T_cw[:3, :3]).as_quat())
        tx, ty, tz = (float(v) for v in T_cw[:3, 3])
        lines.append(f"{k + 1} {w!r} {x!r} {y!r} {z!r} {tx!r} {ty!r} {tz!r} 1 frame_{k:03d}.png")
        ids = range(seen_by_first) if k == 0 else range(0)  # COLMAP leaves the line empty without points
        lines.append(" ".join([*(f"{100.0 + i} {50.0 + i} {i + 1}" for i in ids), *(["7.0 8.0 -1"] if k == 0 else [])]))
    (folder / "images.txt").write_text("\n".join(lines) + "\n")
    pts = [
        f"{i + 1} {float(x)!r} {float(y)!r} {float(z)!r} 128 128 128 0.5 1 0" for i, (x, y, z) in enumerate(world_pts)
    ]
    (folder / "points3D.txt").write_text("# 3D point list\n" + "\n".join(pts) + "\n")


def _case(seed: int, world_scale: float):
    """A first->last pose, the first camera's points, and the same scene in a random world frame
    and unit: (T_cam0_camT on the unit scale, cam-to-world poses of 3 cameras, world points,
    points seen by the first camera)."""
    rng = np.random.default_rng(seed)
    T_rel = _rigid(
        Rotation.from_euler("xyz", rng.uniform(-4, 4, 3), degrees=True).as_matrix(), rng.uniform(-0.08, 0.08, 3)
    )
    pts_cam0 = _scene(rng, 1.0)
    T_world_cam0 = _rigid(Rotation.random(random_state=seed).as_matrix(), rng.uniform(-50, 50, 3))
    T_w0 = T_world_cam0.copy()  # the world in other units: translations and points scaled
    T_w0[:3, 3] *= world_scale
    T_mid = T_rel.copy()
    T_mid[:3, 3] *= 0.5
    cams = []
    for T in (np.eye(4), T_mid, T_rel):
        Tc = T.copy()
        Tc[:3, 3] *= world_scale
        cams.append(T_w0 @ Tc)
    world = (pts_cam0 * world_scale) @ T_w0[:3, :3].T + T_w0[:3, 3]
    return T_rel, cams, world


@pytest.mark.parametrize("seed,world_scale", [(1, 1.0), (2, 37.5), (3, 0.01)])
def test_colmap_model_gives_the_true_pose_on_the_unit_scale(tmp_path, seed, world_scale):
    T_rel, cams, world = _case(seed, world_scale)
    extra = np.random.default_rng(9).uniform(-1e3, 1e3, (50, 3))  # points the first camera does not see
    _write_colmap(tmp_path / "model", cams, np.vstack([world, extra]), seen_by_first=len(world))
    log = from_colmap(tmp_path / "model")
    (tmp_path / "p.json").write_text(json.dumps(log))
    pose = PoseLog(tmp_path / "p.json")
    assert np.allclose(pose.T_unit, T_rel, atol=1e-9)
    assert pose.t_inf == pytest.approx(np.abs(T_rel[:3, 3]).max(), rel=1e-9)
    middle = from_colmap(tmp_path / "model", last="frame_001.png")
    assert np.allclose(np.array(middle["T_cam0_camT"])[:3, 3] / middle["mean_scene_distance"], T_rel[:3, 3] / 2)


def test_dust3r_scene_gives_the_true_pose_on_the_unit_scale(tmp_path):
    T_rel, cams, world = _case(4, 2.5)
    grid = np.full((20, 30, 3), np.nan)  # a point map with holes and a mask of confident points
    grid.reshape(-1, 3)[: len(world)] = world
    mask = np.isfinite(grid).all(axis=2)
    np.savez(tmp_path / "scene.npz", poses=np.stack(cams), pts3d=grid, mask=mask)
    (tmp_path / "p.json").write_text(json.dumps(from_dust3r(tmp_path / "scene.npz")))
    pose = PoseLog(tmp_path / "p.json")
    assert np.allclose(pose.T_unit, T_rel, atol=1e-9)
    # every view's point map and mask, as the global aligner returns them
    np.savez(tmp_path / "all.npz", poses=np.stack(cams), pts3d=np.stack([grid] * 3), mask=np.stack([mask] * 3))
    assert from_dust3r(tmp_path / "all.npz") == from_dust3r(tmp_path / "scene.npz") | {
        "source": from_dust3r(tmp_path / "all.npz")["source"]
    }


def test_quaternion_convention_is_colmaps():
    q = Rotation.from_euler("z", 90, degrees=True).as_quat()  # (x, y, z, w)
    R = rotation_from_quaternion(np.array([q[3], q[0], q[1], q[2]]))
    assert np.allclose(R @ [1, 0, 0], [0, 1, 0])


def test_cli_gates_a_synthetic_clip_with_a_colmap_pose(tmp_path):
    """The ground truth of a translating synthetic clip, written as a COLMAP model in another
    frame and unit, converted by `geocon pose-log` and given to `geocon score --pose-log`: the
    gate reads the true t_inf."""
    from geocon_core.synth import ClipPlan, write_clip

    write_clip(ClipPlan("C3"), tmp_path, seed=2, width=160, height=96, num_frames=6)
    clip = tmp_path / "c3_translation.mp4"
    gt = json.loads(clip.with_suffix(".gt.json").read_text())
    T_rel = np.array(gt["T_cam0_camT"])
    T_rel[:3, 3] /= gt["mean_scene_distance"]
    rng = np.random.default_rng(5)
    pts = _scene(rng, 1.0)
    T_w0 = _rigid(Rotation.random(random_state=5).as_matrix(), [3.0, -1.0, 2.0])
    cams = [T_w0, T_w0 @ T_rel]
    _write_colmap(tmp_path / "model", cams, pts @ T_w0[:3, :3].T + T_w0[:3, 3], seen_by_first=len(pts))
    runner = CliRunner()
    res = runner.invoke(app, ["pose-log", str(tmp_path / "model"), "--out", str(tmp_path / "pose.json")])
    assert res.exit_code == 0, res.output
    res = runner.invoke(
        app,
        [
            "score",
            str(clip),
            "--preset",
            "fast",
            "--json",
            "--pose-log",
            str(tmp_path / "pose.json"),
            "--out",
            str(tmp_path / "r"),
        ],
    )
    assert res.exit_code == 0, res.output
    summary = json.loads(res.stdout)
    assert summary["gate"]["t_inf"] == pytest.approx(gt["t_inf"], rel=1e-9)
    assert summary["gate"]["label"] == gt["expected_gate"]


def test_bad_sources_are_one_sentence(tmp_path):
    runner = CliRunner()
    cases = {
        "missing": (tmp_path / "nope.npz", "does not exist"),
        "empty-model": (tmp_path / "model", "images.txt does not exist"),
        "npz-without-pts3d": (tmp_path / "s.npz", "lacks pts3d"),
        "random-bytes": (tmp_path / "r.npz", "cannot be read as an .npz file"),
    }
    (tmp_path / "model").mkdir()
    np.savez(tmp_path / "s.npz", poses=np.stack([np.eye(4)] * 2))
    (tmp_path / "r.npz").write_bytes(np.random.default_rng(0).bytes(300))
    for name, (source, says) in cases.items():
        res = runner.invoke(app, ["pose-log", str(source), "--out", str(tmp_path / "p.json")])
        assert res.exit_code == 2 and says in res.stderr and res.stderr.count("\n") == 1, (name, res.stderr)
    assert not (tmp_path / "p.json").exists()
