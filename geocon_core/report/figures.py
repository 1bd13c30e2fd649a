"""The figures of ``geocon report`` (see :mod:`geocon_core.report`): each a function of the
benchmark tables that draws into a :class:`FigureBuilder`, or records why the data cannot support
it."""

from __future__ import annotations

import io
import math
import textwrap
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple, Sequence

import numpy as np
import pandas as pd

from . import stats

__all__ = [
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
]

_COLORS = ("#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#e377c2", "#17becf")


@dataclass
class Figure:
    """One rendered figure of the report page; ``overlaps`` lists the tick labels that still
    overlap after :func:`fix_tick_labels` (empty when the figure reads cleanly)."""

    name: str
    title: str
    caption: str
    png: bytes
    overlaps: list["Overlap"] = field(default_factory=list)


class FigureBuilder:
    """Collects the report's figures (PNG/SVG files plus the PNG bytes for the page) and tables;
    ``gate_lines`` are the t_inf values drawn as vertical lines on the gate figures. Every figure is
    checked for overlapping tick labels before it is written (:func:`fix_tick_labels`)."""

    def __init__(self, out: Path, footer: str, formats: Sequence[str], gate_lines: Sequence[float]) -> None:
        import matplotlib

        matplotlib.use("Agg", force=True)
        self.out, self.footer, self.formats = out, footer, tuple(formats)
        self.gate_lines = tuple(gate_lines)
        (out / "figures").mkdir(parents=True, exist_ok=True)
        (out / "tables").mkdir(parents=True, exist_ok=True)
        self.figures: list[Figure] = []
        self.paths: list[Path] = []
        self.tables: list[Path] = []
        self.skipped: list[str] = []

    def figure(self, ncols: int = 1, nrows: int = 1, size: tuple[float, float] = (7.0, 4.0), **kw: Any):
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure

        fig = Figure(figsize=size, dpi=110, layout="constrained")
        FigureCanvasAgg(fig)  # text extents for the tick-label check
        axes = fig.subplots(nrows, ncols, squeeze=False, **kw)
        return fig, axes

    def save(self, fig, name: str, title: str, caption: str) -> None:
        fig.get_layout_engine().set(rect=(0, 0.035, 1, 0.965))  # room for the footer
        fig.text(0.995, 0.004, self.footer, ha="right", va="bottom", fontsize=6, color="#666666")
        left = fix_tick_labels(fig)
        buf = io.BytesIO()
        fig.savefig(buf, format="png", metadata={"Software": None})
        for fmt in self.formats:
            path = self.out / "figures" / f"{name}.{fmt}"
            if fmt == "png":
                path.write_bytes(buf.getvalue())
            else:
                fig.savefig(path, format=fmt, metadata={"Date": None, "Creator": None})
            self.paths.append(path)
        self.figures.append(Figure(name, title, caption, buf.getvalue(), left))

    def skip(self, title: str, reason: str) -> None:
        self.skipped.append(f"{title}: {reason}")

    def table(self, df: pd.DataFrame, name: str) -> None:
        path = self.out / "tables" / f"{name}.csv"
        df.to_csv(path, index=False)
        self.tables.append(path)


# --- overlapping tick labels -------------------------------------------------------------------


class Overlap(NamedTuple):
    """Two tick labels of one axis whose drawn text boxes overlap."""

    axes: str
    """Which axes: its title, or ``axes <i>`` (0-based, in the figure's order) without one."""
    axis: str
    """``x`` or ``y``."""
    first: str
    second: str


_OVERLAP_PX = 0.5
"""Two labels overlap when their text boxes intersect by more than this (display px) across every
separating direction: touching boxes and antialiasing slivers do not count."""
_WRAP_MIN = 6
"""The narrowest a wrapped tick label is made (characters), so that names stay readable."""
_ROTATIONS = (30.0, 45.0, 60.0, 90.0)
_SMALLEST_PT = 5.0


def _axes_name(ax, i: int) -> str:
    title = ax.get_title() or ax.get_title(loc="left")
    return title if title else f"axes {i}"


def _drawn_ticks(axis) -> list:
    """The ticks a draw of ``axis`` shows (those inside its view interval)."""
    update = getattr(axis, "_update_ticks", None)  # what Axis.draw itself calls (matplotlib >= 3.1)
    if update is not None:
        return list(update())
    return list(axis.get_major_ticks())


