"""The dense point clouds of a record in a Rerun recording: the first/last pair in ``world`` (static,
beside the cameras) and each gate window's pair in ``window`` on the timelines (logged at the
window's first frame, so scrubbing the timeline shows the window being scored). Points are
coloured by their epipolar residual (:func:`~geocon_viewer.shared.style.dense_colors`); open3d removes
stray points and thins large clouds. A pair without parallax says so in the 3D view itself.

=============================  ===============================================================
``world/dense``                the first/last dense cloud (first-camera coordinates)
``world/dense_note``           why it is empty (a label in the 3D view), when it is
``window/dense``               the dense cloud of the gate window at the current frame
``window/cam_start``,
``window/cam_end``             the window's two cameras
``window/note``                how it was made, or why it is empty (a label in the 3D view)
``world/dust3r/first``,
``world/dust3r/last``          DUSt3R's point maps of the first and last frame (``--pose
                               dust3r``), their confident pixels, in first-camera coordinates
=============================  ===============================================================
"""

from __future__ import annotations

from typing import Callable

import numpy as np
import rerun as rr

from geocon_core.reconstruction import KIND_OUTLIER, WindowCloud
from geocon_core.record import ClipRecord

from ..shared import OUTLIER_SPAN, dense_points

__all__ = ["log_dense", "log_pointmaps", "dense_legend_markdown", "WORLD_POINTS", "WINDOW_POINTS"]

WORLD_POINTS = 30000
"""At most this many points of the first/last dense cloud go into a recording."""
WINDOW_POINTS = 6000
"""At most this many points of each window's dense cloud go into a recording."""


def dense_legend_markdown(record: ClipRecord) -> list[str]:
    """The audit card's section on the dense clouds: the colour legend and what each cloud holds."""
    if not record.dense:
        return []
    first = record.dense[0].cloud
    tau = first.tau_px if np.isfinite(first.tau_px) else 1.0
    hi = OUTLIER_SPAN * tau
    lines = [
        "",
        "## Dense point clouds",
        f"- colours: **dark to light green** inlier (epipolar residual 0 to {tau:g} px), **yellow to red** "
        f"outlier ({tau:g} to >= {hi:g} px), **blue** moving object (its depth is not a depth)",
    ]
    if len(first):
        lines.append(
            f"- first/last (tab *First/last*): {len(first)} points, outliers {first.share(KIND_OUTLIER):.1%} of "
            f"the background; {first.note}"
        )
    else:
        lines.append(f"- first/last: {first.note}")
    windows = record.dense[1:]
    if windows:
        shares = [w.cloud.share(KIND_OUTLIER) for w in windows if len(w.cloud)]
        worst = f", outliers up to {max(shares):.1%}" if shares else ""
        lines.append(
            f"- gate windows (tab *Gate window*, follows the timeline): {len(windows)} windows, "
            f"{sum(1 for w in windows if len(w.cloud))} with a cloud{worst}"
        )
    return lines


def _note(rec: rr.RecordingStream, path: str, text: str, depth: float, static: bool) -> None:
    rec.log(
        path,
        rr.Points3D([[0.0, 0.0, depth]], radii=rr.Radius.ui_points(0.1), labels=[text], show_labels=True),
        static=static,
    )


def _cameras(rec: rr.RecordingStream, path: str, w: WindowCloud, K: np.ndarray, size: tuple[int, int], depth: float):
    plane = 0.15 * depth
    rec.log(f"{path}/cam_start", rr.Pinhole(image_from_camera=K, resolution=list(size), image_plane_distance=plane))
    if w.T_cam0_camT is None:
        rec.log(f"{path}/cam_end", rr.Clear(recursive=True))
        return
    T = np.asarray(w.T_cam0_camT, float)
    rec.log(f"{path}/cam_end", rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]))
    rec.log(
        f"{path}/cam_end",
        rr.Pinhole(image_from_camera=K, resolution=list(size), image_plane_distance=plane, color=(255, 180, 60, 255)),
    )


def log_dense(rec: rr.RecordingStream, record: ClipRecord, K: np.ndarray, at: Callable[[int], None]) -> float | None:
    """Log the record's dense clouds (``K``: the working intrinsics with the pose's focal scale;
    ``at(t)`` sets the timelines to frame t). Returns the median depth of the first/last cloud
    (None when the record has none)."""
    if not record.dense:
        return None
    first, windows = record.dense[0], record.dense[1:]
    size = record.video.working_size
    depth = None
    if len(first.cloud):
        xyz, rgb = dense_points(first, WORLD_POINTS)
        depth = float(np.median(xyz[:, 2])) if len(xyz) else 1.0
        rec.log("world/dense", rr.Points3D(xyz, colors=rgb, radii=rr.Radius.ui_points(1.5)), static=True)
    else:
        _note(rec, "world/dense_note", f"dense cloud: {first.cloud.note}", 1.0, static=True)
    for w in windows:
        at(w.start)
        if len(w.cloud):
            xyz, rgb = dense_points(w, WINDOW_POINTS)
            d = float(np.median(xyz[:, 2])) if len(xyz) else 1.0
            rec.log("window/dense", rr.Points3D(xyz, colors=rgb, radii=rr.Radius.ui_points(1.5)))
            rec.log("window/note", rr.Clear(recursive=False))
        else:
            d = 1.0
            rec.log("window/dense", rr.Clear(recursive=False))
            _note(rec, "window/note", f"frames {w.start}-{w.end}: {w.cloud.note}", d, static=False)
        _cameras(rec, "window", w, K, size, d)
    return depth


def log_pointmaps(rec: rr.RecordingStream, record: ClipRecord) -> None:
    """DUSt3R's point maps of the record (``--pose dust3r``): the pixels whose confidence reaches
    the backend's ``min_conf`` (the ones its pose used), coloured by the network's input."""
    maps = record.pointmaps
    if maps is None:
        return
    least = record.config.dust3r.min_conf
    for name, xyz, conf, rgb in (
        ("first", maps.xyz0, maps.conf0, maps.rgb0),
        ("last", maps.xyz1, maps.conf1, maps.rgb1),
    ):
        keep = conf.astype(np.float32) >= least
        rec.log(
            f"world/dust3r/{name}",
            rr.Points3D(xyz[keep].astype(np.float32), colors=rgb[keep], radii=rr.Radius.ui_points(1.5)),
            static=True,
        )
