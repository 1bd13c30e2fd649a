"""Pose logs from reconstructions run elsewhere: a COLMAP sparse model or a DUSt3R scene, turned
into the ``geocon-pose/1`` JSON that ``geocon score --pose-log`` reads (:mod:`.log`).

COLMAP (:func:`from_colmap`)
    A sparse model folder in COLMAP's text format (``cameras.txt``, ``images.txt``,
    ``points3D.txt``, as ``colmap model_converter --output_type TXT`` writes it). ``images.txt``
    gives each image's world-to-camera pose (``X_cam = R(q) X_world + t``, ``q = (qw, qx, qy,
    qz)``) and its 2D points with the id of the 3D point each observes. The first and the last
    frame are the images whose names sort first and last (or the names given). The pose log's
    ``T_cam0_camT = T_cam0_world @ inverse(T_camT_world)``; its ``mean_scene_distance`` is the
    mean distance from the first camera of the 3D points the first image observes, so the
    translation lands on GeoCon's scale (unit mean scene distance) whatever the model's units.
DUSt3R (:func:`from_dust3r`)
    An ``.npz`` with ``poses``, the cameras' cam-to-world matrices (N, 4, 4) in frame order, and
    ``pts3d``, the first view's point map in world coordinates (H, W, 3) or every view's (N, H,
    W, 3), with an optional boolean ``mask`` of the confident points (H, W), or (N, H, W): what
    ``scene.get_im_poses()``, ``scene.get_pts3d()`` and ``scene.get_masks()`` of DUSt3R's global
    aligner return, saved with ``numpy.savez``. The scale is that of the point map.

Both return the pose log as a dict; :func:`write_pose_log` checks it by reading it back
(:class:`~geocon_core.pose.log.PoseLog`) before it replaces ``out``.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from ..files import (
    COLMAP_TEXT,
    NPZ_ERRORS,
    POSE_SCENE,
    ReadRefused,
    npz_problem,
    parents_made,
    part_path,
    read_text,
    regular_file,
    replace_file,
)
from .log import POSE_LOG_FORMAT, PoseLog

__all__ = ["from_colmap", "from_dust3r", "write_pose_log", "rotation_from_quaternion"]


def rotation_from_quaternion(q: np.ndarray) -> np.ndarray:
    """The rotation matrix (3, 3) of a quaternion ``(w, x, y, z)`` (normalised first)."""
    w, x, y, z = np.asarray(q, float) / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def _lines(path: Path, keep_empty: bool = False) -> list[str]:
    """The data lines of a COLMAP text file (comments dropped; empty lines kept with
    ``keep_empty``, as images.txt needs: an image without 2D points has an empty second line,
    the last one too)."""
    if not path.exists():
        raise ValueError(f"{path} does not exist (a COLMAP text model holds cameras.txt, images.txt, points3D.txt)")
    try:
        text = read_text(path, COLMAP_TEXT)  # a regular file within its bound, or refused unread
    except ReadRefused as exc:
        if exc.reason == "encoding":
            raise ValueError(f"{path} cannot be read as text (UnicodeDecodeError)") from None
        raise ValueError(
            f"{path} is {exc.why} (a COLMAP text model holds cameras.txt, images.txt, points3D.txt)"
        ) from None
    lines = [line for line in text.splitlines() if not line.lstrip().startswith("#")]
    return lines if keep_empty else [line for line in lines if line.strip()]


def _colmap_images(path: Path) -> dict[str, tuple[np.ndarray, set[int]]]:
    """name -> (T_cam_world (4, 4), ids of the 3D points it observes)."""
    lines = _lines(path, keep_empty=True)
    out = {}
    k = 0
    while k < len(lines):
        if not lines[k].strip():  # stray blank lines between images
            k += 1
            continue
        head = lines[k].split()
        observed = lines[k + 1].split() if k + 1 < len(lines) else []  # the points line (may be empty)
        try:
            q, t = np.array(head[1:5], float), np.array(head[5:8], float)
            name = " ".join(head[9:])
            ids = {int(observed[i]) for i in range(2, len(observed), 3)} - {-1}
        except (ValueError, IndexError):
            what = "a COLMAP image line (IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME)"
            raise ValueError(f"{path}: line {k + 1} is not {what}") from None
        if not name or not np.isfinite(q).all() or not np.isfinite(t).all() or not np.linalg.norm(q) > 0:
            raise ValueError(f"{path}: image line {k + 1} has no name or a non-finite pose")
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = rotation_from_quaternion(q), t
        out[name] = (T, ids)
        k += 2
    if len(out) < 2:
        raise ValueError(f"{path}: holds {len(out)} registered image(s); the pose needs two")
    return out


def _colmap_points(path: Path, wanted: set[int]) -> np.ndarray:
    points = []
    for n, line in enumerate(_lines(path), start=1):
        fields = line.split()
        try:
            if int(fields[0]) in wanted:
                points.append([float(v) for v in fields[1:4]])
        except (ValueError, IndexError):
            raise ValueError(f"{path}: line {n} is not a COLMAP point line (POINT3D_ID X Y Z ...)") from None
    return np.array(points, float).reshape(-1, 3)


def _log(T_cam0_camT: np.ndarray, distance: float, source: str) -> dict[str, Any]:
    if not (math.isfinite(distance) and distance > 0):
        raise ValueError(f"{source}: the first camera sees no scene point in front of it; the scale is unknown")
    return {
        "format": POSE_LOG_FORMAT,
        "T_cam0_camT": [[float(v) for v in row] for row in T_cam0_camT],
        "scale": "metric",
        "mean_scene_distance": float(distance),
        "pose_present": True,
        "source": source,
    }


def from_colmap(model: str | Path, first: str | None = None, last: str | None = None) -> dict[str, Any]:
    """The pose log of a COLMAP text model (see the module docstring); ``first``/``last``: image
    names (default: the first and last registered names in sorted order)."""
    folder = Path(model)
    if not folder.is_dir():
        raise ValueError(f"{folder} is not a folder (a COLMAP text model: cameras.txt, images.txt, points3D.txt)")
    images = _colmap_images(folder / "images.txt")
    names = sorted(images)
    first, last = first or names[0], last or names[-1]
    for name in (first, last):
        if name not in images:
            raise ValueError(f"{folder}: no registered image named {name!r} (first names: {', '.join(names[:3])})")
    if first == last:
        raise ValueError(f"{folder}: the first and the last image are both {first!r}")
    T0, seen = images[first]
    TT, _ = images[last]
    pts = _colmap_points(folder / "points3D.txt", seen)
    cam0 = pts @ T0[:3, :3].T + T0[:3, 3]
    cam0 = cam0[cam0[:, 2] > 0]
    distance = float(np.linalg.norm(cam0, axis=1).mean()) if len(cam0) else float("nan")
    return _log(T0 @ np.linalg.inv(TT), distance, f"colmap {folder.name}: {first} -> {last}")


def from_dust3r(path: str | Path) -> dict[str, Any]:
    """The pose log of a DUSt3R scene saved as an ``.npz`` (see the module docstring): the first
    and the last camera of ``poses``."""
    p = Path(path)
    if not p.exists():
        raise ValueError(f"{p} does not exist (an .npz with DUSt3R's poses and pts3d)")
    regular_file(p, POSE_SCENE)  # a FIFO, a device or a scene past its bound is refused unread
    problem = npz_problem(p)
    if problem is not None:
        raise ValueError(
            f"{p} cannot be read as an .npz file ({problem}): a pose log is made from a DUSt3R scene saved as .npz "
            "(poses and pts3d) or a COLMAP text model folder"
        )
    name = None
    try:
        with np.load(p, allow_pickle=False) as z:
            missing = [k for k in ("poses", "pts3d") if k not in z.files]
            if missing:
                raise ValueError(f"{p}: lacks {', '.join(missing)} (found {', '.join(z.files) or 'nothing'})")
            name = "poses"
            poses = np.asarray(z["poses"], float)
            name = "pts3d"
            pts = np.asarray(z["pts3d"], float)
            name = "mask"
            mask = np.asarray(z["mask"], bool) if "mask" in z.files else None
    except ValueError as exc:
        if str(exc).startswith(str(p)):
            raise
        if name is not None and "allow_pickle" in str(exc):
            raise ValueError(f"{p}: {name!r} holds pickled Python objects, which GeoCon never loads") from None
        raise ValueError(f"{p} cannot be read as an .npz file ({exc})") from None
    except NPZ_ERRORS as exc:
        raise ValueError(f"{p} cannot be read as an .npz file ({type(exc).__name__}: {exc})") from None
    if poses.ndim != 3 or poses.shape[1:] != (4, 4) or len(poses) < 2 or not np.isfinite(poses).all():
        raise ValueError(f"{p}: poses must be (N, 4, 4) cam-to-world matrices with N >= 2, got {poses.shape}")
    first_view = pts[0] if pts.ndim == 4 else pts
    if first_view.ndim != 3 or first_view.shape[-1] != 3:
        raise ValueError(f"{p}: pts3d must be (H, W, 3) or (N, H, W, 3), got {pts.shape}")
    xyz = first_view.reshape(-1, 3)
    if mask is not None:
        if mask.ndim == 3:  # every view's mask: the first view's is the one that counts
            mask = mask[0]
        if mask.shape != first_view.shape[:2]:
            raise ValueError(f"{p}: mask is {mask.shape} but the first point map is {first_view.shape[:2]}")
        xyz = xyz[mask.reshape(-1)]
    xyz = xyz[np.isfinite(xyz).all(axis=1)]
    T_world_cam0 = poses[0]
    cam0 = (xyz - T_world_cam0[:3, 3]) @ T_world_cam0[:3, :3]
    cam0 = cam0[cam0[:, 2] > 0]
    distance = float(np.linalg.norm(cam0, axis=1).mean()) if len(cam0) else float("nan")
    return _log(np.linalg.inv(T_world_cam0) @ poses[-1], distance, f"dust3r {p.name}: view 0 -> view {len(poses) - 1}")


def write_pose_log(log: dict[str, Any], out: str | Path) -> Path:
    """Write ``log`` as JSON to ``out`` once :class:`~geocon_core.pose.log.PoseLog` accepts it
    (a rotation, a plausible translation): written beside ``out`` and renamed into place (never
    onto a device, :func:`~geocon_core.files.replace_file`); a failed write leaves no partial file."""
    out = Path(out)
    tmp = part_path(out)
    with parents_made(out.parent):  # a folder it makes is removed again when the write fails
        try:
            tmp.write_text(json.dumps(log, indent=1) + "\n", encoding="utf-8")
            PoseLog(tmp)
        except ValueError as exc:
            tmp.unlink(missing_ok=True)
            raise ValueError(str(exc).replace(str(tmp), str(out))) from None
        except BaseException:
            tmp.unlink(missing_ok=True)
            raise
        replace_file(tmp, out)
    return out
