"""What the audit app shows for the selected clip, drawn from its record: the 3D scene (point
cloud and cameras), the IR / GE / AdaDFRC / gate plots and the clip card. Functions of the clip's
data and the viser handles they draw into; nothing here computes a score."""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import viser
import viser.transforms as vtf
import viser.uplot as uplot

from geocon_core.reconstruction import KIND_OBJECT, KIND_OUTLIER
from geocon_core.record import ClipRecord, Overlays, clip_finding
from geocon_core.results import ResultClip
from geocon_core.scoring import ClipVerdict, Thresholds, regate_pairs

from ..rerun import why_lines
from ..shared import EMPTY, dense_legend, dense_points, fmt, object_color, track_colors

INLIER = (60, 200, 90)
OUTLIER = (235, 60, 50)
DENSE_POINTS = 40000
"""At most this many points of a dense cloud are sent to the browser."""

__all__ = [
    "ClipView",
    "Plots",
    "thumb",
    "draw_frame",
    "frame_text",
    "empty_plot",
    "render_scene",
    "pair_options",
    "pair_text",
    "dense_legend_html",
    "PAIR_FIRST_LAST",
    "PAIR_CLIP",
    "has_reconstruction",
    "move_clip_camera",
    "render_reconstruction",
    "DENSE_POINTS",
    "render_plots",
    "clip_card",
    "app_picture",
    "map_choice",
    "MAP_MENU",
]


def thumb(img: np.ndarray) -> np.ndarray:
    """A frame at the frustums' thumbnail width (256 px)."""
    return cv2.resize(img, (256, max(1, round(256 * img.shape[0] / img.shape[1]))), interpolation=cv2.INTER_AREA)


@dataclass(eq=False)
class ClipView:
    """What the app holds for the selected clip: its record, overlays, and the frames decoded at
    display size (filled by a background thread; ``frames_ready`` is set when done)."""

    clip_id: str
    folder: Path
    record: ClipRecord
    overlays: Overlays | None
    display_scale: float
    frames: dict[int, np.ndarray] = field(default_factory=dict)
    frames_ready: threading.Event = field(default_factory=threading.Event)
    frames_error: str | None = None
    cancel: threading.Event = field(default_factory=threading.Event)
    frustums: dict[int, Any] = field(default_factory=dict)
    """Scene handles of the first/last camera by frame index (their images arrive with the frames)."""
    clip_camera: Any = None
    """Scene handle of the current camera of the clip's one reconstruction (moved by the frame
    slider), when that scene is shown."""
    heat: dict[str, np.ndarray] = field(default_factory=dict)
    """Reading maps at display size (shares 0..1), by map name, made when first shown."""

    def reading_shares(self, name: str, size: tuple[int, int]) -> np.ndarray | None:
        """Map ``name`` of the clip's readings (:mod:`geocon_core.signals.pictures`) as shares on a
        frame of display ``size`` (w, h); None when the record has no maps."""
        from geocon_core.signals import map_on_frame

        a = self.record.readings.appearance if self.record.readings is not None else None
        if a is None or a.maps is None:
            return None
        if name not in self.heat:
            full = map_on_frame(a.maps, name, self.record.video.content_box, self.working_size)
            self.heat[name] = cv2.resize(full, size, interpolation=cv2.INTER_AREA)
        return self.heat[name]

    @property
    def num_frames(self) -> int:
        return self.record.video.num_frames

    @property
    def working_size(self) -> tuple[int, int]:
        w, h = self.record.video.working_size
        return int(w), int(h)


