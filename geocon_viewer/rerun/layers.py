"""The parts of a Rerun audit recording that come from the finished record: matches and residual
maps per pair, per-cell object vectors, time series, the 3D world, and the maps of where the
clip's readings fire. :class:`RecordLayers`
writes them into an explicit recording stream (see :mod:`geocon_viewer.rerun.log` for the
entity paths)."""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np
import rerun as rr

from geocon_core.geometry import family_spec
from geocon_core.record import ClipRecord, FitSummary

from ..shared import clean_cloud
from .dense import log_dense, log_pointmaps
from .images import colormap, object_rgba, png_bytes, residual_map
from .multiview import log_multiview
from .regions import log_regions

__all__ = ["RecordLayers", "ARROW_GAIN", "INLIER", "OUTLIER"]

INLIER = (60, 200, 90, 255)
OUTLIER = (235, 60, 50, 255)
ARROW_GAIN = 4.0
"""Cell flow vectors are drawn this many times longer than they are (labelled so)."""
# Screen-space sizes (negative radii are UI points in Rerun): matches stay visible at any zoom.
MATCH_RADIUS = rr.Radius.ui_points(1.6)
OUTLIER_RADIUS = rr.Radius.ui_points(2.2)
LINE_RADIUS = rr.Radius.ui_points(0.6)


def _rule(family: str, fit: FitSummary, s: float) -> tuple[str, float]:
    """The inlier rule of ``fit`` as a label, and the top of its residual colour scale (working px)."""
    if family == "H":
        return f"H: symmetric transfer error <= {fit.tau:g} px", 2.0 * fit.tau / s
    return (
        f"F: normalised Sampson <= {fit.tau:g} (~{(fit.tau_px or 0) / s:.2f} px)",
        2.0 * (fit.tau_px or 1.0) / s,
    )


