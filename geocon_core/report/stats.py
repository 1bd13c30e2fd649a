"""Benchmark statistics (SPEC section 6): pure, seeded functions over the result tables.

Definitions (what the report prints):

- **Scene-balanced median**: each scene (``scene_id``: one seed/prompt rendered by every platform)
  contributes the median of its clips' values, then the median over scenes; scenes with many
  regenerations do not dominate.
- **Bootstrap CI**: percentile interval of the scene-balanced median over ``B`` resamples of the
  scenes with replacement (B = 10,000 by default), seeded.
- **F-rate / anomaly rate** per (platform, category): the share of clips whose gate chose F, and
  the share whose gate disagrees with the expected rule (C1/C2/C4 -> H, C3/C5/C6 -> F).
  *Present-only* counts clips with a pose and a decided (non-U) gate label; *fail->F* counts every
  scored clip, a clip without a pose as F (the paper's default protocol) and a gray-zone (U)
  clip by the family it kept. Anomaly rates count only clips whose category was given (a
  non-null ``expected_model``; where none was given, the table's category is the scorer's own,
  which follows the gate); ``n_expected`` says how many. Wilson 95% intervals.
- **Consensus** per (scene, category): whether every platform with a decided gate (pose present,
  not U) agrees; the rate is over tuples where at least two platforms decided. Clips without a
  given category count per scene alone.
- **Calibration**: P(F | t_inf) in K equal-count bins with Wilson intervals; net benefit
  ``(TP - c * FP) / N`` of "predict F iff t_inf >= tau"; bootstrap balanced accuracy over a tau grid.
- **Percentile alignment**: per platform, the y value (GE) of the clips at matched percentiles of
  x (IR): at percentile p, the median y over the clips whose x lies between percentiles p - w and
  p + w (w = 10 points).
- **Dynamic coherence**: AdaP90 per object; per (platform, category) its P80 threshold (linear
  interpolation), the share of objects strictly above it, and the top-N objects by AdaP90 with
  their per-frame ``D_t`` traces.
"""

from __future__ import annotations

from typing import Any, Hashable, Sequence

import numpy as np
import pandas as pd

from ..bench import EXPECTED_MODEL
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

__all__ = [
    "EXPECTED_MODEL",
    "Interval",
    "TAU_GRID",
    "TauBootstrap",
    "wilson_interval",
    "scene_balanced_median",
    "bootstrap_median_ci",
    "median_difference_ci",
    "scene_balanced_table",
    "gate_rates",
    "coverage_table",
    "consensus",
    "margin_summary",
    "calibration_bins",
    "net_benefit",
    "balanced_accuracy",
    "bootstrap_tau",
    "percentile_aligned",
    "adap90_summary",
    "top_hardest",
    "sensitivity_table",
]

_NAN = float("nan")


def _scene_medians(values: Sequence[float], scenes: Sequence[Hashable]) -> np.ndarray:
    v = np.asarray(values, dtype=float)
    s = np.asarray(scenes, dtype=object)
    if v.shape != s.shape:
        raise ValueError(f"values and scenes must have the same length, got {v.shape} and {s.shape}")
    keep = np.isfinite(v)
    df = pd.DataFrame({"v": v[keep], "s": s[keep]})
    return df.groupby("s", sort=True)["v"].median().to_numpy()


def scene_balanced_median(values: Sequence[float], scenes: Sequence[Hashable]) -> float:
    """Median over scenes of each scene's median (NaN values dropped; NaN if nothing is left)."""
    m = _scene_medians(values, scenes)
    return float(np.median(m)) if m.size else _NAN


def _boot_medians(per_scene: np.ndarray, B: int, rng: np.random.Generator) -> np.ndarray:
    idx = rng.integers(0, per_scene.size, size=(B, per_scene.size))
    return np.median(per_scene[idx], axis=1)


def bootstrap_median_ci(
    values: Sequence[float], scenes: Sequence[Hashable], *, B: int = 10_000, confidence: float = 0.95, seed: int = 0
) -> Interval:
    """Scene-balanced median with a percentile bootstrap interval resampling scenes."""
    m = _scene_medians(values, scenes)
    if m.size == 0:
        return Interval(_NAN, _NAN, _NAN, 0)
    boot = _boot_medians(m, B, np.random.default_rng(seed))
    a = (1 - confidence) / 2
    return Interval(float(np.median(m)), float(np.quantile(boot, a)), float(np.quantile(boot, 1 - a)), int(m.size))


