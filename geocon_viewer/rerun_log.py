"""Rerun audit recordings: everything the scorer knows about a clip, on two timelines.

:class:`RerunAudit` writes into an explicit :class:`rerun.RecordingStream` (never the global
one). Frames arrive one at a time (:meth:`RerunAudit.frame`, usable as the scorer's
``on_frame``), then the finished :class:`~geocon_core.record.ClipRecord` adds the matches,
residual maps, object vectors, time series, the point cloud and the audit card
(:meth:`RerunAudit.record`). Nothing here computes a score: every number comes from the
record, and the pictures are drawn from its stored per-match residuals and per-cell vectors.

Timelines: ``frame`` (sequence, frame index t) and ``video_time`` (t / fps). A pair (t, t+k) is
logged at frame t. Entity paths:

=============================  ===============================================================
``frame/image``                the frames (one AV1 video asset with a frame reference per
                               frame, or a JPEG per frame)
``frame/content``              pixels outside the content box (static segmentation)
``frame/objects``              object ids used for masking (segmentation, named by
                               ``frame/objects``' annotation context)
``frame/matches/inliers``      background matches of pair (t, t+1) at x_t, inliers ...
``frame/matches/outliers``     ... and outliers of the chosen family
``frame/matches/lines``        x_t -> x_{t+1}, coloured by residual
``frame/residual_map``         per-match residuals spread over the image (inferno colour map,
                               transparent where there are no matches)
``frame/flow``                 flow-direction hue slices of the objects inside their masks (hue =
                               direction, brightness = magnitude; transparent elsewhere)
``frame/cells/<id>/observed``  per-cell median flow of object <id> (arrows, exaggerated)
``frame/cells/<id>/predicted`` the affine prediction at the same cells
``series/background/...``      IR and GE per gap and scale, report gates, flagged pairs
``series/objects/<id>``        AdaDFRC ``D_t`` per object
``series/gate/...``            per-window ``t_inf`` with the 0.03 / 0.05 lines and margin
``world/points``               first/last two-view point cloud
``world/cam_first``,
``world/cam_last``             both cameras as pinholes
``audit``                      the audit card (markdown)
=============================  ===============================================================
"""

from __future__ import annotations

import contextlib
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import cv2
import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from geocon_core.diagnostics import FlowSlice, FrameDiagnostics, flow_hue
from geocon_core.record import ClipRecord

from .style import fmt, object_color

__all__ = [
    "RerunAudit",
    "AuditFrame",
    "RrdSink",
    "write_rrd",
    "blueprint",
    "audit_card",
    "worst_frame",
    "residual_map",
    "RERUN_VERSION",
    "frames_from_diagnostics",
]

RERUN_VERSION = rr.__version__
INLIER = (60, 200, 90, 255)
OUTLIER = (235, 60, 50, 255)
ARROW_GAIN = 4.0
# Screen-space sizes (negative radii are UI points in Rerun): matches stay visible at any zoom.
MATCH_RADIUS = rr.Radius.ui_points(1.6)
OUTLIER_RADIUS = rr.Radius.ui_points(2.2)
LINE_RADIUS = rr.Radius.ui_points(0.6)
"""Cell flow vectors are drawn this many times longer than they are (labelled so)."""


@dataclass(frozen=True, eq=False)
class AuditFrame:
    """One frame as the recording shows it: (H, W, 3) uint8 RGB, object labels (H, W) uint16 or
    None, and the objects' flow-hue slices on the pair (t, t+1)."""

    index: int
    rgb: np.ndarray
    labels: np.ndarray | None
    flows: Sequence[FlowSlice] = ()


def frames_from_diagnostics(fd: FrameDiagnostics) -> AuditFrame:
    """The scorer's live diagnostics as an :class:`AuditFrame` (flow turned into hue slices)."""
    slices = []
    for of in fd.flows:
        rgba, vmax = flow_hue(of.flow, of.reliable & of.mask)
        slices.append(FlowSlice(of.object_id, of.t0, of.t1, of.box, vmax, rgba))
    return AuditFrame(fd.index, fd.frame.rgb, fd.labels, slices)