def _corners(label, renderer) -> np.ndarray:
    """The four corners (4, 2) of ``label``'s drawn text box in display px, rotation included
    (``get_window_extent`` gives the axis-aligned hull of a rotated box, which overlaps its
    neighbour's hull long before the texts touch)."""
    bb = label.get_window_extent(renderer)
    angle = float(label.get_rotation()) % 180.0
    if angle in (0.0, 90.0):
        return np.array([[bb.x0, bb.y0], [bb.x1, bb.y0], [bb.x1, bb.y1], [bb.x0, bb.y1]], float)
    label.set_rotation(0.0)
    flat = label.get_window_extent(renderer)
    label.set_rotation(angle)
    th = math.radians(angle)
    u = np.array([math.cos(th), math.sin(th)]) * flat.width / 2
    v = np.array([-math.sin(th), math.cos(th)]) * flat.height / 2
    c = np.array([(bb.x0 + bb.x1) / 2, (bb.y0 + bb.y1) / 2])  # a rotated box's hull shares its centre
    return np.array([c - u - v, c + u - v, c + u + v, c - u + v])


def _boxes_overlap(a: np.ndarray, b: np.ndarray, tol: float = _OVERLAP_PX) -> bool:
    """Whether two convex quadrilaterals (4, 2) intersect by more than ``tol`` px (separating axes)."""
    for poly in (a, b):
        for k in range(4):
            edge = poly[(k + 1) % 4] - poly[k]
            n = np.array([-edge[1], edge[0]])
            norm = float(np.hypot(*n))
            if norm == 0:
                continue
            n /= norm
            pa, pb = a @ n, b @ n
            if min(pa.max(), pb.max()) - max(pa.min(), pb.min()) <= tol:
                return False
    return True


def _axis_overlaps(axis, renderer) -> list[tuple[str, str]]:
    labels = []
    for tick in _drawn_ticks(axis):
        for lab in (tick.label1, tick.label2):
            if lab.get_visible() and lab.get_text().strip():
                labels.append(lab)
    boxes = [_corners(lab, renderer) for lab in labels]
    found = []
    for i in range(len(labels)):
        for j in range(i + 1, len(labels)):
            if _boxes_overlap(boxes[i], boxes[j]):
                found.append((labels[i].get_text(), labels[j].get_text()))
    return found


def _overlaps(fig, draw: bool) -> list[tuple[Any, str, Overlap]]:
    if draw:
        fig.draw_without_rendering()
    renderer = fig.canvas.get_renderer()
    out = []
    for i, ax in enumerate(fig.axes):
        if not ax.get_visible():
            continue
        for name, axis in (("x", ax.xaxis), ("y", ax.yaxis)):
            for a, b in _axis_overlaps(axis, renderer):
                out.append((axis, name, Overlap(_axes_name(ax, i), name, a, b)))
    return out


def tick_label_overlaps(fig, *, draw: bool = True) -> list[Overlap]:
    """Every pair of tick labels on one axis of ``fig`` whose drawn text boxes overlap (rotated
    boxes compared as drawn), after laying the figure out (``draw``). Needs a canvas with a
    renderer (Agg, as :meth:`FigureBuilder.figure` gives)."""
    return [o for _, _, o in _overlaps(fig, draw)]


def _wrap(text: str, width: int) -> str:
    return "\n".join(
        textwrap.fill(line, width, break_long_words=False, break_on_hyphens=True) if len(line) > width else line
        for line in text.split("\n")
    )


def _wrap_width(labels: list, dpi: float) -> int | None:
    """Characters per line that fit the narrowest spacing between the labels' centres (None when
    no label is longer than that, or the labels are numbers: wrapping would not help)."""
    if not any(c.isalpha() for lab in labels for c in lab.get_text()):
        return None
    xs = sorted((lab.get_window_extent().x0 + lab.get_window_extent().x1) / 2 for lab in labels)
    gaps = [b - a for a, b in zip(xs, xs[1:], strict=False) if b - a > 0]
    if not gaps:
        return None
    char_px = 0.6 * labels[0].get_fontsize() * dpi / 72
    width = max(_WRAP_MIN, int(min(gaps) / char_px))
    longest = max(len(line) for lab in labels for line in lab.get_text().split("\n"))
    return width if longest > width else None


def _wrapped(inner, width: int):
    """A tick formatter that wraps the labels of ``inner`` to ``width`` characters per line."""
    from matplotlib.ticker import Formatter

    class Wrapped(Formatter):
        def __call__(self, x, pos=None):
            return _wrap(inner(x, pos), width)

        def format_ticks(self, values):
            return [_wrap(s, width) for s in inner.format_ticks(values)]

        def set_locs(self, locs):
            inner.set_locs(locs)

    return Wrapped()


_X_STEPS: tuple[str | float, ...] = ("wrap", *_ROTATIONS, "shrink")
_Y_STEPS: tuple[str | float, ...] = ("shrink",)