def median_difference_ci(
    values_a, scenes_a, values_b, scenes_b, *, B: int = 10_000, confidence: float = 0.95, seed: int = 0
) -> Interval:
    """Effect size: scene-balanced median(a) - median(b), each side's scenes resampled
    independently; ``n`` is the smaller number of scenes."""
    ma, mb = _scene_medians(values_a, scenes_a), _scene_medians(values_b, scenes_b)
    if ma.size == 0 or mb.size == 0:
        return Interval(_NAN, _NAN, _NAN, 0)
    rng = np.random.default_rng(seed)
    diff = _boot_medians(ma, B, rng) - _boot_medians(mb, B, rng)
    a = (1 - confidence) / 2
    return Interval(
        float(np.median(ma) - np.median(mb)),
        float(np.quantile(diff, a)),
        float(np.quantile(diff, 1 - a)),
        int(min(ma.size, mb.size)),
    )


def _ok(df: pd.DataFrame) -> pd.DataFrame:
    return df[df["status"] == "ok"] if "status" in df else df


def scene_balanced_table(
    df: pd.DataFrame,
    value: str,
    *,
    by: Sequence[str] = ("model", "category"),
    scene: str = "scene_id",
    B: int = 10_000,
    seed: int = 0,
) -> pd.DataFrame:
    """Per group: the scene-balanced median of ``value`` with its bootstrap CI (columns
    ``by..., median, low, high, n_scenes, n_clips``), over scored rows with a finite value."""
    rows = []
    data = _ok(df)
    data = data[np.isfinite(data[value].astype(float))]
    for key, g in data.groupby(list(by), sort=True):
        ci = bootstrap_median_ci(g[value].to_numpy(float), g[scene].to_numpy(), B=B, seed=seed)
        key = key if isinstance(key, tuple) else (key,)
        rows.append(
            {
                **dict(zip(by, key, strict=True)),
                "median": ci.estimate,
                "low": ci.low,
                "high": ci.high,
                "n_scenes": ci.n,
                "n_clips": len(g),
            }
        )
    return pd.DataFrame(rows, columns=[*by, "median", "low", "high", "n_scenes", "n_clips"])


def _rate_cols(prefix: str, k: int, n: int) -> dict[str, float]:
    w = wilson_interval(k, n)
    return {prefix: w.estimate, f"{prefix}_low": w.low, f"{prefix}_high": w.high}


def gate_rates(clips: pd.DataFrame, *, by: Sequence[str] = ("model", "category")) -> pd.DataFrame:
    """F-rates and anomaly rates per group, present-only and fail->F (see the module doc)."""
    rows = []
    for key, g in _ok(clips).groupby(list(by), sort=True):
        key = key if isinstance(key, tuple) else (key,)
        pose = g["pose_present"].fillna(False).astype(bool)
        present = g[pose & (g["gate_label"] != "U")]
        fam_fail_f = np.where(pose, g["gate_model"], "F")
        expected = g["expected_model"].to_numpy()
        known = g["expected_model"].notna().to_numpy()
        judged = present[present["expected_model"].notna()]
        rows.append(
            {
                **dict(zip(by, key, strict=True)),
                "n_clips": len(g),
                "n_present": len(present),
                "n_expected": int(known.sum()),
                **_rate_cols("f_rate_present", int((present["gate_label"] == "F").sum()), len(present)),
                **_rate_cols(
                    "anomaly_rate_present",
                    int((judged["gate_label"] != judged["expected_model"]).sum()),
                    len(judged),
                ),
                **_rate_cols("f_rate_fail_f", int((fam_fail_f == "F").sum()), len(g)),
                **_rate_cols("anomaly_rate_fail_f", int(((fam_fail_f != expected) & known).sum()), int(known.sum())),
            }
        )
    return pd.DataFrame(rows)