class RecordLayers:
    """Logs the record-derived layers into ``rec``; the pair (t, t+k) is logged at frame t on both
    timelines (``video_time`` = t / ``fps``). ``scale`` is the scale whose matches are drawn
    (default: the largest)."""

    def __init__(self, rec: rr.RecordingStream, fps: float, scale: float | None) -> None:
        self.rec, self.fps, self.scale = rec, fps, scale

    def log_all(self, record: ClipRecord) -> None:
        self._log_matches(record)
        self._log_cells(record)
        self._log_series(record)
        self._log_world(record)
        log_multiview(self.rec, record, self._time)
        log_regions(self.rec, record, self._time)
        self._log_readings(record)

    def _log_readings(self, record: ClipRecord) -> None:
        """Where each appearance reading fires over the clip (``frame/readings/<map>``, static, on
        the frame's working size; :mod:`geocon_core.signals.pictures`)."""
        from geocon_core.signals import MAP_NAMES, MAP_VIEWS, heat_rgba, map_on_frame

        a = record.readings.appearance if record.readings is not None else None
        if a is None or a.maps is None:
            return
        size = record.video.working_size
        for name in MAP_NAMES:
            shares = map_on_frame(a.maps, name, record.video.content_box, size)
            rgba = heat_rgba(shares, MAP_VIEWS[name].vmax)
            image = rr.EncodedImage(contents=png_bytes(rgba, level=3), media_type="image/png", draw_order=1.5)
            self.rec.log(f"frame/readings/{name}", image, static=True)

    def _time(self, t: int) -> None:
        self.rec.set_time("frame", sequence=int(t))
        self.rec.set_time("video_time", duration=t / self.fps)

    def _draw_scale(self, record: ClipRecord) -> float:
        return self.scale if self.scale is not None else max(record.config.scales)

    def _log_matches(self, record: ClipRecord) -> None:
        rec, fam = self.rec, record.background.model
        s = self._draw_scale(record)
        w, h = record.video.working_size
        for p in record.pairs:
            if p.gap != 1 or p.scale != s:
                continue
            self._time(p.t0)
            fit = p.fit(fam)
            if p.skip is not None or fit is None:
                rec.log("frame/matches", rr.Clear(recursive=True))
                continue
            a = record.matches.pair(p.index)
            # working pixels of the scale's coordinates (cv2.resize pixel-centre convention)
            x1 = (a["x1"].astype(np.float64) + 0.5) / s - 0.5
            x2 = (a["x2"].astype(np.float64) + 0.5) / s - 0.5
            r1, r2 = x1 + 0.5, x2 + 0.5  # Rerun puts pixel centres at +0.5
            spec = family_spec(fam)
            res_px, inl = a[spec.residual_px] / s, a[spec.inliers]
            rule, vmax = _rule(fam, fit, s)
            ir = "invalid" if fit.ir is None else f"IR {fit.ir:.3f}"
            ge = "" if fit.ge is None else f", GE {fit.ge / s:.2f} px"
            rec.log(
                "frame/matches/inliers",
                rr.Points2D(
                    r1[inl],
                    radii=MATCH_RADIUS,
                    colors=INLIER,
                    labels=f"inliers ({rule}); {ir}{ge}",
                    show_labels=False,
                    draw_order=3.0,
                ),
            )
            rec.log(
                "frame/matches/outliers",
                rr.Points2D(
                    r1[~inl],
                    radii=OUTLIER_RADIUS,
                    colors=OUTLIER,
                    labels=f"outliers ({rule})",
                    show_labels=False,
                    draw_order=3.1,
                ),
            )
            strips = np.stack([r1, r2], axis=1)
            rec.log(
                "frame/matches/lines",
                rr.LineStrips2D(
                    strips.astype(np.float32),
                    radii=LINE_RADIUS,
                    colors=colormap(res_px, vmax),
                    labels=f"x_t -> x_t+1, colour = residual 0..{vmax:.2f} px",
                    show_labels=False,
                    draw_order=2.9,
                ),
            )
            heat = residual_map(x1, res_px, (w, h), vmax)
            cell = 8
            # cell i covers working pixels [i*cell, (i+1)*cell) -> Rerun coordinates + 0.5
            rec.log("frame/residual_map", rr.Transform3D(scale=[cell, cell, 1.0], translation=[0.5, 0.5, 0.0]))
            rec.log(
                "frame/residual_map",
                rr.EncodedImage(
                    contents=png_bytes(heat),
                    media_type="image/png",
                    opacity=0.85,
                    draw_order=4.0,
                    magnification_filter="Linear",
                ),
            )
        n = record.video.num_frames
        if n:  # the last frame starts no pair
            self._time(n - 1)
            rec.log("frame/matches", rr.Clear(recursive=True))
            rec.log("frame/residual_map", rr.Clear(recursive=False))

    def _log_cells(self, record: ClipRecord) -> None:
        if record.cells is None:
            return
        rec, s_max = self.rec, max(record.config.scales)
        seen: dict[int, set[int]] = {}
        for e in record.object_entries:
            if e.scale != s_max:
                continue
            self._time(e.t0)
            base = f"frame/cells/{e.object_id}"
            cells = record.cells.entry(e.index)
            if not e.valid or len(cells["weights"]) == 0:
                rec.log(base, rr.Clear(recursive=True))
                continue
            pos = (cells["positions"].astype(np.float64) + 0.5) / s_max  # working pixels, Rerun's +0.5 centres
            obs, pred = cells["observed"] / s_max, cells["predicted"] / s_max
            color = object_rgba(e.object_id)
            rec.log(
                f"{base}/observed",
                rr.Arrows2D(
                    origins=pos,
                    vectors=ARROW_GAIN * obs,
                    colors=color,
                    radii=1.2,
                    labels=f"object {e.object_id}: median cell flow x{ARROW_GAIN:g}",
                    show_labels=False,
                    draw_order=5.0,
                ),
            )
            rec.log(
                f"{base}/predicted",
                rr.Arrows2D(
                    origins=pos,
                    vectors=ARROW_GAIN * pred,
                    colors=(255, 255, 255, 255),
                    radii=0.8,
                    labels=(
                        f"object {e.object_id}: affine prediction x{ARROW_GAIN:g} of frames {e.t0} -> {e.t1}; "
                        f"D_t {e.d_t:.3g} px^2"
                    ),
                    show_labels=False,
                    draw_order=5.1,
                ),
            )
            seen.setdefault(e.object_id, set()).add(e.t0)
        for oid, ts in seen.items():  # no stale arrows once an object is gone
            for t in sorted(ts):
                if t + 1 not in ts:
                    self._time(t + 1)
                    rec.log(f"frame/cells/{oid}", rr.Clear(recursive=True))

    def _cols(self, t: Sequence[int] | np.ndarray) -> list[Any]:
        ts = np.asarray(t, np.int64)
        return [rr.TimeColumn("frame", sequence=ts), rr.TimeColumn("video_time", duration=ts / self.fps)]

    def _line(self, path: str, name: str, color: Any, width: float = 1.5) -> None:
        self.rec.log(path, rr.SeriesLines(colors=[color], names=[name], widths=[width]), static=True)

    def _constant(self, path: str, n: int, value: float) -> None:
        self.rec.send_columns(
            path, indexes=self._cols(np.arange(n)), columns=rr.Scalars.columns(scalars=np.full(n, value))
        )

    def _log_series(self, record: ClipRecord) -> None:
        self._log_background_series(record)
        self._log_object_series(record)
        self._log_gate_series(record)

    def _log_background_series(self, record: ClipRecord) -> None:
        rec, cfg, bg = self.rec, record.config, record.background
        fam = bg.model
        n = record.video.num_frames
        flagged_t, flagged_v = [], []
        for gap in cfg.gaps:
            for si, s in enumerate(cfg.scales):
                rows = [p for p in record.pairs if p.gap == gap and p.scale == s]
                fits = [(p, p.fit(fam)) for p in rows]
                ok = [(p, f) for p, f in fits if p.skip is None and f is not None and f.valid]
                shade = 120 + int(135 * (si + 1) / len(cfg.scales))
                for metric in ("ir", "ge"):
                    path = f"series/background/{metric}/gap{gap}/scale{s:g}"
                    color = (40, 110, shade, 255) if metric == "ir" else (shade, 90, 40, 255)
                    self._line(path, f"{metric.upper()} {fam} gap {gap} scale {s:g}", color)
                    if ok:
                        vals = [getattr(f, metric) for _, f in ok]
                        rec.send_columns(
                            path, indexes=self._cols([p.t0 for p, _ in ok]), columns=rr.Scalars.columns(scalars=vals)
                        )
                for p, f in fits:
                    bad = (
                        p.skip is not None
                        or f is None
                        or not f.valid
                        or f.ir is None
                        or f.ge is None
                        or f.ir < cfg.ir_gate
                        or f.ge > cfg.ge_gate
                    )
                    if bad and gap == 1 and s == max(cfg.scales):
                        flagged_t.append(p.t0)
                        flagged_v.append(0.0 if f is None or f.ir is None else f.ir)
        for path, name, value, color in (
            ("series/background/ir/gate", f"IR gate {cfg.ir_gate:g}", cfg.ir_gate, (90, 160, 255, 255)),
            ("series/background/ge/gate", f"GE gate {cfg.ge_gate:g} px", cfg.ge_gate, (255, 150, 80, 255)),
        ):
            self._line(path, name, color, 1.0)
            self._constant(path, n, value)
        rec.log(
            "series/background/ir/flagged",
            rr.SeriesPoints(colors=[OUTLIER], names=["flagged pair (gap 1)"], markers=["cross"], marker_sizes=[4.0]),
            static=True,
        )
        if flagged_t:
            rec.send_columns(
                "series/background/ir/flagged",
                indexes=self._cols(flagged_t),
                columns=rr.Scalars.columns(scalars=flagged_v),
            )

    def _log_object_series(self, record: ClipRecord) -> None:
        s_max = max(record.config.scales)
        for o in record.objects:
            path = f"series/objects/{o.object_id}"
            self._line(path, f"AdaDFRC D_t object {o.object_id} (px^2)", object_rgba(o.object_id))
            es = [
                e
                for e in record.object_entries
                if e.object_id == o.object_id and e.scale == s_max and e.valid and e.d_t is not None
            ]
            if es:
                self.rec.send_columns(
                    path,
                    indexes=self._cols([e.t0 for e in es]),
                    columns=rr.Scalars.columns(scalars=[e.d_t for e in es if e.d_t is not None]),
                )

    def _log_gate_series(self, record: ClipRecord) -> None:
        g, n = record.gate, record.video.num_frames
        wins = [(w.end, w.t_inf) for w in g.timeline if w.t_inf is not None]
        self._line("series/gate/t_inf", "t_inf per window (at its last frame)", (230, 230, 230, 255), 2.0)
        if wins:
            self.rec.send_columns(
                "series/gate/t_inf",
                indexes=self._cols([end for end, _ in wins]),
                columns=rr.Scalars.columns(scalars=[t_inf for _, t_inf in wins]),
            )
        for name, value, color in (
            ("low", g.thresholds["low"], (80, 200, 120, 255)),
            ("high", g.thresholds["high"], (240, 90, 90, 255)),
        ):
            path = f"series/gate/{name}"
            self._line(path, f"gate {name} {value:g}", color, 1.0)
            self._constant(path, n, value)
        if g.margin is not None:
            self._line("series/gate/margin", f"clip margin {g.margin:+.4f} ({g.label})", (200, 200, 90, 255), 1.0)
            self._constant("series/gate/margin", n, g.margin)

    def _log_world(self, record: ClipRecord) -> None:
        rec = self.rec
        w, h = record.video.working_size
        K = np.asarray(record.intrinsics, dtype=float).copy()
        pose = record.gate.pose
        fs = pose.focal_scale
        K[0, 0] *= fs
        K[1, 1] *= fs
        rec.log("world", rr.ViewCoordinates.RDF, static=True)
        T = None if pose.T_cam0_camT is None else np.asarray(pose.T_cam0_camT, dtype=float)
        cloud = record.cloud
        depth = 1.0
        has_dense = bool(record.dense) and len(record.dense[0].cloud) > 0  # the dense cloud shows more
        if cloud is not None and len(cloud.xyz) and not has_dense:
            xyz, rgb = clean_cloud(cloud.xyz, cloud.rgb)
            depth = float(np.median(xyz[:, 2])) if len(xyz) else 1.0
            rec.log("world/points", rr.Points3D(xyz, colors=rgb, radii=0.004 * depth), static=True)
        dense_depth = log_dense(rec, record, K, self._time)
        log_pointmaps(rec, record)
        depth = depth if dense_depth is None else dense_depth
        plane = 0.15 * depth
        rec.log(
            "world/cam_first",
            rr.Pinhole(image_from_camera=K, resolution=[w, h], image_plane_distance=plane, color=(90, 200, 255, 255)),
            static=True,
        )
        if T is not None:
            rec.log("world/cam_last", rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]), static=True)
            rec.log(
                "world/cam_last",
                rr.Pinhole(
                    image_from_camera=K, resolution=[w, h], image_plane_distance=plane, color=(255, 180, 60, 255)
                ),
                static=True,
            )
            if np.linalg.norm(T[:3, 3]) > 0:
                rec.log(
                    "world/baseline",
                    rr.LineStrips3D(
                        [[[0, 0, 0], T[:3, 3].tolist()]],
                        colors=(255, 255, 255, 255),
                        radii=0.002 * depth,
                        labels=["baseline first -> last"],
                    ),
                    static=True,
                )
        note = "no point cloud" if cloud is None else cloud.note
        rec.log("world/note", rr.TextDocument(note), static=True)