def _relieve(axis, name: str, state: dict[str, Any], dpi: float) -> bool:
    """Make the labels of ``axis`` take less room with the next applicable step (``state`` holds
    where the axis is): x labels are wrapped to the space between ticks; if that is not enough,
    unwrapped and rotated 30, 45, 60, then 90 degrees; then shrunk. y labels are shrunk. False
    when nothing is left to try."""
    labels = [t.label1 for t in _drawn_ticks(axis) if t.label1.get_visible() and t.label1.get_text().strip()]
    steps = _X_STEPS if name == "x" else _Y_STEPS
    step = state.setdefault("step", 0)
    while labels and step < len(steps):
        action = steps[step]
        state["step"] = step + 1
        if action == "wrap":
            width = _wrap_width(labels, dpi)
            if width is not None:
                state["unwrapped"] = axis.get_major_formatter()
                axis.set_major_formatter(_wrapped(state["unwrapped"], width))
                return True
        elif action == "shrink":
            size = labels[0].get_fontsize()
            if size > _SMALLEST_PT:
                axis.set_tick_params(labelsize=max(_SMALLEST_PT, size * 0.85))
                state["step"] = step  # shrink again next time, down to the smallest size
                return True
        else:
            if "unwrapped" in state:  # rotated names read best on one line
                axis.set_major_formatter(state.pop("unwrapped"))
            angle = float(action)
            axis.set_tick_params(labelrotation=angle)
            for tick in axis.get_major_ticks():
                tick.label1.set_horizontalalignment("right" if angle < 90 else "center")
                tick.label1.set_rotation_mode("anchor" if angle < 90 else "default")
            return True
        step += 1
    return False


def fix_tick_labels(fig, *, rounds: int = 16) -> list[Overlap]:
    """Lay ``fig`` out and, while tick labels of an axis overlap (:func:`tick_label_overlaps`),
    make them take less room: long names wrapped to the space between ticks, else rotated
    (30-90 degrees, anchored at their tick), then smaller. Returns the overlaps that are left
    (empty when the figure reads cleanly)."""
    states: dict[int, dict[str, Any]] = {}
    for _ in range(rounds):
        found = _overlaps(fig, draw=True)
        todo = {id(axis): (axis, name) for axis, name, _ in found if not states.get(id(axis), {}).get("spent")}
        if not todo:
            return [o for _, _, o in found]
        for key, (axis, name) in todo.items():
            state = states.setdefault(key, {})
            if not _relieve(axis, name, state, fig.dpi):
                state["spent"] = True
    return tick_label_overlaps(fig)


def _color(i: int) -> str:
    return _COLORS[i % len(_COLORS)]


def _violins(ax, groups: list[tuple[str, np.ndarray]]) -> None:
    data = [(label, v[np.isfinite(v)]) for label, v in groups]
    data = [(label, v) for label, v in data if v.size]
    pos = np.arange(1, len(data) + 1)
    multi = [v if v.size > 1 else np.repeat(v, 2) for _, v in data]
    parts = ax.violinplot(multi, positions=pos, showmedians=True, widths=0.8)
    for i, body in enumerate(parts["bodies"]):
        body.set_facecolor(_color(i))
        body.set_alpha(0.4)
    rng = np.random.default_rng(0)
    for p, (_, v) in zip(pos, data, strict=True):
        ax.scatter(p + rng.uniform(-0.12, 0.12, v.size), v, s=8, color="k", alpha=0.6, zorder=3)
    ax.set_xticks(pos, [label for label, _ in data])


# --- the first screen: one figure per question ------------------------------------------------

SUMMARY_SIZE = (5.0, 3.5)
"""Inches of each first-screen figure (three side by side on the page)."""
NAME_WIDTH = 18
"""Characters per line of a platform name on the first screen's axes (longer names wrap)."""
THIN_MARGIN = 0.01
"""A gate margin thinner than this (t_inf units) is a thin decision (as in
:func:`geocon_core.report.stats.margin_summary`)."""


def platform_order(ir_table: pd.DataFrame) -> list[str]:
    """Platforms best first: by scene-balanced median IR (highest first, ties and missing values
    by name)."""
    if ir_table.empty:
        return []
    t = ir_table.assign(_m=ir_table["median"].astype(float).fillna(-np.inf))
    return [str(m) for m in t.sort_values(["_m", "model"], ascending=[False, True], kind="stable")["model"]]