def coverage_table(clips: pd.DataFrame, *, by: Sequence[str] = ("model",)) -> pd.DataFrame:
    """Per group: scored clips, how many the report gate calls consistent, inconsistent or could
    not judge (the coverage rule), and where the gate's pose came from (first-last pair, a chain
    of short hops, a pose log, none: fail->F), with the share that has a pose."""
    rows = []
    for key, g in _ok(clips).groupby(list(by), sort=True):
        key = key if isinstance(key, tuple) else (key,)
        verdict = g["consistent"]
        method = g["pose_method"].fillna("none") if "pose_method" in g else pd.Series("none", index=g.index)
        pose = g["pose_present"].fillna(False).astype(bool)
        rows.append(
            {
                **dict(zip(by, key, strict=True)),
                "n_clips": len(g),
                "consistent": int((verdict == True).sum()),  # noqa: E712  (NA-aware)
                "inconsistent": int((verdict == False).sum()),  # noqa: E712
                "not_judged": int(verdict.isna().sum()),
                "pose_first_last": int((pose & method.isin(["essential", "rotation"])).sum()),
                "pose_chain": int((method == "chain").sum()),
                "pose_log": int((method == "log").sum()),
                "no_pose": int((~pose).sum()),
                **_rate_cols("pose_coverage", int(pose.sum()), len(g)),
            }
        )
    return pd.DataFrame(rows)


def consensus(clips: pd.DataFrame) -> pd.DataFrame:
    """Per (scene, category): platforms, decided platforms (pose present, not U), and whether
    the decided ones are unanimous (NA with fewer than two). ``attrs`` hold the overall
    ``consensus_rate`` (unanimous / tuples with at least two decided), ``n_tuples`` and
    ``n_unanimous``. A clip whose category was not given (no ``expected_model``) is grouped by its
    scene alone (category None): the scorer's category follows the gate, and grouping by it would
    split a scene wherever its platforms disagree."""
    rows = []
    data = _ok(clips)
    given = data["category"].where(data["expected_model"].notna(), "") if "expected_model" in data else data["category"]
    for (scene, cat), g in data.assign(category=given).groupby(["scene_id", "category"], sort=True):
        decided = g[g["pose_present"].fillna(False).astype(bool) & g["gate_label"].isin(["H", "F"])]
        labels = set(decided["gate_label"])
        rows.append(
            {
                "scene_id": scene,
                "category": cat or None,
                "platforms": int(g["model"].nunique()),
                "n_decided": len(decided),
                "labels": ",".join(sorted(labels)),
                "unanimous": (len(labels) == 1) if len(decided) >= 2 else pd.NA,
            }
        )
    out = pd.DataFrame(rows, columns=["scene_id", "category", "platforms", "n_decided", "labels", "unanimous"])
    judged = out[out["n_decided"] >= 2]
    n_un = int((judged["unanimous"] == True).sum())  # noqa: E712  (NA-aware)
    out.attrs.update(
        consensus_rate=(n_un / len(judged)) if len(judged) else _NAN, n_tuples=len(judged), n_unanimous=n_un
    )
    return out


def margin_summary(clips: pd.DataFrame, *, by: Sequence[str] = ("model",)) -> pd.DataFrame:
    """Gate margins per group: count, P10, median, P90 and the share of thin margins (< 0.01)."""
    rows = []
    data = _ok(clips)
    data = data[np.isfinite(data["margin"].astype(float))]
    for key, g in data.groupby(list(by), sort=True):
        key = key if isinstance(key, tuple) else (key,)
        m = g["margin"].to_numpy(float)
        rows.append(
            {
                **dict(zip(by, key, strict=True)),
                "n": m.size,
                "p10": float(np.percentile(m, 10)),
                "median": float(np.median(m)),
                "p90": float(np.percentile(m, 90)),
                "thin_share": float(np.mean(np.abs(m) < 0.01)),
            }
        )
    return pd.DataFrame(rows)