def draw_frame(
    view: ClipView,
    t: int,
    *,
    masks: bool,
    matches: tuple[np.ndarray, np.ndarray] | None,
    reading_map: str | None = None,
) -> np.ndarray:
    """Frame ``t`` at display size (decoded already) with the object masks tinted in their colours
    (``masks``), the background matches drawn (green inliers, red outliers) when given, and
    under them the map ``reading_map`` of where a reading fires (:data:`~geocon_core.signals.MAP_VIEWS`)."""
    from geocon_core.signals import MAP_VIEWS, blend_heat

    img = view.frames[t].copy()
    k = view.display_scale
    if reading_map is not None:
        shares = view.reading_shares(reading_map, (img.shape[1], img.shape[0]))
        if shares is not None:
            img = blend_heat(img, shares, MAP_VIEWS[reading_map].vmax)
    if masks and view.overlays is not None:
        labels = view.overlays.labels(t)
        if labels is not None:
            small = cv2.resize(labels, (img.shape[1], img.shape[0]), interpolation=cv2.INTER_NEAREST)
            for oid in np.unique(small[small > 0]):
                m = small == oid
                img[m] = (0.5 * img[m] + 0.5 * np.array(object_color(int(oid)))).astype(np.uint8)
    if matches is not None:
        xy, inl = matches
        r = max(2, round(3 * k * 1.5))
        for (x, y), ok in zip(xy * k, inl, strict=True):
            cv2.circle(
                img,
                (int(round(x)), int(round(y))),
                r,
                INLIER if ok else OUTLIER,
                -1 if ok else 1,
                lineType=cv2.LINE_AA,
            )
    return img


def frame_text(
    view: ClipView, t: int, matches: tuple[np.ndarray, np.ndarray] | None, v: ClipVerdict | None, *, shown: bool
) -> str:
    """The caption under frame ``t``: the pair's inlier count, the masked share, decoding state."""
    share = view.overlays.masked_share(t) if view.overlays is not None else None
    text = f"frame {t} of {view.num_frames - 1}"
    if matches is not None:
        k = int(matches[1].sum())
        model = "?" if v is None else v.model
        pair = f"({t}, {t + min(view.record.config.gaps)})"
        text += f" · pair {pair}: {k} of {len(matches[1])} matches inliers under {model}"
    if share is not None:
        text += f" · masked {share:.1%}"
    if view.frames_error:
        text += f"\n\n⚠ {view.frames_error}"
    elif not shown:
        text += " · decoding…"
    return text


def empty_plot(server: viser.ViserServer, title: str) -> Any:
    """A placeholder uPlot in the GUI (filled when a clip is selected)."""
    x = np.zeros(1)
    return server.gui.add_uplot(
        (x, x),
        (uplot.Series(label="frame"), uplot.Series(label="-")),
        title=title,
        aspect=2.2,
        scales={"x": uplot.Scale(time=False)},
    )


@dataclass(frozen=True)
class Plots:
    """The app's plot handles."""

    ir: Any
    ge: Any
    objects: Any
    gate: Any


PAIR_FIRST_LAST = "first/last"
PAIR_CLIP = "one camera for the clip"


def has_reconstruction(record: ClipRecord) -> bool:
    """Whether the record holds the clip's one reconstruction (:mod:`geocon_core.reconstruction.multiview`)."""
    return record.multiview is not None and record.multiview.cam_from_world is not None


def pair_options(record: ClipRecord) -> list[str]:
    """The pairs the 3D scene can show: the first/last pair, then each gate window with a dense
    cloud (``"window a-b"``), then the clip's one reconstruction when the record has it."""
    clip = [PAIR_CLIP] if has_reconstruction(record) else []
    return [PAIR_FIRST_LAST, *(f"window {w.start}-{w.end}" for w in record.dense[1:]), *clip]


def dense_legend_html(record: ClipRecord) -> str:
    """The colour legend of the dense clouds (HTML swatches), or "" for a record without them."""
    if not record.dense:
        return ""
    tau = record.dense[0].cloud.tau_px
    rows = "".join(
        f'<div style="display:flex;align-items:center;gap:6px;margin:2px 0">'
        f'<span style="width:14px;height:14px;border-radius:3px;background:rgb({r},{g},{b})"></span>'
        f"<span>{label}</span></div>"
        for label, (r, g, b) in dense_legend(tau if np.isfinite(tau) else 1.0)
    )
    return (
        '<div style="font-size:0.85em"><b>Dense cloud: epipolar residual of each point</b>'
        f"{rows}<div>a point is the flow of the pair triangulated with its pose</div></div>"
    )


