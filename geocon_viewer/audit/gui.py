"""The panels of the ``geocon serve`` audit app: the control panel (triage list, clip picker,
thresholds), the frame panel (frame, slider, audit card, Rerun button) and the plots panel. Only
the handles are made here; :class:`~geocon_viewer.audit.app.AuditApp` hooks them to its callbacks."""

from __future__ import annotations

from typing import Any

import numpy as np
import viser

from geocon_core.results import VERDICTS, ResultsIndex
from geocon_core.scoring import Thresholds
from geocon_core.signals import MAP_NAMES

from .triage import LIST_ROWS, THRESHOLD_LABELS
from .views import MAP_MENU, PAIR_FIRST_LAST, empty_plot, map_choice

__all__ = ["AuditPanels", "ANY", "FLAGGED"]

ANY = "any"
FLAGGED = "flagged"


class AuditPanels:
    """The GUI handles of the audit app, made by :meth:`build_panels` on ``server`` for ``index``
    (the threshold inputs start at ``thresholds``)."""

    server: viser.ViserServer
    index: ResultsIndex
    thresholds: Thresholds

    def build_panels(self) -> None:
        """Make every panel and handle (no callbacks yet)."""
        gui = self.server.gui
        facets = self.index.facets()
        n = len(self.index.clips)
        title = f"{self.index.root.name}: {n} clip{'s' if n != 1 else ''}" + (
            f" · config {self.index.config_hash}" if self.index.config_hash else ""
        )
        gui.add_markdown(f"**GeoCon audit** · {title}")
        with gui.add_folder("Triage"):
            self.platform = gui.add_dropdown("platform", [ANY, *facets["platform"]], initial_value=ANY)
            self.category = gui.add_dropdown("category", [ANY, *facets["category"]], initial_value=ANY)
            self.gate_label = gui.add_dropdown("gate label", [ANY, "H", "F", "U"], initial_value=ANY)
            self.state = gui.add_dropdown(
                "verdict",
                [ANY, FLAGGED, *VERDICTS],
                initial_value=ANY,
                hint="flagged: not passing, or the gate disagrees with the clip's category",
            )
            self.summary_md = gui.add_markdown("")
            self.table_md = gui.add_markdown("")
            self.page = gui.add_number("page", 1, min=1, step=1, hint=f"{LIST_ROWS} clips a page, most severe first")
            self.clip = gui.add_dropdown(
                "clip",
                ["(none)"],
                initial_value="(none)",
                hint="The clip shown in the scene, the frame panel and the plots",
            )
            self.step_buttons = gui.add_button_group("", ["◀ more severe", "less severe ▶"])
        with gui.add_folder("Thresholds"):
            self.number: dict[str, Any] = {}
            for name, (label, step, hint) in THRESHOLD_LABELS.items():
                self.number[name] = gui.add_number(label, getattr(self.thresholds, name), min=0.0, step=step, hint=hint)
            self.reset = gui.add_button("Reset to the recorded thresholds")
            self.thresholds_md = gui.add_markdown("")
            self.preload_bar = gui.add_progress_bar(0.0, visible=False)
        with gui.add_folder("3D scene"):
            self.pair = gui.add_dropdown(
                "pair",
                [PAIR_FIRST_LAST],
                initial_value=PAIR_FIRST_LAST,
                hint="The frame pair whose cloud and cameras the 3D scene shows: first/last, or a gate window",
            )
            self.pair_md = gui.add_markdown("")
            self.legend_html = gui.add_html("")
        self.frame_panel = gui.add_panel()
        with self.frame_panel.add_tab("Frame", icon=None):
            self.image = gui.add_image(np.zeros((36, 64, 3), np.uint8), format="jpeg", jpeg_quality=85)
            self.slider = gui.add_slider("frame", 0, 1, 1, 0)
            self.play = gui.add_checkbox("play", False)
            self.show_matches = gui.add_checkbox(
                "inliers / outliers", True, hint="Background matches of the pair (t, t+1): green inliers, red outliers"
            )
            self.show_masks = gui.add_checkbox("object masks", True)
            self.reading_map = gui.add_dropdown(
                MAP_MENU,
                [map_choice(None), *(map_choice(name) for name in MAP_NAMES)],
                initial_value=map_choice(None),
                hint="Where a reading of the clip score fires over the whole clip (brighter: more often); "
                "a flagged clip opens on the one its score leans on most",
            )
            self.frame_md = gui.add_markdown("")
        with self.frame_panel.add_tab("Audit card"):
            self.card_md = gui.add_markdown("")
            self.rrd_button = gui.add_button(
                "Write the Rerun recording (.rrd)",
                hint="For a bug report: writes audit.rrd beside the record and offers it as a download",
            )
            self.rrd_md = gui.add_markdown("")
        self.frame_panel.dock_left()
        self.frame_panel.set_width(470)
        self.plot_panel = gui.add_panel()
        with self.plot_panel.add_tab("Background"):
            self.ir_plot = empty_plot(self.server, "IR per pair")
            self.ge_plot = empty_plot(self.server, "GE per pair (px)")
        with self.plot_panel.add_tab("Objects"):
            self.obj_plot = empty_plot(self.server, "AdaDFRC D_t per object (px²)")
        with self.plot_panel.add_tab("Gate"):
            self.gate_plot = empty_plot(self.server, "t_inf per window")
        self.plot_panel.dock_below(self.frame_panel)