def _colormap(values: np.ndarray, vmax: float) -> np.ndarray:
    """Inferno colours (N, 4) uint8 of values in [0, vmax]."""
    v = np.clip(np.asarray(values, np.float64) / max(vmax, 1e-9), 0.0, 1.0)
    idx = np.round(v * 255).astype(np.uint8).reshape(-1, 1)
    bgr = cv2.applyColorMap(idx, cv2.COLORMAP_INFERNO).reshape(-1, 3)
    out = np.full((len(v), 4), 255, np.uint8)
    out[:, :3] = bgr[:, ::-1]
    return out


def _object_color(object_id: int) -> tuple[int, int, int, int]:
    return (*object_color(object_id), 255)


def _png(image: np.ndarray, level: int = 6) -> bytes:
    if image.ndim == 3 and image.shape[2] == 4:
        image = cv2.cvtColor(image, cv2.COLOR_RGBA2BGRA)
    elif image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
    ok, buf = cv2.imencode(".png", image, [cv2.IMWRITE_PNG_COMPRESSION, level])
    assert ok
    return buf.tobytes()


def residual_map(
    xy: np.ndarray, residuals: np.ndarray, size: tuple[int, int], vmax: float, *, cell: int = 8, sigma_px: float = 24.0
) -> np.ndarray:
    """A low-resolution RGBA picture (h/cell, w/cell, 4) of per-match residuals spread over an
    image of ``size`` (w, h): a Gaussian-weighted mean of the residuals around each point,
    inferno-coloured over [0, vmax], opaque where matches are dense and transparent where there
    are none. ``xy`` are the matches' working pixels."""
    w, h = size
    gw, gh = max(1, math.ceil(w / cell)), max(1, math.ceil(h / cell))
    num = np.zeros((gh, gw), np.float64)
    den = np.zeros((gh, gw), np.float64)
    finite = np.isfinite(residuals)
    r = np.clip(residuals[finite], 0, 4 * vmax)
    gx = np.clip((xy[finite, 0] / cell).astype(int), 0, gw - 1)
    gy = np.clip((xy[finite, 1] / cell).astype(int), 0, gh - 1)
    np.add.at(num, (gy, gx), r)
    np.add.at(den, (gy, gx), 1.0)
    s = sigma_px / cell
    num = cv2.GaussianBlur(num, (0, 0), s)
    den = cv2.GaussianBlur(den, (0, 0), s)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(den > 1e-9, num / den, 0.0)
    # one match within ~sigma gives about 1 / (2 pi s^2) density: call 3 matches full evidence
    alpha = np.clip(den * (2 * math.pi * s * s) / 3.0, 0.0, 1.0)
    rgba = _colormap(mean.ravel(), vmax).reshape(gh, gw, 4)
    rgba[..., 3] = np.round(alpha * 220).astype(np.uint8)
    return rgba


def quiet_encoder_logs() -> None:
    """Let the AV1 encoder (SVT-AV1) print errors only, unless ``SVT_LOG`` is set already. The
    command line calls this before writing a recording; it changes the process environment."""
    os.environ.setdefault("SVT_LOG", "1")


def _thread_ids() -> set[int]:
    try:
        return {int(t) for t in os.listdir("/proc/self/task")}
    except OSError:
        return set()


def _is_realtime(tid: int) -> bool:
    with contextlib.suppress(OSError):
        return os.sched_getscheduler(tid) in (os.SCHED_FIFO, os.SCHED_RR)
    return False