def pair_text(record: ClipRecord, pair: int) -> str:
    """What the 3D scene shows for ``pair`` (an index of :func:`pair_options`), in words."""
    if pair_options(record)[min(max(pair, 0), len(pair_options(record)) - 1)] == PAIR_CLIP:
        mv = record.multiview
        assert mv is not None
        what = "; ".join(layer.describe() for layer in mv.layers) or mv.reason or "no layer drifts against it"
        ir = "-" if mv.mv_ir is None else f"{mv.mv_ir:.3f}"
        ge = "-" if mv.mv_ge is None else f"{mv.mv_ge:.2f} px"
        return (
            f"one reconstruction ({mv.model}) of {len(mv.registered)} keyframes and {mv.tracks} tracks, "
            f"points coloured by residual (magenta: a drifting layer); MV-IR {ir}, MV-GE {ge}; {what}"
        )
    if not record.dense:
        cloud = record.cloud
        return "no point cloud" if cloud is None else f"sparse cloud: {len(cloud.xyz)} points; {cloud.note}"
    w = record.dense[pair]
    head = f"frames {w.start} -> {w.end}: "
    if not len(w.cloud):
        return head + w.cloud.note
    return (
        head + f"{len(w.cloud)} points; outliers {w.cloud.share(KIND_OUTLIER):.1%} of the background, "
        f"objects {float(np.mean(w.cloud.kind == KIND_OBJECT)):.1%}; {w.cloud.note}"
    )


def render_scene(server: viser.ViserServer, view: ClipView | None, pair: int = 0) -> Any:
    """The point cloud and both cameras of the selected clip's pair ``pair`` (0: first/last, then
    the gate windows, :func:`pair_options`): the dense residual-coloured cloud when the record has
    one, else the sparse first/last cloud. Returns the point cloud's handle (or None)."""
    scene = server.scene
    scene.reset()
    if view is None:
        return None
    view.frustums.clear()
    view.clip_camera = None
    rec = view.record
    if pair_options(rec)[min(max(pair, 0), len(pair_options(rec)) - 1)] == PAIR_CLIP:
        return render_reconstruction(server, view)
    w, h = view.working_size
    fy = float(np.asarray(rec.intrinsics)[1, 1]) * rec.gate.pose.focal_scale
    fov = 2.0 * math.atan(h / 2.0 / fy)
    depth = 1.0
    cloud_handle = None
    if rec.dense:
        win = rec.dense[min(max(pair, 0), len(rec.dense) - 1)]
        t0, t1, T_end = win.start, win.end, win.T_cam0_camT
        note = f"dense cloud, frames {t0}-{t1}" if len(win.cloud) else f"frames {t0}-{t1}: {win.cloud.note}"
        empty = (np.zeros((0, 3), np.float32), np.zeros((0, 3), np.uint8))
        xyz, rgb = dense_points(win, DENSE_POINTS) if len(win.cloud) else empty
    else:
        t0, t1, T_end = 0, view.num_frames - 1, rec.gate.pose.T_cam0_camT
        note = "no point cloud" if rec.cloud is None else rec.cloud.note
        xyz = np.zeros((0, 3), np.float32) if rec.cloud is None else rec.cloud.xyz
        rgb = np.zeros((0, 3), np.uint8) if rec.cloud is None else rec.cloud.rgb
    if len(xyz):
        depth = float(np.median(xyz[:, 2])) or 1.0
        cloud_handle = scene.add_point_cloud(
            "/cloud",
            points=xyz.astype(np.float32),
            colors=rgb,
            point_size=(0.006 if rec.dense else 0.012) * depth,
            precision="float32",
            point_shape="circle",
        )

    def frustum(name: str, t: int, color: tuple[int, int, int], **pose: Any) -> None:
        img = view.frames.get(t)
        view.frustums[t] = scene.add_camera_frustum(
            name,
            fov=fov,
            aspect=w / h,
            scale=0.08 * depth,
            thickness=0.004 * depth,
            color=color,
            image=None if img is None else thumb(img),
            format="jpeg",
            jpeg_quality=80,
            **pose,
        )

    frustum("/cam_first", t0, (90, 200, 255))
    if T_end is not None:
        T = np.asarray(T_end, dtype=float)
        frustum("/cam_last", t1, (255, 180, 60), wxyz=vtf.SO3.from_matrix(T[:3, :3]).wxyz, position=T[:3, 3])
        if np.linalg.norm(T[:3, 3]) > 0:
            scene.add_line_segments(
                "/baseline",
                np.array([[[0, 0, 0], T[:3, 3]]], np.float32),
                colors=(255, 255, 255),
                thickness=2.0,
                thickness_units="screen",
            )
    scene.add_label("/note", note, position=(0.0, -0.12 * depth, 0.0))
    _look(server, (0.0, 0.0, depth), (0.3 * depth, -0.45 * depth, -0.7 * depth))
    return cloud_handle


