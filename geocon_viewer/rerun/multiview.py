"""The clip's one reconstruction (:mod:`geocon_core.reconstruction.multiview`) in a Rerun recording.

``clip3d``: the camera path (a line through the keyframes' centres and, on the timeline, the
current keyframe's frustum), the reconstruction's points coloured by their track's residual
(green consistent .. red at three times ``tau_px``) with the drifting layers' tracks in magenta;
for a rotation-only clip the points lie on a sphere around the one camera centre.
``frame/multiview``: each judged track on its middle keyframe, in the same colours.
Everything is read from the record; nothing is recomputed.
"""

from __future__ import annotations

import numpy as np
import rerun as rr

from geocon_core.record import ClipRecord
from geocon_core.results import LAYER_RGB

from ..shared import track_colors

__all__ = ["LAYER_RGBA", "log_multiview"]

LAYER_RGBA = (*LAYER_RGB, 255)
"""Colour of the tracks of a drifting layer."""
_SPHERE = 10.0
"""Radius of the sphere a rotation-only reconstruction's points are drawn on (world units)."""


def log_multiview(rec: rr.RecordingStream, record: ClipRecord, set_time) -> bool:
    """Log the record's reconstruction; ``set_time(t)`` sets the recording's time to frame t.
    Returns False (logging nothing) when the record has none."""
    mv = record.multiview
    if mv is None or mv.cam_from_world is None or mv.points is None or mv.residual is None:
        why = (
            f"The multi-view check is off in the {record.config.preset!r} preset (it runs in 'audit')."
            if not record.config.multiview.enabled
            else f"No reconstruction: {mv.reason if mv is not None else 'the record predates the check'}."
        )
        rec.log("clip3d/note", rr.TextDocument(why), static=True)
        return False
    tau = record.config.multiview.tau_px
    colors = track_colors(mv.residual, tau, mv.layer_of)
    poses = np.asarray(mv.cam_from_world, dtype=float)
    centres = np.stack([-P[:, :3].T @ P[:, 3] for P in poses]) if len(poses) else np.zeros((0, 3))
    pts = np.asarray(mv.points, dtype=float)
    if mv.model == "H":
        pts = pts * _SPHERE
        centres = np.zeros_like(centres)  # the adjuster's free camera position means nothing here
    finite = np.all(np.isfinite(pts), axis=1)
    if finite.any():
        depth = np.linalg.norm(pts[finite] - (centres[0] if len(centres) else 0), axis=1)
        scale = float(np.median(depth)) if len(depth) else 1.0
        lo, hi = np.percentile(pts[finite], [2, 98], axis=0)
        pad = 0.5 * (hi - lo)
        finite &= np.all((pts >= lo - pad) & (pts <= hi + pad), axis=1)  # far outliers would shrink the view
    else:
        scale = 1.0
    rec.log("clip3d", rr.ViewCoordinates.RDF, static=True)
    labels = [f"residual {r:.2f} px" for r in mv.residual[finite]]
    rec.log(
        "clip3d/points",
        rr.Points3D(
            pts[finite], colors=colors[finite], radii=rr.Radius.ui_points(2.0), labels=labels, show_labels=False
        ),
        static=True,
    )
    if mv.model != "H" and len(centres) > 1:
        rec.log(
            "clip3d/path",
            rr.LineStrips3D(
                [centres], colors=(255, 255, 255, 255), radii=rr.Radius.ui_points(1.5), labels=["camera path"]
            ),
            static=True,
        )
    K = np.asarray(record.intrinsics, dtype=float).copy()
    if mv.focal_px:
        K[0, 0] = K[1, 1] = mv.focal_px
    w, h = record.video.working_size
    plane = 0.08 * scale
    for P, t in zip(poses, mv.registered, strict=True):
        set_time(int(t))
        R, tr = P[:, :3], P[:, 3]
        centre = np.zeros(3) if mv.model == "H" else -R.T @ tr
        rec.log("clip3d/camera", rr.Transform3D(translation=centre, mat3x3=R.T))
        rec.log("clip3d/camera", rr.Pinhole(image_from_camera=K, resolution=[w, h], image_plane_distance=plane))
    if mv.track_xy is not None and mv.track_frame is not None:
        s = record.video.scale
        ox, oy = record.video.offset
        xy = np.asarray(mv.track_xy, dtype=float) * s + (ox, oy)
        for t in np.unique(mv.track_frame):
            pick = mv.track_frame == t
            set_time(int(t))
            rec.log(
                "frame/multiview",
                rr.Points2D(xy[pick], colors=colors[pick], radii=rr.Radius.ui_points(3.0)),
            )
    finding = "; ".join(layer.describe() for layer in mv.layers) or (mv.reason or "no drifting layer")
    ir = "-" if mv.mv_ir is None else f"{mv.mv_ir:.3f}"
    ge = "-" if mv.mv_ge is None else f"{mv.mv_ge:.2f} px"
    rec.log(
        "clip3d/note",
        rr.TextDocument(
            f"One reconstruction ({mv.model}, {len(mv.registered)} of {len(mv.frames)} keyframes, {mv.tracks} tracks): "
            f"MV-IR {ir}, MV-GE {ge}. {finding}."
        ),
        static=True,
    )
    return True