class _EncoderThreads:
    """Undoes what SVT-AV1 does to scheduling, and nothing else.

    SVT-AV1 running as root gives its worker threads, and the thread that opens the encoder,
    ``SCHED_FIFO`` priority 99. Left alone, they and every process started afterwards (the rerun
    server, a browser) starve the rest of the machine; on two cores the box stops responding.
    This remembers the threads that ran under a real-time policy before the encoder opened (a
    caller's choice, kept) and puts every other real-time thread back to the normal policy."""

    def __init__(self) -> None:
        supported = hasattr(os, "sched_getscheduler") and hasattr(os, "sched_setscheduler")
        self.kept = {t for t in _thread_ids() if _is_realtime(t)} if supported else set()
        self.enabled = supported

    def restore(self) -> None:
        if not self.enabled:
            return
        for tid in _thread_ids() - self.kept:
            with contextlib.suppress(OSError):
                if _is_realtime(tid):
                    os.sched_setscheduler(tid, os.SCHED_OTHER, os.sched_param(0))


class _FrameVideo:
    """Frames encoded into one AV1 mp4 in memory as they arrive (SVT-AV1, low-delay: no frame
    reordering), logged at the end as an ``AssetVideo`` with one ``VideoFrameReference`` per
    frame. AV1 decodes in both the native and the web viewer without extra software."""

    def __init__(self, fps: float, crf: int) -> None:
        import io

        import av

        self.buf = io.BytesIO()
        self.container = av.open(self.buf, "w", format="mp4")
        self.fps, self.crf = fps, crf
        self.stream = None
        self.indices: list[int] = []
        self._threads = _EncoderThreads()

    def add(self, index: int, rgb: np.ndarray) -> None:
        import av

        if self.stream is None:
            h, w = rgb.shape[:2]
            from fractions import Fraction

            st = self.container.add_stream("libsvtav1", rate=Fraction(self.fps).limit_denominator(1001))
            st.width, st.height, st.pix_fmt = w - w % 2, h - h % 2, "yuv420p"
            st.options = {"preset": "10", "crf": str(self.crf), "svtav1-params": "pred-struct=1:keyint=48"}
            self.stream = st
        frame = av.VideoFrame.from_ndarray(
            np.ascontiguousarray(rgb[: self.stream.height, : self.stream.width]), format="rgb24"
        )
        frame.pts = len(self.indices)
        self.indices.append(index)
        for packet in self.stream.encode(frame):
            self.container.mux(packet)
        self._threads.restore()

    def finish(self) -> bytes | None:
        if self.stream is None:
            return None
        for packet in self.stream.encode():
            self.container.mux(packet)
        self.container.close()
        self._threads.restore()
        return self.buf.getvalue()