def percentile_aligned(
    clips: pd.DataFrame,
    *,
    x: str = "ir",
    y: str = "ge",
    percentiles: Sequence[float] = (10, 25, 50, 75, 90),
    by: Sequence[str] = ("model",),
    band: float = 10.0,
) -> pd.DataFrame:
    """Per group and percentile p: ``x_p`` (percentile p of x) and ``y_at`` (the median y over the
    clips whose x lies between percentiles p - band and p + band of x; NaN when no clip does, as
    between two far-apart values of a small group)."""
    rows = []
    data = _ok(clips)
    data = data[np.isfinite(data[x].astype(float)) & np.isfinite(data[y].astype(float))]
    for key, g in data.groupby(list(by), sort=True):
        key = key if isinstance(key, tuple) else (key,)
        xv, yv = g[x].to_numpy(float), g[y].to_numpy(float)
        for p in percentiles:
            lo, hi = np.percentile(xv, max(0.0, p - band)), np.percentile(xv, min(100.0, p + band))
            sel = (xv >= lo) & (xv <= hi)
            rows.append(
                {
                    **dict(zip(by, key, strict=True)),
                    "percentile": float(p),
                    f"{x}_p": float(np.percentile(xv, p)),
                    f"{y}_at": float(np.median(yv[sel])) if sel.any() else float("nan"),
                    "n": int(sel.sum()),
                }
            )
    return pd.DataFrame(rows)


def adap90_summary(objects: pd.DataFrame, *, by: Sequence[str] = ("model", "category")) -> pd.DataFrame:
    """Per group: objects, median (p50) and P80 of AdaP90, the share strictly above P80, max."""
    rows = []
    data = objects[np.isfinite(objects["adap90"].astype(float))]
    for key, g in data.groupby(list(by), sort=True):
        key = key if isinstance(key, tuple) else (key,)
        v = g["adap90"].to_numpy(float)
        p80 = float(np.percentile(v, 80))
        rows.append(
            {
                **dict(zip(by, key, strict=True)),
                "n_objects": v.size,
                "p50": float(np.median(v)),
                "p80": p80,
                "rate_above_p80": float(np.mean(v > p80)),
                "max": float(v.max()),
            }
        )
    return pd.DataFrame(rows, columns=[*by, "n_objects", "p50", "p80", "rate_above_p80", "max"])


def top_hardest(
    objects: pd.DataFrame, object_frames: pd.DataFrame, *, n: int = 10, by: Sequence[str] = ("model",)
) -> list[dict[str, Any]]:
    """Per group, the ``n`` objects with the highest AdaP90 with their per-frame ``D_t`` trace
    (valid frames, in order), P50/P90 of the trace and its length."""
    out = []
    data = objects[np.isfinite(objects["adap90"].astype(float))]
    for key, g in data.groupby(list(by), sort=True):
        key = key if isinstance(key, tuple) else (key,)
        for row in (
            g.sort_values(["adap90", "clip_id", "object_id"], ascending=[False, True, True]).head(n).itertuples()
        ):
            fr = object_frames[
                (object_frames["clip_id"] == row.clip_id)
                & (object_frames["object_id"] == row.object_id)
                & object_frames["valid"]
            ]
            fr = fr.sort_values("t0")
            d = fr["d_t"].to_numpy(float)
            out.append(
                {
                    **dict(zip(by, key, strict=True)),
                    "clip_id": row.clip_id,
                    "object_id": int(row.object_id),
                    "category": row.category,
                    "adap90": float(row.adap90),
                    "trace": list(zip(fr["t0"].astype(int).tolist(), d.tolist(), strict=True)),
                    "p50": float(np.median(d)) if d.size else _NAN,
                    "p90": float(np.percentile(d, 90)) if d.size else _NAN,
                    "frames": int(d.size),
                }
            )
    return out


def sensitivity_table(sensitivity: pd.DataFrame, *, by: Sequence[str] = ("model",)) -> pd.DataFrame:
    """Per group, family and tau: scene-balanced median IR and GE over the clips whose gate chose
    that family."""
    rows = []
    data = sensitivity[sensitivity["chosen"]]
    for key, g in data.groupby([*by, "family", "tau"], sort=True):
        rows.append(
            {
                **dict(zip([*by, "family", "tau"], key, strict=True)),
                "ir": scene_balanced_median(g["ir"], g["scene_id"]),
                "ge": scene_balanced_median(g["ge"], g["scene_id"]),
                "n_clips": len(g),
            }
        )
    return pd.DataFrame(rows, columns=[*by, "family", "tau", "ir", "ge", "n_clips"])
