"""``geocon serve``: the Viser audit app over a results folder.

One page for triaging a whole benchmark (or one scored clip):

- **control panel** (right): the triage list, most severe first (:func:`geocon_core.results.triage.severity_key`),
  filterable by platform, category, gate label and verdict; the clip picker; and the thresholds
  (tau_H, tau_F, the IR/GE report gates, the hysteresis gate) with what differs from the recorded
  configuration;
- **3D scene**: the selected clip's first/last point cloud and both cameras as frustums showing
  the first and last frames; with dense clouds in the record, the residual-coloured dense cloud of
  the first/last pair or of a gate window (picked in the control panel's *3D scene* folder, with the
  colour legend);
- **Frame panel** (left): the current frame with its background inliers/outliers under the
  thresholds of the moment and the object masks, a frame slider with play, the audit card and a
  button that writes the clip's Rerun recording (and offers it as a download);
- **Plots panel** (left, below): per-pair IR and GE of the family in use, AdaDFRC ``D_t`` per
  object, and the gate's per-window ``t_inf`` against its thresholds.

Every number comes from :mod:`geocon_core` (records, :class:`~geocon_core.results.triage.ResultsIndex`,
:mod:`geocon_core.scoring.regate`); this module only draws. The GUI state is shared by every browser
tab connected to the server. The server binds to 127.0.0.1 unless told otherwise.
"""

from __future__ import annotations

import threading
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import viser

from geocon_core.geometry import FAMILIES
from geocon_core.media import DEFAULT_FPS
from geocon_core.record import ClipRecord, RecordError, read_overlays, read_record
from geocon_core.results import BROKEN, ResultsError, ResultsIndex, TriageRow
from geocon_core.scoring import ClipVerdict, Thresholds, pair_inliers
from geocon_core.signals import MAP_NAMES, ClipModelError

from ..capture import check_bind
from ..rerun import evidence
from .gui import ANY, FLAGGED, AuditPanels
from .served import ServedApp
from .triage import LIST_ROWS, rrd_text, thresholds_text, triage_summary, triage_table
from .views import (
    ClipView,
    Plots,
    clip_card,
    dense_legend_html,
    draw_frame,
    frame_text,
    map_choice,
    move_clip_camera,
    pair_options,
    pair_text,
    render_plots,
    render_scene,
    thumb,
)

__all__ = ["AuditApp", "ClipView", "LIST_ROWS"]

DISPLAY_WIDTH = 640
"""Width (px) the frames are shown at."""


