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

from geocon_core.diagnostics import Overlays
from geocon_core.record import ClipRecord
from geocon_core.regate import regate_pairs
from geocon_core.results import ResultClip
from geocon_core.verdict import ClipVerdict, Thresholds

from .style import EMPTY, fmt, object_color

INLIER = (60, 200, 90)
OUTLIER = (235, 60, 50)

__all__ = [
    "ClipView",
    "Plots",
    "thumb",
    "draw_frame",
    "frame_text",
    "empty_plot",
    "render_scene",
    "render_plots",
    "clip_card",
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

    @property
    def num_frames(self) -> int:
        return self.record.video.num_frames

    @property
    def working_size(self) -> tuple[int, int]:
        w, h = self.record.video.working_size
        return int(w), int(h)


def draw_frame(view: ClipView, t: int, *, masks: bool, matches: tuple[np.ndarray, np.ndarray] | None) -> np.ndarray:
    """Frame ``t`` at display size (decoded already) with the object masks tinted in their colours
    (``masks``) and the background matches drawn (green inliers, red outliers) when given."""
    img = view.frames[t].copy()
    k = view.display_scale
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


def render_scene(server: viser.ViserServer, view: ClipView | None) -> Any:
    """Point cloud and both cameras of the selected clip; returns the point cloud's handle (or
    None)."""
    scene = server.scene
    scene.reset()
    if view is None:
        return None
    rec = view.record
    w, h = view.working_size
    fy = float(np.asarray(rec.intrinsics)[1, 1]) * rec.gate.pose.focal_scale
    fov = 2.0 * math.atan(h / 2.0 / fy)
    cloud = rec.cloud
    depth = 1.0
    cloud_handle = None
    if cloud is not None and len(cloud.xyz):
        depth = float(np.median(cloud.xyz[:, 2])) or 1.0
        cloud_handle = scene.add_point_cloud(
            "/cloud",
            points=cloud.xyz.astype(np.float32),
            colors=cloud.rgb,
            point_size=0.012 * depth,
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

    frustum("/cam_first", 0, (90, 200, 255))
    if rec.gate.pose.T_cam0_camT is not None:
        T = np.asarray(rec.gate.pose.T_cam0_camT, dtype=float)
        frustum(
            "/cam_last",
            view.num_frames - 1,
            (255, 180, 60),
            wxyz=vtf.SO3.from_matrix(T[:3, :3]).wxyz,
            position=T[:3, 3],
        )
        if np.linalg.norm(T[:3, 3]) > 0:
            scene.add_line_segments(
                "/baseline",
                np.array([[[0, 0, 0], T[:3, 3]]], np.float32),
                colors=(255, 255, 255),
                thickness=2.0,
                thickness_units="screen",
            )
    note = "no point cloud" if cloud is None else cloud.note
    scene.add_label("/note", note, position=(0.0, -0.12 * depth, 0.0))
    look_at, position, up = (0.0, 0.0, depth), (0.3 * depth, -0.45 * depth, -0.7 * depth), (0.0, -1.0, 0.0)
    cam = server.initial_camera
    cam.look_at, cam.position, cam.up = look_at, position, up
    for client in server.get_clients().values():
        client.camera.look_at = look_at
        client.camera.position = position
        client.camera.up_direction = up
    return cloud_handle


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


def clip_card(view: ClipView, v: ClipVerdict, clip: ResultClip, th: Thresholds, recorded: Thresholds) -> str:
    """The markdown card of the selected clip under the verdict ``v`` at ``th``."""
    rec = view.record
    bg, g = rec.background, rec.gate
    state = {True: "passes", False: "FAILS", None: "cannot be judged"}[v.consistent]
    lines = [
        f"### {view.clip_id}",
        f"platform **{clip.platform}** · category **{clip.category or EMPTY}** (expects {clip.expected_model or EMPTY})"
        + (f" · {clip.prompt}" if clip.prompt else ""),
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