def fig_summary_platforms(b: FigureBuilder, ir_table: pd.DataFrame, ir_gate: float, bootstrap: int) -> list[str]:
    """Which platform is most consistent: the scene-balanced median IR per platform with its 95%
    CI (``ir_table``: :func:`geocon_core.report.stats.scene_balanced_table` of ``ir`` by model), best at
    the top, against the report gate's IR line. Returns the platforms best first."""
    order = platform_order(ir_table)
    if not order:
        b.skip("Platform consistency", "no platform has a clip with an IR")
        return order
    t = ir_table.set_index("model").loc[order]
    fin = np.isfinite(t["median"].astype(float).to_numpy())
    if not fin.any():
        b.skip("Platform consistency", "no platform has a clip with an IR")
        return order
    fig, ax = b.figure(size=SUMMARY_SIZE)
    a = ax[0, 0]
    y = np.arange(len(order))[::-1]
    med, lo, hi = (t[c].astype(float).to_numpy() for c in ("median", "low", "high"))
    below = med < ir_gate
    for sel, col, label in ((~below, _color(0), "at or above the gate"), (below, _color(1), "below the gate")):
        sel = sel & fin
        if sel.any():
            a.errorbar(
                med[sel],
                y[sel],
                xerr=[med[sel] - lo[sel], hi[sel] - med[sel]],
                fmt="o",
                color=col,
                capsize=3,
                ms=6,
                label=label,
            )
    a.axvline(ir_gate, color="k", ls="--", lw=1)
    a.text(ir_gate, 1.0, f" gate {ir_gate:g}", transform=a.get_xaxis_transform(), fontsize=7, va="bottom")
    _name_rows(a, y, order, [f"{m:.3f}" if np.isfinite(m) else "no IR" for m in med])
    a.set(xlabel="scene-balanced median IR (95% CI)")
    a.legend(fontsize=7, loc="lower left")
    b.save(
        fig,
        "summary_platforms",
        "Which platform is most consistent?",
        f"Scene-balanced median inlier ratio per platform, best at the top, with 95% bootstrap CIs over scenes "
        f"(B = {bootstrap}); dashed: the report gate's IR.",
    )
    return order


def _name_rows(a, y, names: Sequence[str], notes: Sequence[str]) -> None:
    """Rows ``y`` of a summary chart labelled with (wrapped) ``names`` on the left and ``notes``
    beside the axes on the right."""
    for yi, note in zip(y, notes, strict=True):
        a.annotate(
            note,
            (1.0, yi),
            xycoords=("axes fraction", "data"),
            xytext=(4, 0),
            textcoords="offset points",
            va="center",
            fontsize=7,
        )
    a.set_yticks(y, [_wrap(p, NAME_WIDTH) for p in names])
    a.set_ylim(-0.7, len(names) - 0.3)


def fig_summary_margins(b: FigureBuilder, ok: pd.DataFrame, order: Sequence[str]) -> None:
    """Where the gate is thin: every clip's gate margin per platform (rows in ``order``), the thin
    band shaded and each platform's share of thin decisions beside it."""
    m_all = ok["margin"].to_numpy(float)
    if not np.isfinite(m_all).any():
        return b.skip("Gate margins (first screen)", "no clip has a pose")
    rows = [p for p in order if p in set(ok["model"])] or sorted(ok["model"].unique())
    fig, ax = b.figure(size=SUMMARY_SIZE)
    a = ax[0, 0]
    a.axvspan(-THIN_MARGIN, THIN_MARGIN, color=_color(4), alpha=0.18, lw=0, label=f"thin (|margin| < {THIN_MARGIN:g})")
    a.axvline(0, color="k", lw=1)
    rng = np.random.default_rng(0)
    y = np.arange(len(rows))[::-1]
    notes: list[str] = []
    for yi, p in zip(y, rows, strict=True):
        m = ok.loc[ok["model"] == p, "margin"].to_numpy(float)
        m = m[np.isfinite(m)]
        thin = np.abs(m) < THIN_MARGIN
        jitter = rng.uniform(-0.18, 0.18, m.size)
        a.scatter(m[~thin], yi + jitter[~thin], s=12, color="#555555", alpha=0.7, lw=0)
        a.scatter(m[thin], yi + jitter[thin], s=16, color=_color(1), alpha=0.9, lw=0)
        notes.append(f"{int(thin.sum())}/{m.size} thin" if m.size else "no pose")
    _name_rows(a, y, rows, notes)
    a.set(xlabel="gate margin (t_inf units; 0 = on a threshold)")
    a.legend(fontsize=7, loc="lower right")
    b.save(
        fig,
        "summary_margins",
        "Where is the gate thin?",
        "Each clip's distance of t_inf to the nearer gate threshold; red dots in the shaded band are thin "
        "decisions that a small pose error flips.",
    )


