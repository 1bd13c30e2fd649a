"""``geocon teach``: a Viser app for teaching two-view geometry on a synthetic scene.

Sliders set the camera's rotation and translation, the background's breathing and slide, and
the disc's elasticity and the objects' speed (:mod:`.teach_scene`); menus set the render size,
the codec and where the object masks come from. Every change re-renders a short clip (320x180,
16 frames by default) into a temporary folder and scores it with the ``fast`` preset
(:func:`geocon_core.scoring.scorer.score_clip`, given the renderer's exact masks unless motion
segmentation is picked) on a background thread: a change waits briefly for the next one
(debounce), a newer change supersedes the update in progress (its rendering or scoring stops at
the next frame), and the GUI never waits. The page then shows, from the new record only
(:mod:`.teach_views`):

- **left**: one sentence on what changed and why; the frame of a pair with its background
  inliers (green) and outliers (red) and the objects tinted; the gate's label (H / U / F) with
  the measured ``t_inf`` against the 0.03 / 0.05 band and the true one of the rendered path; IR
  and GE against the report gate, and the strict IR of one homography; each object's AdaDFRC;
- **centre**: the first and last cameras as the gate's pose places them, and the two-view cloud.

Nothing here computes a score: the numbers are the record's (SPEC section 7). The server binds
to 127.0.0.1 unless told otherwise. Drive the app from Python through its GUI handles (setting
``.value`` runs the callbacks) and :meth:`TeachApp.wait`; each update's latency, from the
change to its numbers on the page, is kept on the update (:attr:`TeachApp.last_update_s`) and
logged on the ``geocon.teach`` logger.
"""

from __future__ import annotations

import logging
import math
import shutil
import tempfile
import threading
import time
from dataclasses import replace
from pathlib import Path
from typing import Any, Callable

import cv2
import numpy as np
import viser
import viser.transforms as vtf

from geocon_core.config import MultiViewConfig, preset
from geocon_core.record import ClipRecord, FrameDiagnostics
from geocon_core.scoring import Thresholds, score_clip

from ..audit import ServedApp, thumb
from ..capture import check_bind
from ..shared import track_colors
from .scene import FAMILY, SIZES, SLIDERS, TeachParams, mean_distance, render_teach_clip
from .views import (
    TeachUpdate,
    draw_matches,
    explain,
    model_name,
    numbers_html,
    pair_matches,
    tinted,
    worst_pair,
)

__all__ = ["TeachApp", "TeachParams", "TeachUpdate", "PRESET", "DEBOUNCE_S", "HISTORY"]

log = logging.getLogger("geocon.teach")

PRESET = "fast"
"""The scoring preset of every update, with the multi-view check on (a sliding panel flags the
clip and the 3D panel shows the clip's one reconstruction)."""
DISPLAY_WIDTH = 640
"""Width (px) the frame is shown at."""
DEBOUNCE_S = 0.08
"""A change waits this long (seconds) for a newer one before its clip is rendered."""
HISTORY = 200
"""How many past updates :attr:`TeachApp.updates` keeps."""

_GROUPS = (
    ("Camera", ("rotation_deg", "translation")),
    ("Background failures", ("breathing_px", "slide_px")),
    ("Objects", ("elastic_px", "object_speed")),
)


class _Superseded(Exception):
    """A newer change arrived (or the app is stopping): the update in progress stops."""


