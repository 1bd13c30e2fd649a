"""Point clouds as the viewers draw them: open3d removes stray points and thins large clouds; the
dense clouds of a record are coloured by their epipolar residual
(:func:`~geocon_viewer.shared.style.dense_colors`). Shared by the Rerun recording and the Viser app."""

from __future__ import annotations

import math

import numpy as np

from geocon_core.reconstruction import WindowCloud

from .style import dense_colors

__all__ = ["clean_cloud", "dense_points"]


def clean_cloud(xyz: np.ndarray, rgb: np.ndarray, *, max_points: int = 20000) -> tuple[np.ndarray, np.ndarray]:
    """Statistical outlier removal and, for clouds larger than ``max_points``, voxel down-sampling
    (open3d; colours are averaged per voxel)."""
    if len(xyz) < 20:
        return xyz, rgb
    import open3d as o3d

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(xyz.astype(np.float64)))
    pc.colors = o3d.utility.Vector3dVector(rgb.astype(np.float64) / 255.0)
    if len(xyz) > max_points:
        extent = float(np.linalg.norm(np.ptp(xyz, axis=0)))
        voxel = extent / math.sqrt(max_points) / 4
        for _ in range(8):  # the voxel grows until the cloud fits
            down = pc.voxel_down_sample(voxel)
            if len(down.points) <= max_points:
                break
            voxel *= 1.5
        pc = down
    pc, _ = pc.remove_statistical_outlier(nb_neighbors=16, std_ratio=2.5)
    return np.asarray(pc.points, np.float32), np.round(np.asarray(pc.colors) * 255).astype(np.uint8)


def dense_points(w: WindowCloud, max_points: int) -> tuple[np.ndarray, np.ndarray]:
    """The points of a dense cloud and their residual colours, cleaned (:func:`clean_cloud`)."""
    c = w.cloud
    tau = c.tau_px if np.isfinite(c.tau_px) else 1.0
    return clean_cloud(c.xyz, dense_colors(c.residual, c.kind, tau), max_points=max_points)