def fig_summary_failures(b: FigureBuilder, ok: pd.DataFrame, order: Sequence[str]) -> None:
    """Which categories fail: per platform (rows in ``order``) and category, the share of clips
    failing the report gate and the share whose translation gate contradicts the category (fail->F,
    over the clips whose category was given), each cell labelled with its count."""
    cats = sorted(ok["category"].dropna().unique())
    if not cats:
        return b.skip("Failures per category", "no scored clip has a category")
    rows = [p for p in order if p in set(ok["model"])] or sorted(ok["model"].unique())
    cover = stats.coverage_table(ok, by=("model", "category")).set_index(["model", "category"])
    rates = stats.gate_rates(ok).set_index(["model", "category"])
    panels = []
    for title, count in (
        (
            "fails the report gate",
            lambda k: (int(cover.loc[k, "inconsistent"]), int(cover.loc[k, "n_clips"])) if k in cover.index else None,
        ),
        (
            "gate anomaly (fail\u2192F)",
            lambda k: (
                (
                    int(round(float(rates.loc[k, "anomaly_rate_fail_f"]) * int(rates.loc[k, "n_expected"]))),
                    int(rates.loc[k, "n_expected"]),
                )
                if k in rates.index and int(rates.loc[k, "n_expected"])
                else None
            ),
        ),
    ):
        k = np.full((len(rows), len(cats)), np.nan)
        n = np.zeros((len(rows), len(cats)), dtype=int)
        for i, p in enumerate(rows):
            for j, c in enumerate(cats):
                got = count((p, c))
                if got is not None:
                    k[i, j], n[i, j] = got
        panels.append((title, k, n))
    fig, ax = b.figure(2, 1, SUMMARY_SIZE, sharey=True)
    for j, (title, k, n) in enumerate(panels):
        a = ax[0, j]
        share = np.where(n > 0, k / np.maximum(n, 1), np.nan)
        a.imshow(np.ma.masked_invalid(share), cmap="Reds", vmin=0, vmax=1, aspect="auto")
        a.set_facecolor("#eeeeee")
        for r in range(len(rows)):
            for c in range(len(cats)):
                text = f"{int(k[r, c])}/{n[r, c]}" if n[r, c] else "\u2013"
                dark = n[r, c] and share[r, c] > 0.6
                a.text(c, r, text, ha="center", va="center", fontsize=7, color="white" if dark else "#222222")
        a.set_xticks(np.arange(len(cats)), cats)
        a.set_yticks(np.arange(len(rows)), [_wrap(p, NAME_WIDTH) for p in rows])
        a.set_title(title, fontsize=9)
        a.tick_params(length=0)
    b.save(
        fig,
        "summary_failures",
        "Which categories fail?",
        "Per platform and category: clips failing the report gate (IR/GE), and clips whose translation gate "
        "contradicts the category (C1/C2/C4 should gate H, C3/C5/C6 F; no pose counts as F).",
    )


def fig_tinf(b: FigureBuilder, ok: pd.DataFrame) -> None:
    """The t_inf distributions per platform against the gate's hysteresis band (0.03/0.05)."""
    t = ok["t_inf"].to_numpy(float)
    fin = np.isfinite(t)
    if not fin.any():
        return b.skip("t_inf distributions", "no clip has a pose")
    expected = ok["expected_model"].to_numpy(object)  # None where no category was given
    fig, ax = b.figure(2, 1, (10, 4))
    edges = np.linspace(0, max(0.1, float(np.nanmax(t)) * 1.05), 31)
    for label, sel, col in (
        ("expected H (C1/C2/C4)", (expected == "H") & fin, _color(0)),
        ("expected F (C3/C5/C6)", (expected == "F") & fin, _color(1)),
        ("category not given", ok["expected_model"].isna().to_numpy() & fin, "#999999"),
    ):
        if sel.any():
            ax[0, 0].hist(t[sel], edges, alpha=0.55, color=col, label=f"{label}, n={int(sel.sum())}")
    for x, ls in zip(b.gate_lines, (":", "--", ":"), strict=True):
        ax[0, 0].axvline(x, color="k", ls=ls, lw=1)
    ax[0, 0].set(xlabel="t_inf", ylabel="clips", title="t_inf by expected class (gate lines 0.03 / 0.04 / 0.05)")
    ax[0, 0].legend(fontsize=7)
    cats = sorted(ok["category"].dropna().unique())
    _violins(ax[0, 1], [(c, ok.loc[ok["category"] == c, "t_inf"].to_numpy(float)) for c in cats])
    for x, ls in zip(b.gate_lines, (":", "--", ":"), strict=True):
        ax[0, 1].axhline(x, color="k", ls=ls, lw=1)
    ax[0, 1].set(ylabel="t_inf", title="t_inf per family")
    b.save(
        fig,
        "tinf",
        "Translation statistic",
        "Where clips fall against the gate: expected-H clips should sit left of 0.03, expected-F clips right of "
        "0.05; the gray zone between fits both models.",
    )


