"""The figures of ``geocon report`` (see :mod:`geocon_core.report`): each a function of the
benchmark tables that draws into a :class:`FigureBuilder`, or records why the data cannot support
it."""

from __future__ import annotations

import io
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import pandas as pd

from . import stats

__all__ = [
    "Figure",
    "FigureBuilder",
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
    """One rendered figure of the report page."""

    name: str
    title: str
    caption: str
    png: bytes


class FigureBuilder:
    """Collects the report's figures (PNG/SVG files plus the PNG bytes for the page) and tables;
    ``gate_lines`` are the t_inf values drawn as vertical lines on the gate figures."""

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

    def figure(self, ncols: int = 1, nrows: int = 1, size: tuple[float, float] = (7.0, 4.0)):
        from matplotlib.figure import Figure

        fig = Figure(figsize=size, dpi=110, layout="constrained")
        axes = fig.subplots(nrows, ncols, squeeze=False)
        return fig, axes

    def save(self, fig, name: str, title: str, caption: str) -> None:
        fig.get_layout_engine().set(rect=(0, 0.035, 1, 0.965))  # room for the footer
        fig.text(0.995, 0.004, self.footer, ha="right", va="bottom", fontsize=6, color="#666666")
        for fmt in self.formats:
            path = self.out / "figures" / f"{name}.{fmt}"
            meta = {"Software": None} if fmt == "png" else {"Date": None, "Creator": None}
            fig.savefig(path, format=fmt, metadata=meta)
            self.paths.append(path)
        buf = io.BytesIO()
        fig.savefig(buf, format="png", metadata={"Software": None})
        self.figures.append(Figure(name, title, caption, buf.getvalue()))

    def skip(self, title: str, reason: str) -> None:
        self.skipped.append(f"{title}: {reason}")

    def table(self, df: pd.DataFrame, name: str) -> None:
        path = self.out / "tables" / f"{name}.csv"
        df.to_csv(path, index=False)
        self.tables.append(path)


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


def fig_tinf(b: FigureBuilder, ok: pd.DataFrame) -> None:
    t = ok["t_inf"].to_numpy(float)
    fin = np.isfinite(t)
    if not fin.any():
        return b.skip("t_inf distributions", "no clip has a pose")
    is_f = (ok["expected_model"] == "F").to_numpy()
    fig, ax = b.figure(2, 1, (10, 4))
    edges = np.linspace(0, max(0.1, float(np.nanmax(t)) * 1.05), 31)
    for label, sel, col in (
        ("expected H (C1/C2/C4)", ~is_f & fin, _color(0)),
        ("expected F (C3/C5/C6)", is_f & fin, _color(1)),
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