class AuditApp(AuditPanels, ServedApp):
    """The audit app over ``results`` (a ``geocon bench`` folder or a ``geocon score`` record
    folder). Drive it from Python through its GUI handles (setting ``.value`` runs the callbacks),
    or open :attr:`url` in a browser. :meth:`stop` shuts the server down and frees its port.

    ``host`` and ``port`` are checked before anything starts (:func:`~.processes.check_bind`
    raises :class:`~.processes.BindError`); a busy ``port`` moves to the next free one
    (:attr:`requested_port` keeps the one asked for)."""

    def __init__(
        self, results: str | Path | ResultsIndex, *, host: str = "127.0.0.1", port: int = 8080, preload: bool = True
    ) -> None:
        self.requested_port = port
        free = check_bind(host, port)
        self.index = results if isinstance(results, ResultsIndex) else ResultsIndex.open(results)
        self.thresholds: Thresholds = self.index.recorded
        self.rows: list[TriageRow] = []
        self.view: ClipView | None = None
        self.verdict: ClipVerdict | None = None
        self.frame = 0
        self._lock = threading.RLock()
        self._stop = threading.Event()
        self._decoder: threading.Thread | None = None
        self.cloud_handle: Any = None
        self._pair_index = 0
        """The selected clip's point cloud in the scene (None when it has none)."""
        self.server = viser.ViserServer(host=host, port=free, label="GeoCon audit", verbose=False)
        self.server.gui.configure_theme(
            control_width="large", show_logo=False, show_share_button=False, brand_color=(40, 110, 180)
        )
        self.server.gui.main_panel.dock_right()
        self.server.scene.set_up_direction("-y")
        self.build_panels()
        self._wire_gui()
        self.refresh()
        self._preload: threading.Thread | None = None
        if preload and self.index.kind == "bench":
            self._preload = threading.Thread(target=self._preload_residuals, name="geocon-preload", daemon=True)
            self._preload.start()
        self._player = threading.Thread(target=self._play_loop, name="geocon-play", daemon=True)
        self._player.start()

    # --- server ------------------------------------------------------------------------------
    def stop(self) -> None:
        """Stop the background threads and the server (its port is free when this returns)."""
        self._stop.set()
        if self.view is not None:
            self.view.cancel.set()
        for thread in (self._decoder, self._preload, self._player):
            if thread is not None:
                thread.join(timeout=5.0)
        self.server.stop()

    # --- GUI ---------------------------------------------------------------------------------
    def _wire_gui(self) -> None:
        """Hook the panels' handles to the app's callbacks."""
        for handle in (self.platform, self.category, self.gate_label, self.state):
            handle.on_update(lambda _: self._on_filters())
        self.page.on_update(lambda _: self._render_table())
        self.clip.on_update(lambda e: self._on_clip(e.target.value))
        self.step_buttons.on_click(lambda e: self._step(-1 if e.target.value.startswith("◀") else 1))
        for name, handle in self.number.items():
            handle.on_update(lambda e, name=name: self._on_threshold(name, e.target.value))
        self.reset.on_click(lambda _: self._reset_thresholds())

        self.slider.on_update(lambda e: self._on_frame(int(e.target.value)))
        self.pair.on_update(lambda e: self._on_pair(e.target.value))
        for box in (self.show_matches, self.show_masks, self.reading_map):
            box.on_update(lambda _: self._render_frame())

        def on_rrd(_: object) -> None:
            self.write_rrd(background=True)

        self.rrd_button.on_click(on_rrd)

    # --- triage list ---------------------------------------------------------------------------
    def _filters(self) -> dict[str, Any]:
        def pick(handle) -> str | None:
            return None if handle.value == ANY else handle.value

        state = self.state.value
        return {
            "platform": pick(self.platform),
            "category": pick(self.category),
            "gate_label": pick(self.gate_label),
            "state": None if state in (ANY, FLAGGED) else state,
            "flagged_only": state == FLAGGED,
        }

    def refresh(self, *, keep_selection: bool = True) -> None:
        """Re-gate and re-sort the list under the current thresholds and filters, then redraw."""
        with self._lock:
            self.rows = self.index.triage(self.thresholds, **self._filters())
            ids = [r.clip_id for r in self.rows]
            current = self.clip.value if keep_selection else None
            options = ids or ["(none)"]
            target = current if current in ids else options[0]
            self.clip.options = options
            self._render_summary()
            self._render_table()
            if self.clip.value != target:
                self.clip.value = target  # type: ignore[misc]  # runs _on_clip; viser setter typing gap
            elif self.view is None or self.view.clip_id != target:
                self._on_clip(target)
            else:
                self._refresh_selected()

    def _render_summary(self) -> None:
        self.summary_md.content = triage_summary(self.rows, self.index.counts(self.rows), len(self.index.clips))

    def _render_table(self) -> None:
        selected = None if self.view is None else self.view.clip_id
        self.table_md.content = triage_table(self.rows, int(self.page.value), selected)

    def _on_filters(self) -> None:
        self.page.value = 1  # type: ignore[misc]  # viser setter typing gap
        self.refresh()

    def _step(self, delta: int) -> None:
        ids = [r.clip_id for r in self.rows]
        if not ids:
            return
        i = ids.index(self.clip.value) if self.clip.value in ids else 0
        self.clip.value = ids[min(max(i + delta, 0), len(ids) - 1)]  # type: ignore[misc]  # viser setter typing gap

    # --- thresholds ----------------------------------------------------------------------------
    def _on_threshold(self, name: str, value: float) -> None:
        try:
            new = replace(self.thresholds, **{name: float(value)})
        except ValueError as exc:
            self.thresholds_md.content = f"⚠ {exc}; keeping {getattr(self.thresholds, name):g}"
            return
        if new == self.thresholds:
            return
        self.thresholds = new
        pending = sum(c.status == "ok" for c in self.index.clips) - self.index.loaded()
        if pending > 0 and any(new.tau(f) != self.index.recorded.tau(f) for f in FAMILIES):
            self.thresholds_md.content = f"re-gating… (reading the stored residuals of {pending} more clips first)"
        self.refresh()

    def _reset_thresholds(self) -> None:
        self.thresholds = self.index.recorded
        for name, handle in self.number.items():
            handle.value = getattr(self.thresholds, name)  # each a no-op re-gate once equal
        self.refresh()

    def _render_thresholds(self) -> None:
        self.thresholds_md.content = thresholds_text(self.thresholds, self.index.recorded, self.index.config_hash)

    def _preload_residuals(self) -> None:
        bar = self.preload_bar
        bar.visible = True

        def progress(done: int, total: int) -> None:
            bar.value = 100.0 * done / max(total, 1)  # type: ignore[misc]  # viser setter typing gap

        broken = self._broken()
        try:
            self.index.preload(progress=progress, stop=self._stop)  # lists unreadable records as broken
        except (OSError, ValueError, ResultsError):
            pass  # anything else wrong with a record is reported when it is selected or re-gated
        finally:
            bar.visible = False
        if self._broken() != broken and not self._stop.is_set():
            self.refresh()  # the clips found broken are listed as such

    def _broken(self) -> int:
        return sum(c.status == BROKEN for c in self.index.clips)

    # --- the selected clip ---------------------------------------------------------------------
    def _on_clip(self, clip_id: str) -> None:
        if clip_id not in self.index.by_id:
            return
        with self._lock:
            clip = self.index.by_id[clip_id]
            if self.view is not None:
                self.view.cancel.set()
            self.view = None
            self.verdict = self.index.verdict(clip_id, self.thresholds)
            if clip.status != "ok" or clip.folder is None:
                self._show_failed(clip_id)
                return
            try:
                record = read_record(clip.folder)
            except (RecordError, ClipModelError) as exc:  # listed as broken from now on, with the reason
                self.index.mark_broken(clip_id, str(exc))
                self.refresh()
                return
            try:
                overlays = read_overlays(clip.folder, record)
            except (OSError, ValueError):  # unreadable masks: the clip is shown without them
                overlays = None
            w, _ = record.video.working_size
            view = ClipView(clip_id, clip.folder, record, overlays, display_scale=min(1.0, DISPLAY_WIDTH / w))
            self.view = view
            n = view.num_frames
            self.slider.max = max(1, n - 1)
            # a flagged clip opens on its evidence: the reading map its score leans on and the frame
            # where that reading is strongest (or the worst background pair)
            shown_map, at = evidence(record)
            self.reading_map.value = map_choice(shown_map)  # type: ignore[misc]  # viser setter typing gap
            self.frame = min(self.frame if at is None else at, n - 1)
            if at is not None and int(self.slider.value) != self.frame:
                self.slider.value = self.frame  # type: ignore[misc]  # viser setter typing gap
            self._show_pairs(record)
            self.cloud_handle = render_scene(self.server, self.view, self._pair_index)
            move_clip_camera(view, self.frame)
            self._refresh_selected()
            self.rrd_md.content = self._rrd_text()
        self._decoder = threading.Thread(target=self._decode_frames, args=(view,), name="geocon-frames", daemon=True)
        self._decoder.start()

    def _show_pairs(self, record: ClipRecord) -> None:
        """The 3D tab of a newly selected clip: its pairs, the first/last one shown, the legend."""
        options = pair_options(record)
        # a clip the multi-view check failed opens on its evidence: the clip's one reconstruction
        self._pair_index = len(options) - 1 if record.drift_finding() is not None else 0
        self.pair.options = options
        if self.pair.value != options[self._pair_index]:
            self.pair.value = options[self._pair_index]  # type: ignore[misc]  # viser setter typing gap
        self.pair_md.content = pair_text(record, self._pair_index)
        self.legend_html.content = dense_legend_html(record)

    def _on_pair(self, value: str) -> None:
        with self._lock:
            view = self.view
            if view is None or value not in self.pair.options:
                return
            index = list(self.pair.options).index(value)
            if index == self._pair_index:
                return
            self._pair_index = index
            self.cloud_handle = render_scene(self.server, view, index)
            move_clip_camera(view, self.frame)
            self.pair_md.content = pair_text(view.record, index)

    def _show_failed(self, clip_id: str) -> None:
        clip = self.index.by_id[clip_id]
        self.server.scene.reset()
        self.cloud_handle = None
        what = "Its saved record could not be read" if clip.status == BROKEN else "This clip could not be scored"
        self.card_md.content = f"### {clip_id}\n\n**{what}.**\n\n```\n{clip.error}\n```"
        self.frame_md.content = "no frames: the clip has no readable record"
        self.image.image = np.full((36, 64, 3), 40, np.uint8)
        self._render_thresholds()
        self._render_table()

    def _refresh_selected(self) -> None:
        """Everything that depends on the thresholds: verdict, card, plots, overlay."""
        view = self.view
        self._render_thresholds()
        if view is None:
            return
        self.verdict = v = self.index.verdict(view.clip_id, self.thresholds)
        if v is None:  # its record turned out unreadable (re-gating read it): listed as broken now
            self.view = None
            view.cancel.set()
            self.refresh()
            return
        self.card_md.content = clip_card(view, v, self.index.by_id[view.clip_id], self.thresholds, self.index.recorded)
        plots = Plots(self.ir_plot, self.ge_plot, self.obj_plot, self.gate_plot)
        render_plots(plots, view, v, self.thresholds)
        self._render_frame()
        self._render_table()

    def _decode_frames(self, view: ClipView) -> None:
        """Decode the clip of ``view`` into its display frames, in a background thread.

        Every write into the scene or the GUI happens under the app's lock and only while ``view``
        is still the selected clip: a clip switch (or a pair switch, which rebuilds the frustums)
        holds the same lock, so no write can reach a handle it removed. The thread stops as soon as
        another clip is selected or the app stops."""
        from geocon_core.media import ClipError, iter_frames, locate_clip

        def current() -> bool:
            return view is self.view and not view.cancel.is_set() and not self._stop.is_set()

        try:
            info = locate_clip(view.record.video, view.folder)
            for f in iter_frames(info):
                if not current():
                    return
                img = f.rgb
                if view.display_scale < 1.0:
                    img = cv2.resize(
                        img, None, fx=view.display_scale, fy=view.display_scale, interpolation=cv2.INTER_AREA
                    )
                view.frames[f.index] = img
                with self._lock:
                    if not current():
                        return
                    handle = view.frustums.get(f.index)
                    if handle is not None:
                        handle.image = thumb(img)
                    if f.index == self.frame:
                        self._render_frame()
        except (ClipError, OSError, ValueError) as exc:
            view.frames_error = f"frames not shown: {exc}"
            with self._lock:
                if current():
                    self._render_frame()
        finally:
            view.frames_ready.set()

    def _on_frame(self, t: int) -> None:
        self.frame = t
        if self.view is not None:
            move_clip_camera(self.view, t)
        self._render_frame()

    def _play_loop(self) -> None:
        while not self._stop.wait(0.0):
            view = self.view
            fps = view.record.video.fps if view is not None else DEFAULT_FPS
            time.sleep(1.0 / min(max(fps, 1.0), 12.0))
            if self.play.value and view is not None and view.num_frames > 1:
                self.slider.value = (int(self.slider.value) + 1) % view.num_frames  # type: ignore[misc]  # viser setter typing gap

    # --- drawing -------------------------------------------------------------------------------
    def frame_matches(self, t: int) -> tuple[np.ndarray, np.ndarray] | None:
        """(x_t at working pixels, inlier mask) of the background matches of the gap-1 pair
        starting at ``t`` at the largest scale, under the family and threshold in use."""
        view, v = self.view, self.verdict
        if view is None or v is None:
            return None
        rec = view.record
        s = max(rec.config.scales)
        for p in rec.pairs:
            if p.t0 == t and p.gap == min(rec.config.gaps) and p.scale == s and p.skip is None:
                fit = p.fit(v.model)
                if fit is None or fit.model is None:
                    return None
                tau = self.thresholds.tau(v.model)
                return rec.matches.x1[rec.matches.rows(p.index)] / s, pair_inliers(rec, p.index, v.model, tau)
        return None

    def frame_image(self, t: int, matches: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray | None:
        """The frame shown for ``t`` with the chosen overlays (None before it is decoded);
        ``matches`` is :meth:`frame_matches` of ``t`` when the caller has it already."""
        view = self.view
        if view is None or t not in view.frames:
            return None
        if self.show_matches.value and matches is None:
            matches = self.frame_matches(t)
        chosen = {map_choice(name): name for name in MAP_NAMES}.get(str(self.reading_map.value))
        return draw_frame(
            view,
            t,
            masks=bool(self.show_masks.value),
            matches=matches if self.show_matches.value else None,
            reading_map=chosen,
        )

    def _render_frame(self) -> None:
        view, t = self.view, self.frame
        if view is None:
            return
        matches = self.frame_matches(t)
        img = self.frame_image(t, matches)
        if img is not None:
            self.image.image = img
        self.frame_md.content = frame_text(view, t, matches, self.verdict, shown=img is not None)

    # --- recordings ----------------------------------------------------------------------------
    def _rrd_text(self) -> str:
        return "" if self.view is None else rrd_text(self.view.folder)

    def write_rrd(self, *, background: bool = False) -> Path | None:
        """Write the selected clip's Rerun recording to ``audit.rrd`` in its record folder and
        offer it to connected browsers as a download. Returns the path (None in the background)."""
        view = self.view
        if view is None:
            return None
        if background:
            threading.Thread(target=self.write_rrd, name="geocon-rrd", daemon=True).start()
            return None
        from ..rerun import write_rrd

        self.rrd_button.disabled = True
        self.rrd_md.content = "writing the recording…"
        try:
            path = write_rrd(view.folder, view.folder / "audit.rrd")
        except (OSError, ValueError, RuntimeError) as exc:
            self.rrd_md.content = f"⚠ could not write the recording: {exc}"
            return None
        finally:
            self.rrd_button.disabled = False
        assert path is not None
        if view is self.view:
            self.rrd_md.content = self._rrd_text()
        if self.server.get_clients():
            self.server.send_file_download(f"{view.clip_id}.rrd", path.read_bytes())
        return path