def _look(server: viser.ViserServer, look_at: Any, position: Any) -> None:
    """Point the scene's camera (new and connected clients) from ``position`` at ``look_at``, y down."""
    up = (0.0, -1.0, 0.0)
    look_at, position = tuple(float(v) for v in look_at), tuple(float(v) for v in position)
    cam = server.initial_camera
    cam.look_at, cam.position, cam.up = look_at, position, up
    for client in server.get_clients().values():
        client.camera.look_at = look_at
        client.camera.position = position
        client.camera.up_direction = up


def render_reconstruction(server: viser.ViserServer, view: ClipView) -> Any:
    """The clip's one reconstruction: its points coloured by residual (the drifting layer in
    magenta), the camera path, and the current keyframe's camera (:func:`move_clip_camera`)."""
    scene, rec = server.scene, view.record
    mv = rec.multiview
    assert mv is not None and mv.cam_from_world is not None and mv.points is not None and mv.residual is not None
    pts = np.asarray(mv.points, dtype=float) * (10.0 if mv.model == "H" else 1.0)
    colors = track_colors(mv.residual, rec.config.multiview.tau_px, mv.layer_of)
    ok = np.all(np.isfinite(pts), axis=1)
    if ok.any():
        lo, hi = np.percentile(pts[ok], [2, 98], axis=0)
        ok &= np.all((pts >= lo - 0.5 * (hi - lo)) & (pts <= hi + 0.5 * (hi - lo)), axis=1)
    poses = np.asarray(mv.cam_from_world, dtype=float)
    centres = np.zeros((len(poses), 3)) if mv.model == "H" else np.stack([-P[:, :3].T @ P[:, 3] for P in poses])
    depth = float(np.median(np.linalg.norm(pts[ok] - centres[0], axis=1))) if ok.any() else 1.0
    middle = np.median(pts[ok], axis=0) if ok.any() else np.array([0.0, 0.0, depth])
    _look(server, middle, centres.mean(axis=0) + np.array([0.35, -0.5, -0.9]) * depth)
    handle = scene.add_point_cloud(
        "/clip/points",
        points=pts[ok].astype(np.float32),
        colors=colors[ok],
        point_size=0.004 * depth,
        precision="float32",
        point_shape="circle",
    )
    if mv.model != "H" and len(centres) > 1:
        segments = np.stack([centres[:-1], centres[1:]], axis=1).astype(np.float32)
        scene.add_line_segments("/clip/path", segments, colors=(255, 255, 255), thickness=2.0, thickness_units="screen")
    w, h = view.working_size
    f = mv.focal_px or float(np.asarray(rec.intrinsics)[1, 1])
    view.clip_camera = scene.add_camera_frustum(
        "/clip/camera", fov=2.0 * math.atan(h / 2.0 / f), aspect=w / h, scale=0.08 * depth, color=(90, 200, 255)
    )
    scene.add_label("/clip/note", pair_text(rec, len(pair_options(rec)) - 1)[:160], position=(0.0, -0.12 * depth, 0.0))
    return handle


def move_clip_camera(view: ClipView, t: int) -> None:
    """Put the reconstruction's current camera at the last keyframe at or before frame ``t``."""
    mv = view.record.multiview
    if view.clip_camera is None or mv is None or mv.cam_from_world is None or not len(mv.registered):
        return
    k = max(0, int(np.searchsorted(np.asarray(mv.registered), t, side="right")) - 1)
    P = np.asarray(mv.cam_from_world[k], dtype=float)
    R = P[:, :3]
    view.clip_camera.wxyz = vtf.SO3.from_matrix(R.T).wxyz
    view.clip_camera.position = (0.0, 0.0, 0.0) if mv.model == "H" else tuple(-R.T @ P[:, 3])


