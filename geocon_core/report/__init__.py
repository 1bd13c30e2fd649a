"""Statistics and the HTML report of a results folder (the ``bench`` extra: pandas, matplotlib).

:mod:`.stats` and :mod:`.gate_stats` turn the tables into per-platform, per-category statistics
with confidence intervals; :func:`build_report` (:mod:`.pages`) writes the report with its figures
(:mod:`.figures`) and the clips' thumbnails (:mod:`geocon_core.results`).
"""

from __future__ import annotations

from .figures import (
    Figure,
    FigureBuilder,
    Overlap,
    fig_calibration,
    fig_dynamic,
    fig_effects,
    fig_margins,
    fig_ridgelines,
    fig_sensitivity,
    fig_summary_failures,
    fig_summary_margins,
    fig_summary_platforms,
    fig_tinf,
    fix_tick_labels,
    platform_order,
    tick_label_overlaps,
)
from .gate_stats import (
    TAU_GRID,
    Interval,
    TauBootstrap,
    balanced_accuracy,
    bootstrap_tau,
    calibration_bins,
    net_benefit,
    wilson_interval,
)
from .pages import (
    REPORT_ENTRIES,
    ReportError,
    ReportResult,
    build_report,
)
from .stats import (
    EXPECTED_MODEL,
    adap90_summary,
    bootstrap_median_ci,
    consensus,
    coverage_table,
    gate_rates,
    margin_summary,
    median_difference_ci,
    percentile_aligned,
    scene_balanced_median,
    scene_balanced_table,
    sensitivity_table,
    top_hardest,
)

__all__ = [
    "TAU_GRID",
    "Interval",
    "TauBootstrap",
    "wilson_interval",
    "calibration_bins",
    "net_benefit",
    "balanced_accuracy",
    "bootstrap_tau",
    "EXPECTED_MODEL",
    "scene_balanced_median",
    "bootstrap_median_ci",
    "median_difference_ci",
    "scene_balanced_table",
    "gate_rates",
    "coverage_table",
    "consensus",
    "margin_summary",
    "percentile_aligned",
    "adap90_summary",
    "top_hardest",
    "sensitivity_table",
    "Figure",
    "FigureBuilder",
    "Overlap",
    "tick_label_overlaps",
    "fix_tick_labels",
    "fig_summary_platforms",
    "fig_summary_margins",
    "fig_summary_failures",
    "platform_order",
    "fig_tinf",
    "fig_margins",
    "fig_calibration",
    "fig_ridgelines",
    "fig_effects",
    "fig_dynamic",
    "fig_sensitivity",
    "REPORT_ENTRIES",
    "ReportError",
    "ReportResult",
    "build_report",
]