class RerunAudit:
    """Writes one clip's audit into ``rec``.

    fps: the clip's frame rate (for ``video_time``); frames: ``"video"`` (AV1, compact, the
    default) or ``"jpeg"`` (one JPEG per frame, ``quality``); scale: which scale's matches are
    drawn over the frames (default: the largest).
    """

    def __init__(
        self,
        rec: rr.RecordingStream,
        *,
        fps: float,
        frames: str = "video",
        quality: int | None = None,
        scale: float | None = None,
    ) -> None:
        if frames not in ("video", "jpeg"):
            raise ValueError(f"frames must be 'video' or 'jpeg', got {frames!r}")
        if not fps > 0:
            fps = 30.0
        self.rec, self.fps, self.scale = rec, float(fps), scale
        self.frames_mode = frames
        self.quality = int(quality if quality is not None else (32 if frames == "video" else 80))
        self.video = _FrameVideo(self.fps, self.quality) if frames == "video" else None
        self.n_frames = 0
        self._content_logged = False
        self._flow_shown = False

    def _time(self, t: int) -> None:
        self.rec.set_time("frame", sequence=int(t))
        self.rec.set_time("video_time", duration=t / self.fps)

    # -- per frame ---------------------------------------------------------------------------

    def frame(self, f: AuditFrame | FrameDiagnostics) -> None:
        """Log one frame with its object labels and flow-hue slices."""
        if isinstance(f, FrameDiagnostics):
            if not self._content_logged:
                self._log_content(f.frame.content)
            f = frames_from_diagnostics(f)
        rec = self.rec
        self._time(f.index)
        if self.video is not None:
            self.video.add(f.index, f.rgb)
        else:
            ok, jpg = cv2.imencode(
                ".jpg", cv2.cvtColor(f.rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, self.quality]
            )
            assert ok
            rec.log("frame/image", rr.EncodedImage(contents=jpg.tobytes(), media_type="image/jpeg", draw_order=0.0))
        if f.labels is not None:
            labels = f.labels.astype(np.uint8) if f.labels.max(initial=0) < 256 else f.labels.astype(np.uint16)
            rec.log("frame/objects", rr.SegmentationImage(labels, opacity=0.35, draw_order=1.0))
        # All objects' slices in one image of the frame's size: Rerun needs an image entity to keep
        # its dimensions over time, and a mostly transparent PNG costs a few kB.
        if f.flows:
            h, w = f.rgb.shape[:2]
            hue = np.zeros((h, w, 4), dtype=np.uint8)
            for sl in f.flows:
                x0, y0, x1, y1 = sl.box
                x1, y1 = min(x1, w), min(y1, h)
                patch = sl.image[: y1 - y0, : x1 - x0]
                covered = patch[..., 3] > 0
                hue[y0:y1, x0:x1][covered] = patch[covered]
            rec.log(
                "frame/flow",
                rr.EncodedImage(contents=_png(hue, level=1), media_type="image/png", opacity=0.9, draw_order=2.0),
            )
            self._flow_shown = True
        elif self._flow_shown:
            rec.log("frame/flow", rr.Clear(recursive=False))
            self._flow_shown = False
        self.n_frames = max(self.n_frames, f.index + 1)

    def _log_content(self, content: np.ndarray) -> None:
        outside = (~content).astype(np.uint8)
        self.rec.log(
            "frame/content",
            rr.AnnotationContext([(0, "content", (0, 0, 0, 0)), (1, "outside the content box", (40, 40, 160, 160))]),
            static=True,
        )
        self.rec.log("frame/content", rr.SegmentationImage(outside, opacity=0.5, draw_order=0.5), static=True)
        self._content_logged = True

    # -- from the record ---------------------------------------------------------------------

    def record(self, record: ClipRecord) -> None:
        """Log everything that comes from the finished record."""
        rec = self.rec
        if not self._content_logged:
            self._log_content_box(record)
        if self.video is not None:
            data = self.video.finish()
            if data is not None:
                asset = rr.AssetVideo(contents=data, media_type="video/mp4")
                rec.log("frame/image", asset, static=True)
                # the container's own timestamps, so every reference hits its frame exactly
                ns = asset.read_frame_timestamps_nanos()
                t = np.asarray(self.video.indices, np.int64)
                if len(ns) != len(t):
                    raise RuntimeError(f"the frame video holds {len(ns)} frames, {len(t)} were encoded")
                rec.send_columns(
                    "frame/image",
                    indexes=[rr.TimeColumn("frame", sequence=t), rr.TimeColumn("video_time", duration=t / self.fps)],
                    columns=rr.VideoFrameReference.columns_nanos(ns),
                )
        rec.send_property(
            "geocon",
            rr.AnyValues(
                clip=record.clip,
                config_hash=record.config_hash,
                preset=record.config.preset,
                geocon_version=record.versions.get("geocon", "?"),
                rerun_version=RERUN_VERSION,
            ),
        )
        ids = [o.object_id for o in record.objects]
        rec.log(
            "frame/objects",
            rr.AnnotationContext(
                [(0, "background", (0, 0, 0, 0))] + [(i, f"object {i}", _object_color(i)) for i in ids]
            ),
            static=True,
        )
        self._log_matches(record)
        self._log_cells(record)
        self._log_series(record)
        self._log_world(record)
        rec.log("audit", rr.TextDocument(audit_card(record), media_type=rr.MediaType.MARKDOWN), static=True)

    def _log_content_box(self, record: ClipRecord) -> None:
        w, h = record.video.working_size
        x0, y0, x1, y1 = record.video.content_box
        content = np.zeros((h, w), bool)
        content[y0:y1, x0:x1] = True
        self._log_content(content)

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
            if fam == "H":
                res_px, inl, rule = a["h_res"] / s, a["h_inl"], f"H: symmetric transfer error <= {fit.tau:g} px"
                vmax = 2.0 * fit.tau / s
            else:
                res_px, inl, rule = (
                    a["f_res_px"] / s,
                    a["f_inl"],
                    f"F: normalised Sampson <= {fit.tau:g} (~{(fit.tau_px or 0) / s:.2f} px)",
                )
                vmax = 2.0 * (fit.tau_px or 1.0) / s
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
                    strips,
                    radii=LINE_RADIUS,
                    colors=_colormap(res_px, vmax),
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
                    contents=_png(heat),
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
            color = _object_color(e.object_id)
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
                    labels=f"object {e.object_id}: affine prediction x{ARROW_GAIN:g}; D_t {e.d_t:.3g} px^2",
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

    def _log_series(self, record: ClipRecord) -> None:
        rec, cfg, bg = self.rec, record.config, record.background
        fam = bg.model
        n = record.video.num_frames
        frames = np.arange(n)

        def cols(t: Sequence[int]) -> list:
            t = np.asarray(t, np.int64)
            return [rr.TimeColumn("frame", sequence=t), rr.TimeColumn("video_time", duration=t / self.fps)]

        def line(path: str, name: str, color, width: float = 1.5) -> None:
            rec.log(path, rr.SeriesLines(colors=[color], names=[name], widths=[width]), static=True)

        flagged_t, flagged_v = [], []
        for gap in cfg.gaps:
            for si, s in enumerate(cfg.scales):
                rows = [p for p in record.pairs if p.gap == gap and p.scale == s]
                ok = [p for p in rows if p.skip is None and p.fit(fam) is not None and p.fit(fam).valid]
                shade = 120 + int(135 * (si + 1) / len(cfg.scales))
                for metric, gate_ok in (("ir", lambda v: v >= cfg.ir_gate), ("ge", lambda v: v <= cfg.ge_gate)):
                    path = f"series/background/{metric}/gap{gap}/scale{s:g}"
                    color = (40, 110, shade, 255) if metric == "ir" else (shade, 90, 40, 255)
                    line(path, f"{metric.upper()} {fam} gap {gap} scale {s:g}", color)
                    if ok:
                        vals = [getattr(p.fit(fam), metric) for p in ok]
                        rec.send_columns(
                            path, indexes=cols([p.t0 for p in ok]), columns=rr.Scalars.columns(scalars=vals)
                        )
                for p in rows:
                    f = p.fit(fam)
                    bad = p.skip is not None or f is None or not f.valid or f.ir < cfg.ir_gate or f.ge > cfg.ge_gate
                    if bad and gap == 1 and s == max(cfg.scales):
                        flagged_t.append(p.t0)
                        flagged_v.append(0.0 if f is None or f.ir is None else f.ir)
        for path, name, value, color in (
            ("series/background/ir/gate", f"IR gate {cfg.ir_gate:g}", cfg.ir_gate, (90, 160, 255, 255)),
            ("series/background/ge/gate", f"GE gate {cfg.ge_gate:g} px", cfg.ge_gate, (255, 150, 80, 255)),
        ):
            line(path, name, color, 1.0)
            rec.send_columns(path, indexes=cols(frames), columns=rr.Scalars.columns(scalars=np.full(n, value)))
        rec.log(
            "series/background/ir/flagged",
            rr.SeriesPoints(colors=[OUTLIER], names=["flagged pair (gap 1)"], markers=["cross"], marker_sizes=[4.0]),
            static=True,
        )
        if flagged_t:
            rec.send_columns(
                "series/background/ir/flagged", indexes=cols(flagged_t), columns=rr.Scalars.columns(scalars=flagged_v)
            )
        s_max = max(cfg.scales)
        for o in record.objects:
            path = f"series/objects/{o.object_id}"
            line(path, f"AdaDFRC D_t object {o.object_id} (px^2)", _object_color(o.object_id))
            es = [e for e in record.object_entries if e.object_id == o.object_id and e.scale == s_max and e.valid]
            if es:
                rec.send_columns(
                    path, indexes=cols([e.t0 for e in es]), columns=rr.Scalars.columns(scalars=[e.d_t for e in es])
                )
        g = record.gate
        wins = [w for w in g.timeline if w.t_inf is not None]
        line("series/gate/t_inf", "t_inf per window (at its last frame)", (230, 230, 230, 255), 2.0)
        if wins:
            rec.send_columns(
                "series/gate/t_inf",
                indexes=cols([w.end for w in wins]),
                columns=rr.Scalars.columns(scalars=[w.t_inf for w in wins]),
            )
        for name, value, color in (
            ("low", g.thresholds["low"], (80, 200, 120, 255)),
            ("high", g.thresholds["high"], (240, 90, 90, 255)),
        ):
            path = f"series/gate/{name}"
            line(path, f"gate {name} {value:g}", color, 1.0)
            rec.send_columns(path, indexes=cols(frames), columns=rr.Scalars.columns(scalars=np.full(n, value)))
        if g.margin is not None:
            line("series/gate/margin", f"clip margin {g.margin:+.4f} ({g.label})", (200, 200, 90, 255), 1.0)
            rec.send_columns(
                "series/gate/margin", indexes=cols(frames), columns=rr.Scalars.columns(scalars=np.full(n, g.margin))
            )

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
        if cloud is not None and len(cloud.xyz):
            xyz, rgb = _clean_cloud(cloud.xyz, cloud.rgb)
            depth = float(np.median(xyz[:, 2])) if len(xyz) else 1.0
            rec.log("world/points", rr.Points3D(xyz, colors=rgb, radii=0.004 * depth), static=True)
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