def render_plots(plots: Plots, view: ClipView | None, v: ClipVerdict | None, th: Thresholds) -> None:
    """The IR, GE, AdaDFRC and gate plots of the selected clip under the verdict ``v`` at ``th``."""
    if view is None or v is None:
        return
    rec = view.record
    s = max(rec.config.scales)
    tau = th.tau(v.model)
    n = max(view.num_frames, 1)
    x = np.arange(n, dtype=np.float64)
    ir = np.full(n, np.nan)
    ge = np.full(n, np.nan)
    g0 = min(rec.config.gaps)
    for p, row in regate_pairs(rec, v.model, tau):
        if p.gap == g0 and p.scale == s and row.valid:
            ir[p.t0], ge[p.t0] = row.ir, row.ge
    plots.ir.data = (x, ir, np.full(n, th.ir_gate))
    plots.ir.series = (
        uplot.Series(label="frame"),
        uplot.Series(label=f"IR {v.model} (scale {s:g})", stroke="#1f77b4", width=2),
        uplot.Series(label=f"gate {th.ir_gate:g}", stroke="#d62728", dash=(6, 4)),
    )
    plots.ir.title = f"IR per pair ({v.model}, tau {tau:g})"
    plots.ge.data = (x, ge, np.full(n, th.ge_gate))
    plots.ge.series = (
        uplot.Series(label="frame"),
        uplot.Series(label=f"GE {v.model} px", stroke="#ff7f0e", width=2),
        uplot.Series(label=f"gate {th.ge_gate:g} px", stroke="#d62728", dash=(6, 4)),
    )
    objects = sorted(rec.objects, key=lambda o: -(o.adap90 or 0.0))[:6]
    s_obj = max((e.scale for e in rec.object_entries), default=s)
    ys = []
    for o in objects:
        y = np.full(n, np.nan)
        for e in rec.object_entries:
            if e.object_id == o.object_id and e.scale == s_obj and e.valid and e.d_t is not None:
                y[e.t0] = e.d_t
        ys.append(y)
    if objects:
        plots.objects.data = (x, *ys)
        plots.objects.series = (
            uplot.Series(label="frame"),
            *[
                uplot.Series(label=f"object {o.object_id}", stroke="#%02x%02x%02x" % object_color(o.object_id), width=2)
                for o in objects
            ],
        )
        plots.objects.title = (
            f"AdaDFRC D_t (px², frames t -> t+{rec.config.object_gap}), "
            f"{len(objects)} of {len(rec.objects)} objects by AdaP90"
        )
    else:
        plots.objects.data = (x, np.full(n, np.nan))
        plots.objects.series = (uplot.Series(label="frame"), uplot.Series(label="no objects"))
        plots.objects.title = "AdaDFRC: no moving objects in this clip"
    wins = [w for w in rec.gate.timeline if w.t_inf is not None and (w.start, w.end) != (0, n - 1)]
    if wins:
        gx = np.array([w.end for w in wins], np.float64)
        gy = np.array([w.t_inf for w in wins], np.float64)
    else:
        gx, gy = np.array([0.0, n - 1.0]), np.full(2, np.nan)
    clip_t = np.full(len(gx), np.nan if rec.gate.t_inf is None else rec.gate.t_inf)
    plots.gate.data = (gx, gy, np.full(len(gx), th.tau_t_low), np.full(len(gx), th.tau_t_high), clip_t)
    plots.gate.series = (
        uplot.Series(label="window end"),
        uplot.Series(label="t_inf per window", stroke="#9467bd", width=2),
        uplot.Series(label=f"low {th.tau_t_low:g}", stroke="#2ca02c", dash=(6, 4)),
        uplot.Series(label=f"high {th.tau_t_high:g}", stroke="#d62728", dash=(6, 4)),
        uplot.Series(label="first→last", stroke="#555555", dash=(2, 3)),
    )
    plots.gate.title = f"Gate t_inf: {v.label} (margin {fmt(v.margin, '+.4f')})"