def fig_margins(b: FigureBuilder, ok: pd.DataFrame) -> None:
    """The gate margins per platform: how far each clip's t_inf lies from the band."""
    models = sorted(ok["model"].unique())
    groups = [(m, ok.loc[ok["model"] == m, "margin"].to_numpy(float)) for m in models]
    if not any(np.isfinite(v).any() for _, v in groups):
        return b.skip("Gate margins", "no clip has a pose")
    fig, ax = b.figure(size=(7, 3.6))
    _violins(ax[0, 0], groups)
    ax[0, 0].axhline(0, color="k", lw=1)
    ax[0, 0].set(ylabel="gate margin (t_inf units)", title="Gate margins per platform")
    b.save(
        fig,
        "margins",
        "Gate margins",
        "Distance of t_inf to the nearer gate threshold; values near 0 are thin decisions that flip with small pose "
        "errors.",
    )


def fig_calibration(b: FigureBuilder, ok: pd.DataFrame, seed: int) -> dict[str, Any] | None:
    """The gate's calibration on clips with a given category: t_inf against the expected model
    (H or F), with the rate of each decision; returns the calibration numbers, or None when skipped."""
    ok = ok[ok["expected_model"].notna()]  # the clips whose category was given
    t = ok["t_inf"].to_numpy(float)
    is_f = (ok["expected_model"] == "F").to_numpy()
    fin = np.isfinite(t)
    if not (is_f[fin].any() and (~is_f[fin]).any()):
        b.skip("Gate calibration", "needs clips of both expected classes with a pose")
        return None
    bins = stats.calibration_bins(t, is_f, K=12)
    b.table(bins, "calibration_bins")
    fig, ax = b.figure(size=(6, 4))
    a = ax[0, 0]
    a.fill_between(bins["t_mid"], bins["low"], bins["high"], color=_color(0), alpha=0.25, label="Wilson 95%")
    a.plot(bins["t_mid"], bins["p"], "o-", color=_color(0), label="P(F | t_inf), 12 equal-count bins")
    for x, ls in zip(b.gate_lines, (":", "--", ":"), strict=True):
        a.axvline(x, color="k", ls=ls, lw=1)
    a.set(xlabel="t_inf (bin median)", ylabel="share expected F", ylim=(-0.02, 1.02), title="Gate calibration")
    a.legend(fontsize=7)
    b.save(
        fig,
        "calibration",
        "Gate calibration",
        "Share of expected-F clips per t_inf bin; a well-placed gate has the curve rise across the gray zone.",
    )
    taus = np.linspace(0.0, max(0.1, float(np.nanmax(t))), 101)
    nb = stats.net_benefit(t, is_f, taus)
    boot = stats.bootstrap_tau(t, is_f, B=400, seed=seed)
    fig, ax = b.figure(3, 1, (12, 3.8))
    for i, c in enumerate((0.5, 1.0, 2.0)):
        sel = nb[nb["c"] == c]
        ax[0, 0].plot(sel["tau"], sel["net_benefit"], color=_color(i), label=f"c = {c:g}")
    for g in stats.TAU_GRID:
        ax[0, 0].axvline(g, color="#999999", lw=0.6)
    ax[0, 0].set(xlabel="tau_t", ylabel="net benefit", title="Net benefit (TP - c FP) / N")
    ax[0, 0].legend(fontsize=7)
    pos = np.arange(len(boot.grid))
    ax[0, 1].errorbar(pos, boot.mean, yerr=[boot.mean - boot.low, boot.high - boot.mean], fmt="o", capsize=3)
    ax[0, 1].set_xticks(pos, [f"{g:g}" for g in boot.grid])
    ax[0, 1].set(xlabel="tau_t", ylabel="balanced accuracy", title=f"Bootstrap (B = {boot.B}) mean and 95% CI")
    ax[0, 2].bar(pos, boot.argmax_counts, color=_color(2))
    ax[0, 2].set_xticks(pos, [f"{g:g}" for g in boot.grid])
    ax[0, 2].set(xlabel="tau_t", ylabel="replicates", title=f"argmax histogram (best {boot.best_tau:g})")
    b.save(
        fig,
        "net_benefit_bootstrap",
        "Threshold choice",
        "Net benefit of calling F above tau_t for three false-positive costs, and which tau_t of the grid maximises "
        "balanced accuracy across bootstrap replicates.",
    )
    return {"best_tau": boot.best_tau, "grid": list(boot.grid), "argmax_counts": boot.argmax_counts.tolist()}