class TeachApp(ServedApp):
    """The teaching app. ``host`` and ``port`` are checked before anything starts
    (:func:`~.processes.check_bind`); a busy port moves to the next free one. The first clip is
    rendered and scored in the background at once; :meth:`wait` returns when the newest change is
    on the page. ``on_update(update)`` is called after each update (the CLI prints its latency)."""

    def __init__(
        self,
        *,
        host: str = "127.0.0.1",
        port: int = 0,
        params: TeachParams | None = None,
        debounce_s: float = DEBOUNCE_S,
        on_update: Callable[[TeachUpdate], None] | None = None,
    ) -> None:
        self.requested_port = port
        free = check_bind(host, port)
        self.params = params or TeachParams()
        self.debounce_s = debounce_s
        self.on_update = on_update
        self.cfg = preset(PRESET).with_(multiview=MultiViewConfig(enabled=True))
        self.updates: list[TeachUpdate] = []
        """The last :data:`HISTORY` updates shown, oldest first, without their frames."""
        self.last: TeachUpdate | None = None
        """The update on the page."""
        self._workdir = Path(tempfile.mkdtemp(prefix="geocon-teach-"))
        self._distances: dict[tuple[int, int, int], float] = {}
        self._cv = threading.Condition()
        self._requested = 0
        self._shown = 0
        self._pending: tuple[int, TeachParams, float] | None = None
        self._stop = threading.Event()
        self._pair: int | None = None  # the pair the user picked (None: the worst one of each update)
        self._syncing = False
        self._moving_pair = False
        self._camera_set = False
        self.server = viser.ViserServer(host=host, port=free, label="GeoCon teach", verbose=False)
        self.server.gui.configure_theme(
            control_width="large",
            show_logo=False,
            show_share_button=False,
            brand_color=(40, 110, 180),
        )
        self.server.gui.main_panel.dock_right()
        self.server.scene.set_up_direction("-y")
        self._build_gui()
        self._worker = threading.Thread(target=self._run, name="geocon-teach", daemon=True)
        self._worker.start()
        self.request(self.params)

    # --- server --------------------------------------------------------------------------------
    @property
    def last_update_s(self) -> float | None:
        """Seconds from the change on the page to its numbers (None before the first update)."""
        return None if self.last is None else self.last.latency_s

    def stop(self) -> None:
        """Stop the worker (an update in progress stops at its next frame) and the server (its
        port is free when this returns), and remove the temporary clips."""
        self._stop.set()
        with self._cv:
            self._cv.notify_all()
        self._worker.join(timeout=60.0)
        self.server.stop()
        shutil.rmtree(self._workdir, ignore_errors=True)

    # --- GUI -----------------------------------------------------------------------------------
    def _build_gui(self) -> None:
        gui, p = self.server.gui, self.params
        gui.add_markdown(
            f"**GeoCon teach** · a synthetic scene (the {FAMILY} layout: a wall, two panels, a disc and a card), "
            f"re-rendered and scored with the `{PRESET}` preset after every change. Hover a control for what it does."
        )
        by_name = {s.name: s for s in SLIDERS}
        self.sliders: dict[str, Any] = {}
        for title, names in _GROUPS:
            with gui.add_folder(title):
                for name in names:
                    s = by_name[name]
                    unit = f" ({s.unit.strip()})" if s.unit.strip() else ""
                    self.sliders[name] = gui.add_slider(
                        f"{s.label}{unit}", s.low, s.high, s.step, getattr(p, name), hint=s.hint
                    )
        with gui.add_folder("Clip"):
            self.size = gui.add_dropdown("size", SIZES, initial_value=p.size, hint="Render size, px")
            self.codec = gui.add_dropdown(
                "codec", ("h264", "png"), initial_value=p.codec, hint="H.264 MP4 (lossy) or lossless PNG frames"
            )
            self.masks = gui.add_dropdown(
                "masks",
                ("rendered", "motion"),
                initial_value=p.masks,
                hint="The renderer's exact object masks, or the scorer's built-in motion segmentation",
            )
        self.status_md = gui.add_markdown("rendering the first clip…")
        for handle in (*self.sliders.values(), self.size, self.codec, self.masks):
            handle.on_update(lambda _: self._on_change())

        self.frame_panel = gui.add_panel()
        with self.frame_panel.add_tab("What changed"):
            self.explain_md = gui.add_markdown("")
            self.image = gui.add_image(np.full((36, 64, 3), 235, np.uint8), format="jpeg", jpeg_quality=85)
            self.pair_slider = gui.add_slider(
                "pair (t, t+1)", 0, max(1, p.num_frames - 2), 1, 0, hint="The pair shown (default: the lowest IR)"
            )
            self.pair_slider.on_update(lambda e: self._on_pair(int(e.target.value)))
            self.caption_md = gui.add_markdown("")
            self.numbers = gui.add_html("")
        self.frame_panel.dock_left()
        self.frame_panel.set_width(DISPLAY_WIDTH + 30)

    def _params_from_gui(self) -> TeachParams:
        values: dict[str, Any] = {name: float(h.value) for name, h in self.sliders.items()}
        values.update(size=str(self.size.value), codec=str(self.codec.value), masks=str(self.masks.value))
        return replace(self.params, **values)

    def _on_change(self) -> None:
        if self._syncing:
            return
        try:
            params = self._params_from_gui()
        except ValueError as exc:
            self.status_md.content = f"⚠ {exc}"
            return
        self.request(params)

    def set_params(self, params: TeachParams) -> int:
        """Move every control to ``params`` and ask for one update (one change, however many
        controls move). Returns the request's number."""
        self._syncing = True
        try:
            for name, handle in self.sliders.items():
                handle.value = getattr(params, name)
            self.size.value = params.size  # type: ignore[misc]  # viser setter typing gap
            self.codec.value = params.codec  # type: ignore[misc]
            self.masks.value = params.masks  # type: ignore[misc]
        finally:
            self._syncing = False
        return self.request(params)

    # --- the worker ----------------------------------------------------------------------------
    def request(self, params: TeachParams) -> int:
        """Ask for an update with ``params`` and return at once (the request's number); a newer
        request supersedes it."""
        with self._cv:
            self._requested += 1
            self.params = params
            self._pending = (self._requested, params, time.perf_counter())
            self._cv.notify_all()
            return self._requested

    def wait(self, timeout: float = 60.0) -> TeachUpdate:
        """Block until the newest request made so far is on the page and return its update.
        Raises TimeoutError after ``timeout`` seconds."""
        with self._cv:
            target = self._requested
            if not self._cv.wait_for(lambda: self._shown >= target, timeout):
                raise TimeoutError(f"no update on the page within {timeout:g} s")
            assert self.last is not None
            return self.last

    def _take(self) -> tuple[int, TeachParams, float] | None:
        """The newest request once ``debounce_s`` passed without a newer one (None: stopping)."""
        with self._cv:
            while not self._stop.is_set():
                if self._pending is None:
                    self._cv.wait()
                    continue
                remaining = self._pending[2] + self.debounce_s - time.perf_counter()
                if remaining > 0:
                    self._cv.wait(remaining)
                    continue
                job, self._pending = self._pending, None
                return job
            return None

    def _run(self) -> None:
        while (job := self._take()) is not None:
            index, params, asked_at = job
            self.status_md.content = "rendering and scoring…"
            try:
                update = self._compute(index, params)
            except _Superseded:
                shutil.rmtree(self._folder(index), ignore_errors=True)
                continue
            except Exception as exc:  # shown on the page; the app keeps serving
                log.exception("teach update %d failed", index)
                shutil.rmtree(self._folder(index), ignore_errors=True)
                update = TeachUpdate(index, params, None, None, error=f"{type(exc).__name__}: {exc}")
                update = replace(update, explanation=explain(self.last, update))
            self._show(update, asked_at)

    def _folder(self, index: int) -> Path:
        """Where update ``index`` renders its clip."""
        return self._workdir / f"update-{index:05d}"

    def _check(self, index: int) -> Callable[[], None]:
        def check() -> None:
            if self._stop.is_set() or self._requested != index:
                raise _Superseded

        return check

    def _distance(self, params: TeachParams) -> float:
        w, h = params.width_height
        key = (params.seed, w, h)
        if key not in self._distances:
            self._distances[key] = mean_distance(*key)
        return self._distances[key]

    def _compute(self, index: int, params: TeachParams) -> TeachUpdate:
        """Render and score the clip of ``params``; raises _Superseded when a newer request came."""
        check = self._check(index)
        start = time.perf_counter()
        clip = render_teach_clip(params, self._folder(index), distance=self._distance(params), check=check)
        rendered = time.perf_counter()
        frames: dict[int, np.ndarray] = {}

        def on_frame(d: FrameDiagnostics) -> None:  # the working-canvas frames and masks the scorer used
            check()
            rgb = d.frame.rgb
            size = (DISPLAY_WIDTH, round(rgb.shape[0] * DISPLAY_WIDTH / rgb.shape[1]))
            frames[d.index] = cv2.resize(tinted(rgb, d.labels), size, interpolation=cv2.INTER_LINEAR)

        record = score_clip(
            clip.video,
            self.cfg,
            masks=clip.masks if params.masks == "rendered" else None,
            on_frame=on_frame,
            progress=lambda _done, _total: check(),
        )
        scored = time.perf_counter()
        check()
        update = TeachUpdate(
            index,
            params,
            record,
            clip,
            render_s=rendered - start,
            score_s=scored - rendered,
            frames=frames,
            display_scale=DISPLAY_WIDTH / record.video.working_size[0],
        )
        return replace(update, explanation=explain(self.last, update))

    def _show(self, update: TeachUpdate, asked_at: float) -> None:
        """Put ``update`` on the page; its latency runs from ``asked_at`` to here."""
        self.explain_md.content = f"**{update.explanation}**"
        self.numbers.content = numbers_html(update)
        if update.record is not None:
            n = update.record.video.num_frames
            self.pair_slider.max = max(1, n - 2)
            t = self._pair if self._pair is not None else worst_pair(update.record)
            self._show_pair(min(t if t is not None else (n - 2) // 2, n - 2))
            self._draw_pair(update)
            self._draw_scene(update)
        latency = time.perf_counter() - asked_at
        update = replace(update, latency_s=latency)
        previous, self.last = self.last, update
        self.updates = [*self.updates[-(HISTORY - 1) :], replace(update, frames={})]
        self.status_md.content = (
            f"update {update.index}: **{latency:.2f} s** from the change to the numbers "
            f"(render {update.render_s:.2f} s, score {update.score_s:.2f} s)"
        )
        log.info(
            "teach update %d: %.2f s (render %.2f s, score %.2f s): %s",
            update.index,
            latency,
            update.render_s,
            update.score_s,
            update.explanation,
        )
        if previous is not None and previous.clip is not None:
            shutil.rmtree(previous.clip.video.parent, ignore_errors=True)
        with self._cv:
            self._shown = update.index
            self._cv.notify_all()
        if self.on_update is not None:
            self.on_update(update)

    # --- drawing -------------------------------------------------------------------------------
    def _show_pair(self, t: int) -> None:
        """Move the pair slider to ``t`` without pinning the choice."""
        self._moving_pair = True
        try:
            self.pair_slider.value = t  # type: ignore[misc]  # viser setter typing gap
        finally:
            self._moving_pair = False

    def _on_pair(self, t: int) -> None:
        if self._moving_pair:
            return
        self._pair = t  # the user's choice: kept across updates
        last = self.last
        if last is not None and last.record is not None:
            self._draw_pair(last)

    def _draw_pair(self, update: TeachUpdate) -> None:
        """The frame of the pair picked with its background inliers/outliers, and the caption."""
        rec, clip = update.record, update.clip
        assert rec is not None and clip is not None
        n = rec.video.num_frames
        t = min(int(self.pair_slider.value), n - 2)
        matches = pair_matches(rec, t)
        if t in update.frames:
            frame = update.frames[t]
            xy, inl = (np.zeros((0, 2)), np.zeros(0, bool)) if matches is None else matches
            self.image.image = draw_matches(frame, xy * update.display_scale, inl)
        model = rec.background.model
        tau = Thresholds.of(rec.config).tau(model)
        unit = "px (transfer error)" if model == "H" else "(normalised Sampson distance)"
        if matches is None:
            self.caption_md.content = f"pair ({t}, {t + 1}): no background fit under {model}"
        else:
            k, m = int(matches[1].sum()), len(matches[1])
            self.caption_md.content = (
                f"pair ({t}, {t + 1}): **{k} of {m}** background matches are inliers (green) of the "
                f"{model_name(model)} ({model}, τ {tau:g} {unit}); red: outliers; objects tinted"
            )

    def _draw_reconstruction(self, rec: ClipRecord, depth: float) -> None:
        """The clip's one reconstruction beside the two-view cloud: its points coloured by residual
        (a drifting layer in magenta), scaled to the same median distance; on a sphere for a
        camera that only turns."""
        scene, mv = self.server.scene, rec.multiview
        if mv is None or mv.points is None or mv.residual is None or not len(mv.points):
            scene.remove_by_name("/clip_points")
            return
        pts = np.asarray(mv.points, dtype=float)
        ok = np.all(np.isfinite(pts), axis=1) & (pts[:, 2] > 0)
        if not ok.any():
            scene.remove_by_name("/clip_points")
            return
        dist = np.linalg.norm(pts, axis=1)
        pts = pts / float(np.median(dist[ok])) * depth
        ok &= dist <= 5 * float(np.median(dist[ok]))  # a few far points would shrink the rest to a dot
        colors = track_colors(mv.residual, rec.config.multiview.tau_px, mv.layer_of)
        scene.add_point_cloud(
            "/clip_points",
            points=pts[ok].astype(np.float32),
            colors=colors[ok],
            point_size=0.015 * depth,
            precision="float32",
        )

    def _draw_scene(self, update: TeachUpdate) -> None:
        """The two-view cloud of the record, the first camera, the last one where the gate's pose
        puts it (orange) and where the renderer put it (grey), both at unit mean scene distance."""
        rec = update.record
        assert rec is not None
        scene = self.server.scene
        w, h = rec.video.working_size
        fy = float(np.asarray(rec.intrinsics)[1, 1]) * rec.gate.pose.focal_scale
        fov = 2.0 * math.atan(h / 2.0 / fy)
        cloud = rec.cloud
        depth = 1.0
        if cloud is not None and len(cloud.xyz):
            depth = float(np.median(cloud.xyz[:, 2])) or 1.0
            scene.add_point_cloud(
                "/cloud",
                points=cloud.xyz.astype(np.float32),
                colors=cloud.rgb,
                point_size=0.02 * depth,
                point_shape="circle",
            )
        else:
            scene.remove_by_name("/cloud")
        scene.add_label("/note", "no point cloud" if cloud is None else cloud.note, position=(0.0, -0.15 * depth, 0.0))
        self._draw_reconstruction(rec, depth)

        def frustum(name: str, T_cam0_cam: np.ndarray, color: tuple[int, int, int], t: int | None) -> None:
            img = None if t is None else update.frames.get(t)
            scene.add_camera_frustum(
                name,
                fov=fov,
                aspect=w / h,
                scale=0.12 * depth,
                thickness=(0.004 if t is not None else 0.002) * depth,
                color=color,
                image=None if img is None else thumb(img),
                format="jpeg",
                jpeg_quality=80,
                wxyz=vtf.SO3.from_matrix(T_cam0_cam[:3, :3]).wxyz,
                position=T_cam0_cam[:3, 3],
            )

        frustum("/cam_first", np.eye(4), (90, 200, 255), 0)
        if update.clip is not None:
            frustum("/cam_last_truth", update.clip.T_cam0_camT_truth, (150, 150, 150), None)
        T = rec.gate.pose.T_cam0_camT
        if T is None:
            scene.remove_by_name("/cam_last")
        else:
            frustum("/cam_last", np.asarray(T, dtype=float), (255, 180, 60), rec.video.num_frames - 1)
        if not self._camera_set:  # once: later updates keep the viewpoint a user chose
            cam = self.server.initial_camera
            cam.look_at, cam.up = (0.0, 0.0, 0.4 * depth), (0.0, -1.0, 0.0)
            cam.position = (0.6 * depth, -0.35 * depth, -0.6 * depth)
            self._camera_set = True