def _clean_cloud(xyz: np.ndarray, rgb: np.ndarray, *, max_points: int = 20000) -> tuple[np.ndarray, np.ndarray]:
    """Statistical outlier removal and, for large clouds, voxel downsampling (open3d)."""
    if len(xyz) < 20:
        return xyz, rgb
    import open3d as o3d

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(xyz.astype(np.float64)))
    pc.colors = o3d.utility.Vector3dVector(rgb.astype(np.float64) / 255.0)
    if len(xyz) > max_points:
        extent = float(np.linalg.norm(np.ptp(xyz, axis=0)))
        pc = pc.voxel_down_sample(extent / math.sqrt(max_points) / 4)
    pc, _ = pc.remove_statistical_outlier(nb_neighbors=16, std_ratio=2.5)
    return np.asarray(pc.points, np.float32), np.round(np.asarray(pc.colors) * 255).astype(np.uint8)


def blueprint() -> rrb.Blueprint:
    """The default layout: frame with matches, residual map and object flow on top; 3D, the
    time series and the audit card below."""
    frame_view = rrb.Spatial2DView(
        name="Frame + background matches",
        origin="frame",
        contents=["+ frame/image", "+ frame/content", "+ frame/objects", "+ frame/matches/**"],
    )
    residual_view = rrb.Spatial2DView(
        name="Residual map", origin="frame", contents=["+ frame/image", "+ frame/residual_map/**"]
    )
    object_view = rrb.Spatial2DView(
        name="Object flow + AdaDFRC cells",
        origin="frame",
        contents=["+ frame/image", "+ frame/objects", "+ frame/flow", "+ frame/cells/**"],
    )
    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Horizontal(frame_view, residual_view, object_view),
            rrb.Horizontal(
                rrb.Spatial3DView(name="First/last two-view geometry", origin="world"),
                rrb.Vertical(
                    rrb.TimeSeriesView(name="Background IR", origin="series/background/ir"),
                    rrb.TimeSeriesView(name="Background GE (px)", origin="series/background/ge"),
                ),
                rrb.Vertical(
                    rrb.TimeSeriesView(name="Gate t_inf", origin="series/gate"),
                    rrb.TimeSeriesView(name="AdaDFRC per object (px^2)", origin="series/objects"),
                ),
                rrb.TextDocumentView(name="Audit card", origin="audit"),
                column_shares=[3, 3, 3, 2],
            ),
            row_shares=[3, 2],
        ),
        rrb.TimePanel(timeline="frame", play_state="paused", state="collapsed"),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
    )