def fig_ridgelines(b: FigureBuilder, ok: pd.DataFrame) -> None:
    """The IR and GE distributions per category and platform (ridgelines)."""
    cats = sorted(ok["category"].dropna().unique())
    if not cats:
        return b.skip("IR/GE ridgelines", "no scored clips")
    fig, ax = b.figure(2, 1, (10, 1.0 + 0.9 * len(cats)))
    for j, (metric, lo_hi) in enumerate((("ir", (0.0, 1.0)), ("ge", None))):
        vals = ok[[f"{metric}_h", f"{metric}_f"]].to_numpy(float)
        top = lo_hi or (0.0, max(1e-3, float(np.nanpercentile(vals, 98)) if np.isfinite(vals).any() else 1.0))
        edges = np.linspace(*top, 41)
        for i, c in enumerate(cats):
            g = ok[ok["category"] == c]
            for fam, col in (("h", _color(0)), ("f", _color(1))):
                v = g[f"{metric}_{fam}"].to_numpy(float)
                v = v[np.isfinite(v)]
                if not v.size:
                    continue
                h, _ = np.histogram(np.clip(v, *top), edges)
                h = 0.8 * h / max(1, h.max())
                ax[0, j].fill_between(
                    edges[:-1],
                    i,
                    i + h,
                    step="post",
                    alpha=0.5,
                    color=col,
                    label=f"{fam.upper()} fit" if i == 0 else None,
                )
        ax[0, j].set_yticks(np.arange(len(cats)) + 0.3, cats)
        ax[0, j].set(xlabel="IR" if metric == "ir" else "GE (px)", title=f"{metric.upper()} per family, H vs F fit")
        ax[0, j].legend(fontsize=7)
    b.save(
        fig,
        "ridgelines",
        "IR/GE ridgelines",
        "Distribution of each family's clip IR and GE under the homography and the fundamental-matrix fit; "
        "translation families should separate H from F.",
    )


def fig_effects(b: FigureBuilder, ok: pd.DataFrame, boot: int, seed: int) -> pd.DataFrame | None:
    """The effect sizes between platforms (bootstrap CIs); returns their table, or None when skipped."""
    models = sorted(ok["model"].unique())
    if len(models) < 2:
        b.skip("Effect sizes", "needs at least two platforms")
        return None
    rows = []
    for metric in ("ir", "ge"):
        for m in models:
            a, o = ok[ok["model"] == m], ok[ok["model"] != m]
            ci = stats.median_difference_ci(a[metric], a["scene_id"], o[metric], o["scene_id"], B=boot, seed=seed)
            rows.append({"metric": metric, "model": m, "difference": ci.estimate, "low": ci.low, "high": ci.high})
    df = pd.DataFrame(rows)
    b.table(df, "effect_sizes")
    fig, ax = b.figure(2, 1, (9, 0.8 + 0.5 * len(models)))
    for j, metric in enumerate(("ir", "ge")):
        d = df[df["metric"] == metric]
        y = np.arange(len(d))
        ax[0, j].errorbar(
            d["difference"], y, xerr=[d["difference"] - d["low"], d["high"] - d["difference"]], fmt="o", capsize=3
        )
        ax[0, j].axvline(0, color="k", lw=1)
        ax[0, j].set_yticks(y, d["model"])
        ax[0, j].set(xlabel=f"median {metric.upper()} difference vs. the other platforms", title=metric.upper())
    b.save(
        fig,
        "effect_sizes",
        "Effect sizes",
        "Scene-balanced median difference of each platform against the pooled others, with 95% bootstrap CIs "
        "(resampling scenes); an interval clear of 0 is a real gap.",
    )
    return df