MAP_MENU = "reading map"
"""The label of the Frame tab's menu of reading maps."""


def map_choice(name: str | None) -> str:
    """The entry of the reading-map menu for map ``name`` (None: no map)."""
    from geocon_core.signals import MAP_VIEWS

    return "none" if name is None else MAP_VIEWS[name].title


def app_picture(name: str) -> str:
    """Where the app shows reading ``name``: the Frame tab's reading-map entry, or its other view."""
    from geocon_core.signals import picture_of

    tab = picture_of(name)
    if tab is not None:
        return f"Frame tab, {MAP_MENU} *{map_choice(tab)}*"
    return {
        "shortfall": "Frame tab (inliers / outliers), Background plots",
        "unkept": "Frame tab (red: outliers)",
        "mv_residual": "3D scene, pair *one camera for the clip*",
        "object_rigidity": "Objects plot",
    }.get(name, "")


def clip_card(view: ClipView, v: ClipVerdict, clip: ResultClip, th: Thresholds, recorded: Thresholds) -> str:
    """The markdown card of the selected clip under the verdict ``v`` at ``th``."""
    rec = view.record
    bg, g = rec.background, rec.gate
    state = {True: "passes", False: "FAILS", None: "cannot be judged"}[v.consistent]
    finding = clip_finding(
        model=v.model,
        ir=v.ir,
        ge=v.ge,
        consistent=v.consistent,
        margin=v.report_margin,
        ir_gate=th.ir_gate,
        ge_gate=th.ge_gate,
        note=bg.choice_note,
        shots=len(rec.shots),
    )
    why: list[str] = []
    if rec.readings is not None and rec.config.signals.enabled:
        # the clip model reads the record as scored; moving the thresholds re-gates the background only
        finding, why = rec.finding(), why_lines(rec, app_picture)
    lines = [
        f"### {view.clip_id}",
        f"platform **{clip.platform}** · category **{clip.category or EMPTY}** (expects {clip.expected_model or EMPTY})"
        + (f" · {clip.prompt}" if clip.prompt else ""),
        "",
        f"**{finding.verdict}** (clip score {fmt(finding.clip_score, '.2f')}, 0 sound .. 1 broken): {finding.reason}",
        *([] if rec.model_note() is None else ["", f"⚠ This record was {rec.model_note()}."]),
        *why,
        "",
        f"**Background {state}** the report gate: model **{v.model}**, IR **{fmt(v.ir)}** "
        f"(gate ≥ {th.ir_gate:g}), "
        f"GE **{fmt(v.ge, '.2f')} px** (gate ≤ {th.ge_gate:g}).",
        f"- gate: t_inf {fmt(g.t_inf, '.4f')} → **{v.label}**, margin {fmt(v.margin, '+.4f')}"
        + ("" if g.pose_present else f" (no pose: {g.pose.reason}; fail → F)"),
        f"- H: IR {fmt(v.ir_h)}, GE {fmt(v.ge_h, '.2f')} · F: IR {fmt(v.ir_f)}, GE {fmt(v.ge_f, '.2f')}",
    ]
    if th != recorded:
        rec_state = {True: "passed", False: "failed", None: "was not judged"}[bg.consistent]
        lines.append(f"- as recorded: model {bg.model}, IR {fmt(bg.ir)}, GE {fmt(bg.ge, '.2f')}, {rec_state}")
    lines.append(f"- valid pairs {bg.valid_pairs} of {bg.total_pairs}; masks: {rec.masks_source}")
    if rec.objects:
        worst = max(rec.objects, key=lambda o: o.adap90 or 0.0)
        lines.append(
            f"- {len(rec.objects)} objects; worst AdaP90 {fmt(worst.adap90, '.3g')} px² (object {worst.object_id})"
        )
    if rec.warnings:
        lines += ["", *[f"⚠ {w}" for w in rec.warnings]]
    lines += ["", f"`{rec.clip}`", f"record `{view.folder}`"]
    return "\n".join(lines)