def worst_frame(record: ClipRecord) -> int:
    """The first frame of the worst gap-1 pair at the largest scale under the chosen family
    (lowest IR; an unjudged pair counts as worst), where an inspector should look first."""
    s, fam = max(record.config.scales), record.background.model
    worst, key = 0, None
    for p in record.pairs:
        if p.gap != 1 or p.scale != s or p.skip is not None:
            continue
        f = p.fit(fam)
        k = -1.0 if f is None or f.ir is None else f.ir
        if key is None or k < key:
            worst, key = p.t0, k
    return worst


def audit_card(record: ClipRecord) -> str:
    """The clip's audit card in markdown: verdict, gate rationale with its inputs, thresholds,
    coverage, objects, configuration and versions."""
    g, bg, cfg = record.gate, record.background, record.config
    verdict = {True: "consistent", False: "INCONSISTENT", None: "not judged"}[bg.consistent]
    v = record.video
    reasons = ", ".join(f"{k}: {n}" for k, n in bg.chosen.invalid_reasons.items()) or "none"
    lines = [
        f"# {record.clip.rsplit('/', 1)[-1]}",
        "",
        f"**Verdict: background {verdict}** — model {bg.model}, IR {fmt(bg.ir, '.3f')} (gate >= {cfg.ir_gate:g}), "
        f"GE {fmt(bg.ge, '.2f', ' px')} (gate <= {cfg.ge_gate:g} px); category **{record.category.label if record.category else 'n/a'}**.",
        "",
        "## Translation gate",
        f"- label **{g.label}** (binary {g.binary_label}), model used **{g.model}**, backend `{g.backend}`",
        f"- t_inf {fmt(g.t_inf, '.4f')}, margin {fmt(g.margin, '+.4f')}; thresholds: low {g.thresholds['low']:g} / high {g.thresholds['high']:g} "
        f"(binary {g.thresholds['tau_t']:g})",
        f"- pose: method {g.pose.method}, {g.pose.n_inliers} of {g.pose.n_matches} matches, rotation "
        f"{fmt(g.pose.rotation_deg, '.2f', ' deg')}, parallax {fmt(g.pose.parallax_px, '.2f', ' px')}"
        + ("" if g.pose_present else f"; no pose ({g.pose.reason}): fail -> F"),
        f"- {bg.choice_note}",
        "",
        "## Background",
        f"- residual rules: H symmetric transfer error <= {cfg.tau_h:g} px; F normalised Sampson <= {cfg.tau_f:g} "
        f"(~{fmt(bg.tau_f_px, '.2f', ' px')} at the largest scale)",
        f"- valid pairs {bg.valid_pairs} of {bg.total_pairs}; invalid: {reasons}",
        f"- other family {bg.other.family}: IR {fmt(bg.other.ir, '.3f')}, GE {fmt(bg.other.ge, '.2f', ' px')}",
        "",
        "| gap | IR | GE (px) | valid |",
        "|---|---|---|---|",
        *[
            f"| {gs.gap} | {fmt(gs.ir, '.3f')} | {fmt(gs.ge, '.2f')} | {gs.valid_pairs}/{gs.total_pairs} |"
            for gs in bg.chosen.per_gap
        ],
        "",
        "## Coverage",
        f"- {v.num_frames} frames at {v.fps} fps, working size {list(v.working_size)}, "
        f"content box {list(v.content_box)}",
        f"- duplicated frames {len(v.duplicates)}, hard cuts {len(v.cuts)}; masks: {record.masks_source}",
    ]
    if record.objects:
        lines += [
            "",
            "## Objects",
            "",
            "| id | frames | AdaDFRC (px^2) | W2 | AdaP90 | masked share |",
            "|---|---|---|---|---|---|",
        ]
        lines += [
            f"| {o.object_id} | {o.frames} | {fmt(o.adadfrc, '.3g')} | {fmt(o.adadfrc_w2, '.3g')} | {fmt(o.adap90, '.3g')} | {o.masked_share:.3f} |"
            for o in record.objects
        ]
    if record.warnings:
        lines += ["", "## Warnings", *[f"- {w}" for w in record.warnings]]
    versions = ", ".join(f"{k} {val}" for k, val in record.versions.items())
    lines += [
        "",
        "## Configuration",
        f"- preset `{cfg.preset}`, config hash `{record.config_hash}`, scales {list(cfg.scales)}, gaps {list(cfg.gaps)}, matcher {cfg.matcher}",
        f"- versions: {versions}; rerun {RERUN_VERSION}",
        f"- this recording was written with Rerun {RERUN_VERSION}: open it with a viewer of the same version "
        f"(`pip install rerun-sdk=={RERUN_VERSION}`, then `rerun FILE.rrd`).",
    ]
    return "\n".join(lines) + "\n"