def fig_dynamic(b: FigureBuilder, objects: pd.DataFrame, frames: pd.DataFrame) -> list[dict[str, Any]]:
    """Dynamic coherence: the AdaP90 distributions of moving objects per platform and category;
    returns the rows of the figure's table."""
    obj = objects[np.isfinite(objects["adap90"].astype(float))]
    if obj.empty:
        b.skip("Dynamic coherence (AdaP90)", "no moving objects were scored")
        return []
    summ = stats.adap90_summary(obj)
    b.table(summ, "adap90_summary")
    models = sorted(obj["model"].unique())
    cats = sorted(obj["category"].unique())
    fig, ax = b.figure(3, 1, (13, 4))
    rng = np.random.default_rng(0)
    ticks, labels = [], []
    for i, (m, c) in enumerate((m, c) for m in models for c in cats):
        v = obj[(obj["model"] == m) & (obj["category"] == c)]["adap90"].to_numpy(float)
        if not v.size:
            continue
        ax[0, 0].scatter(i + rng.uniform(-0.2, 0.2, v.size), v, s=10, color=_color(models.index(m)), alpha=0.7)
        p80 = float(np.percentile(v, 80))
        ax[0, 0].hlines([p80], i - 0.3, i + 0.3, colors="k", linestyles="--", lw=1)
        ax[0, 0].hlines([np.median(v)], i - 0.15, i + 0.15, colors="k", lw=2)
        ticks.append(i)
        labels.append(f"{m}\n{c}")
    ax[0, 0].set_xticks(ticks, labels, fontsize=7)
    ax[0, 0].set_yscale("symlog", linthresh=1.0)
    ax[0, 0].set(ylabel="AdaP90 (px²)", title="AdaP90 per object (dashed: P80, bar: median)")
    for k, m in enumerate(models):
        v = np.sort(obj[obj["model"] == m]["adap90"].to_numpy(float))
        ax[0, 1].step(v, np.arange(1, v.size + 1) / v.size, where="post", color=_color(k), label=m)
    ax[0, 1].set_xscale("symlog", linthresh=1.0)
    ax[0, 1].set(xlabel="AdaP90 (px²)", ylabel="ECDF", title="ECDF per platform")
    ax[0, 1].legend(fontsize=7)
    x = np.arange(len(summ))
    ax[0, 2].bar(x, summ["rate_above_p80"], color=[_color(models.index(m)) for m in summ["model"]])
    ax[0, 2].set_xticks(x, [f"{m}\n{c}" for m, c in zip(summ["model"], summ["category"], strict=True)], fontsize=7)
    ax[0, 2].set(ylabel="share above P80", title="Share above P80 (~20% by construction)")
    b.save(
        fig,
        "adap90",
        "Dynamic coherence",
        "Per-object AdaP90 (90th percentile of the per-frame AdaDFRC): severity and tail shape matter, not the rate "
        "above P80, which is near 20% by construction.",
    )
    top = stats.top_hardest(obj, frames, n=8)
    if top:
        fig, ax = b.figure(1, len(top), (7, 0.75 * len(top) + 0.6))
        for i, t in enumerate(top):
            a = ax[i, 0]
            if t["trace"]:
                xs, ys = zip(*t["trace"], strict=True)
                a.plot(xs, ys, color=_color(models.index(t["model"])), lw=1)
            a.set_yticks([])
            a.text(
                1.01,
                0.5,
                f"{t['clip_id']} #{t['object_id']}  P50 {t['p50']:.2f}  P90 {t['p90']:.2f}  n={t['frames']}",
                transform=a.transAxes,
                fontsize=7,
                va="center",
            )
            if i < len(top) - 1:
                a.set_xticks([])
        ax[-1, 0].set_xlabel("frame")
        b.save(
            fig,
            "top_objects",
            "Hardest objects",
            "Per-frame AdaDFRC (D_t, px²) of the objects with the highest AdaP90: a sustained plateau is a deforming "
            "object, a lone spike a segmentation glitch.",
        )
    return top


def fig_sensitivity(b: FigureBuilder, sens: pd.DataFrame, config: dict[str, Any]) -> None:
    """The sensitivity curves: how flag rates move when the thresholds move (the scan in the results)."""
    if sens.empty or not sens["chosen"].any():
        return b.skip("Sensitivity curves", "no sensitivity scan in the results")
    tab = stats.sensitivity_table(sens)
    b.table(tab, "sensitivity")
    fig, ax = b.figure(2, 2, (10, 6))
    models = sorted(tab["model"].unique())
    for j, (fam, recorded) in enumerate((("H", config.get("tau_h", 2.0)), ("F", config.get("tau_f", 0.1)))):
        for r, metric in enumerate(("ir", "ge")):
            a = ax[r, j]
            for k, m in enumerate(models):
                d = tab[(tab["model"] == m) & (tab["family"] == fam)]
                a.plot(d["tau"], d[metric], "o-", color=_color(k), label=m, ms=3)
            a.axvline(recorded, color="k", ls="--", lw=1)
            a.set(
                xlabel=f"tau_{fam} ({'px' if fam == 'H' else 'normalised Sampson'})",
                ylabel=metric.upper(),
                title=f"{metric.upper()} vs tau_{fam} (clips gated {fam})",
            )
            a.legend(fontsize=7)
    b.save(
        fig,
        "sensitivity",
        "Threshold-score sensitivity",
        "Scene-balanced median IR and GE re-gated from stored residuals at other thresholds (dashed: the recorded "
        "one); rankings that survive the sweep are robust.",
    )