class RrdSink:
    """Streams a clip into a recording while it is scored: pass it as the scorer's ``on_frame``,
    then call :meth:`finish` with the record. Writes ``path`` (a ``.rrd`` file) and/or streams to
    a running viewer at ``connect`` (a ``rerun+http://.../proxy`` URL)."""

    def __init__(self, path: str | Path | None, *, connect: str | None = None, frames: str = "video") -> None:
        if path is None and connect is None:
            raise ValueError("RrdSink needs a file path, a viewer URL to connect to, or both")
        self.path = None if path is None else Path(path)
        self.rec = rr.RecordingStream("geocon")
        sinks: list = []
        if self.path is not None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            sinks.append(rr.FileSink(str(self.path)))
        if connect is not None:
            sinks.append(rr.GrpcSink(connect))
        self.rec.set_sinks(*sinks, default_blueprint=blueprint())
        self.frames = frames
        self.audit: RerunAudit | None = None

    def _audit(self, fps: float) -> RerunAudit:
        if self.audit is None:
            self.audit = RerunAudit(self.rec, fps=fps, frames=self.frames)
        return self.audit

    def __call__(self, fd: FrameDiagnostics) -> None:
        self._audit(fd.fps).frame(fd)

    def frame(self, f: AuditFrame, fps: float) -> None:
        self._audit(fps).frame(f)

    def finish(self, record: ClipRecord) -> Path | None:
        self._audit(record.video.fps).record(record)
        self.rec.flush()
        self.rec.disconnect()
        return self.path


def write_rrd(
    record_dir: str | Path, path: str | Path | None, *, connect: str | None = None, progress=None
) -> Path | None:
    """Re-render the recording of a saved record (``record.json`` + ``matches.npz`` + ``overlays/``)
    without re-scoring: frames are decoded again from the clip the record names."""
    from geocon_core.diagnostics import read_overlays
    from geocon_core.reader import iter_frames, probe_clip
    from geocon_core.record import read_record

    record = read_record(record_dir)
    overlays = read_overlays(record_dir)
    sink = RrdSink(path, connect=connect)
    fps = record.video.fps
    clip = Path(record.clip)
    if clip.exists():
        info = probe_clip(clip, record.config)
        for frame in iter_frames(info):
            labels = flows = None
            if overlays is not None:
                labels, flows = overlays.labels(frame.index), overlays.flows(frame.index)
            sink.frame(AuditFrame(frame.index, frame.rgb, labels, flows or ()), fps)
            if progress is not None:
                progress(frame.index + 1, info.num_frames)
    else:
        sink.rec.log(
            "audit/missing_clip", rr.TextDocument(f"the clip {clip} was not found: frames are not shown"), static=True
        )
    return sink.finish(record)
