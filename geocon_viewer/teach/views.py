"""What ``geocon teach`` shows for one update, drawn from its record: the numbers with their
scales (:func:`numbers_html`), the background matches of a pair (:func:`pair_matches`), and one
sentence on what changed and why (:func:`explain`). Functions of the records; nothing here
computes a score: labels, verdicts and inlier sets are the core's."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import Sequence

import cv2
import numpy as np

from geocon_core.record import ClipRecord, FamilySummary
from geocon_core.scoring import Thresholds, pair_inliers

from ..audit import INLIER, OUTLIER
from ..shared import fmt, object_color
from .scene import SLIDERS, TeachClip, TeachParams

__all__ = [
    "TeachUpdate",
    "explain",
    "numbers_html",
    "pair_matches",
    "draw_matches",
    "worst_pair",
    "tinted",
    "model_name",
    "family",
]

_BY_NAME = {s.name: s for s in SLIDERS}


@dataclass(frozen=True, eq=False)
class TeachUpdate:
    """One finished update: the parameters, the clip and its record (None when scoring failed,
    with ``error``), the sentence shown, and its timings in seconds: ``latency_s`` from the
    change that asked for it to its numbers on the page, of which ``render_s`` rendering and
    ``score_s`` scoring."""

    index: int
    params: TeachParams
    record: ClipRecord | None
    clip: TeachClip | None
    explanation: str = ""
    latency_s: float = 0.0
    render_s: float = 0.0
    score_s: float = 0.0
    error: str | None = None
    frames: dict[int, np.ndarray] = field(default_factory=dict)
    """Display-size frames of the working canvas, object masks tinted, by frame index."""
    display_scale: float = 1.0
    """Display px per working px."""

    @property
    def gate_label(self) -> str | None:
        """The gate's label (H / U / F) in the record."""
        return None if self.record is None else self.record.gate.label

    @property
    def t_inf(self) -> float | None:
        return None if self.record is None else self.record.gate.t_inf

    @property
    def ir(self) -> float | None:
        """The clip's IR under the model in use."""
        return None if self.record is None else self.record.background.ir

    @property
    def ge(self) -> float | None:
        return None if self.record is None else self.record.background.ge

    @property
    def strict_ir(self) -> float | None:
        """The clip's IR under one homography (family H), whatever model the gate chose: the
        strictest reading of the background (a fundamental matrix only asks each point to stay on
        its epipolar line, so it absorbs much of a warp)."""
        fam = family(self.record, "H")
        return None if fam is None else fam.ir

    def adadfrc(self, object_id: int | None = None) -> float | None:
        """AdaDFRC (px²) of ``object_id`` (default: the object the elasticity slider deforms)."""
        if self.record is None:
            return None
        oid = object_id if object_id is not None else (self.clip.deforming_id if self.clip else 1)
        return next((o.adadfrc for o in self.record.objects if o.object_id == oid), None)


def family(rec: ClipRecord | None, name: str) -> FamilySummary | None:
    """The record's summary of family ``name`` (H or F), chosen or not."""
    if rec is None:
        return None
    bg = rec.background
    return bg.chosen if bg.chosen.family == name else bg.other


def model_name(model: str) -> str:
    return "homography" if model == "H" else "fundamental matrix"


# --- the sentence ----------------------------------------------------------------------------------


def _changed(before: TeachParams, after: TeachParams) -> list[str]:
    return [f.name for f in fields(TeachParams) if getattr(before, f.name) != getattr(after, f.name)]


def _control(name: str, p: TeachParams) -> str:
    if name in _BY_NAME:
        s = _BY_NAME[name]
        v = getattr(p, name)
        return f"{s.label} {v:.3f}" if name == "translation" else f"{s.label} {v:g}{s.unit}"
    return {
        "size": f"size {p.size}",
        "codec": f"codec {p.codec}",
        "masks": "motion-segmentation masks" if p.masks == "motion" else "rendered masks",
        "num_frames": f"{p.num_frames} frames",
        "seed": f"seed {p.seed}",
    }[name]


def _gate_clause(rec: ClipRecord, old_label: str | None, cause: str) -> str:
    """Why the gate reads what it reads (``old_label``: the previous label when it changed)."""
    g, th = rec.gate, Thresholds.of(rec.config)
    flip = "" if old_label is None else f" (gate {old_label} → {g.label})"
    if not g.pose_present or g.t_inf is None:
        return f"the pose could not be recovered ({g.pose.reason}), so the gate falls back to F{flip}"
    t = g.t_inf
    warp = {"breathing_px": "the warp", "slide_px": "the sliding panel"}.get(cause)
    if g.label == "H":
        why = "the camera barely translates" if warp is None else "the pose backend sees no parallax"
        return f"t_inf {t:.3f} ≤ {th.tau_t_low:g} ({why}), so the gate asks for one homography{flip}"
    h = family(rec, "H")
    strict = fmt(None if h is None else h.ir)
    if g.label == "F":
        if warp is None:
            return f"t_inf {t:.3f} ≥ {th.tau_t_high:g}, so the background now needs a fundamental matrix{flip}"
        return (
            f"the pose backend reads {warp} as parallax (t_inf {t:.3f} ≥ {th.tau_t_high:g}), so the gate asks for "
            f"a fundamental matrix{flip}, which absorbs much of it (IR {fmt(rec.background.ir)}; one homography: "
            f"{strict})"
        )
    model = rec.background.model
    tail = "" if warp is None else f", while one homography keeps {strict}"
    return (
        f"t_inf {t:.3f} is inside the {th.tau_t_low:g}–{th.tau_t_high:g} band, so both models are fitted and the "
        f"{model_name(model)} ({model}, the higher IR) is used{flip}{tail}"
    )


def _verdict_clause(old: ClipRecord, rec: ClipRecord) -> str:
    th = Thresholds.of(rec.config)
    bg0, bg1 = old.background, rec.background
    if bg1.consistent is None:
        return "too few pairs have a valid fit, so the background cannot be judged"
    if bg1.consistent:
        return f"IR {fmt(bg0.ir)} → {fmt(bg1.ir)}: the background passes the report gate again"
    drift = rec.drift_finding()
    if drift is not None and bg1.ir is not None and bg1.ir >= th.ir_gate:
        return (
            f"every pair still fits one {model_name(bg1.model)} (IR {fmt(bg1.ir)}), but the whole clip does not fit "
            f"one camera: {drift}"
        )
    if bg1.ir is not None and bg1.ir < th.ir_gate:
        return (
            f"IR {fmt(bg0.ir)} → {fmt(bg1.ir)} < {th.ir_gate:g}: no single {model_name(bg1.model)} fits the "
            "background any more, so it fails the report gate"
        )
    return (
        f"GE {fmt(bg0.ge, '.2f')} → {fmt(bg1.ge, '.2f')} px > {th.ge_gate:g} px: the background fails the report gate"
    )


def _object_clause(clip: TeachClip | None, old: ClipRecord, rec: ClipRecord, cause: str) -> str:
    oid = clip.deforming_id if clip is not None else 1
    names = clip.object_names if clip is not None else {}

    def score(r: ClipRecord, i: int) -> float | None:
        return next((o.adadfrc for o in r.objects if o.object_id == i), None)

    others = [
        f"the {names.get(o.object_id, f'object {o.object_id}')} {fmt(o.adadfrc, '.2f')}"
        for o in rec.objects
        if o.object_id != oid
    ]
    rest = f" ({', '.join(others)} px²)" if others else ""
    name = names.get(oid, f"object {oid}")
    why = (
        "a deforming object's flow is no longer one affine motion"
        if cause == "elastic_px"
        else "faster motion makes the dense flow less exact, rigid or not"
    )
    return f"AdaDFRC of the {name} {fmt(score(old, oid), '.2f')} → {fmt(score(rec, oid), '.2f')} px²{rest}, as {why}"


def _state(rec: ClipRecord) -> str:
    return {True: "passes", False: "fails", None: "cannot be judged by"}[rec.background.consistent]


def explain(before: TeachUpdate | None, after: TeachUpdate) -> str:
    """One sentence: what changed since ``before`` and why the numbers moved, read from the two
    records (the gate's label and the report verdict are the records')."""
    rec = after.record
    if rec is None:
        return f"The clip could not be scored: {after.error}."
    bg = rec.background
    if before is None or before.record is None:
        verdict = f"IR {fmt(bg.ir)} under {bg.model}: the background {_state(rec)} the report gate"
        head = "In the first clip" if before is None else "Scored again after a failed update"
        return f"{head}, {_gate_clause(rec, None, '')}; {verdict}."
    old = before.record
    changed = _changed(before.params, after.params)
    what = ", ".join(_control(n, after.params) for n in changed) or "the same settings again"
    cause = changed[0] if changed else ""
    clauses = []
    if old.gate.label != rec.gate.label:
        clauses.append(_gate_clause(rec, old.gate.label, cause))
    if old.background.consistent != bg.consistent:
        clauses.append(_verdict_clause(old, rec))
    if cause in ("elastic_px", "object_speed") and rec.objects:
        clauses.append(_object_clause(after.clip, old, rec, cause))
    if not clauses:
        strict0, strict1 = family(old, "H"), family(rec, "H")
        if cause == "rotation_deg":
            clauses.append(
                f"a rotation moves the background by one homography however large, so the gate stays "
                f"{rec.gate.label} (t_inf {fmt(rec.gate.t_inf)}) and IR is {fmt(bg.ir)}"
            )
        elif cause in ("breathing_px", "slide_px") and strict0 is not None and strict1 is not None:
            clauses.append(
                f"one homography's IR {fmt(strict0.ir)} → {fmt(strict1.ir)}; the gate stays {rec.gate.label} "
                f"(t_inf {fmt(rec.gate.t_inf)}) and the background still {_state(rec)} the report gate "
                f"(IR {fmt(bg.ir)} under {bg.model})"
            )
            p = after.params
            per_frame = p.slide_px / max(1, p.num_frames - 1)
            if cause == "slide_px" and 0 < per_frame < rec.config.tau_h and min(rec.config.gaps) == 1:
                clauses.append(
                    f"the panel drifts {per_frame:.1f} px a frame, under τ_H {rec.config.tau_h:g} px, so adjacent "
                    "pairs barely see it"
                )
        else:
            clauses.append(
                f"the gate stays {rec.gate.label} (t_inf {fmt(old.gate.t_inf)} → {fmt(rec.gate.t_inf)}), IR "
                f"{fmt(old.background.ir)} → {fmt(bg.ir)} under {bg.model}, and the background still {_state(rec)} "
                "the report gate"
            )
    return f"{what[0].upper()}{what[1:]}: {'; '.join(clauses)}."


# --- the numbers -----------------------------------------------------------------------------------


def _meter(
    value: float | None,
    lo: float,
    hi: float,
    zones: Sequence[tuple[float, float, str, str]],
    *,
    truth: float | None = None,
) -> str:
    """A horizontal scale from ``lo`` to ``hi`` with coloured ``zones`` (start, end, css colour,
    label), a black marker at ``value`` and a hollow one at ``truth``."""

    def pos(v: float) -> float:
        return 100.0 * (min(max(v, lo), hi) - lo) / (hi - lo)

    parts = [
        f'<div style="position:absolute;left:{pos(a):.2f}%;width:{pos(b) - pos(a):.2f}%;top:0;bottom:0;'
        f'background:{colour};color:#333;font-size:10px;text-align:center;line-height:14px;overflow:hidden">'
        f"{label}</div>"
        for a, b, colour, label in zones
    ]
    if truth is not None and math.isfinite(truth):
        parts.append(
            f'<div title="truth" style="position:absolute;left:calc({pos(truth):.2f}% - 5px);top:-3px;width:6px;'
            'height:16px;border:2px solid #1565c0;border-radius:3px"></div>'
        )
    if value is not None and math.isfinite(value):
        parts.append(
            f'<div style="position:absolute;left:calc({pos(value):.2f}% - 2px);top:-4px;width:4px;height:22px;'
            'background:#111;border-radius:2px"></div>'
        )
    return (
        '<div style="position:relative;height:14px;margin:6px 2px 1px 2px;background:#eee;border-radius:3px">'
        + "".join(parts)
        + '</div><div style="display:flex;justify-content:space-between;font-size:10px;color:#777">'
        f"<span>{lo:g}</span><span>{hi:g}</span></div>"
    )


_PASS, _FAIL, _GREY = "#c8e6c9", "#ffcdd2", "#e0e0e0"
_LABEL_COLOURS = {"H": "#2e7d32", "U": "#616161", "F": "#c75b00"}


def _gate_html(update: TeachUpdate, rec: ClipRecord, th: Thresholds) -> str:
    g = rec.gate
    truth = update.clip.t_inf_truth if update.clip is not None else None
    hi = max(0.12, 1.15 * max(g.t_inf or 0.0, truth or 0.0))
    no_pose = "" if g.pose_present else f" · no pose ({g.pose.reason}): F"
    return (
        f'<div style="font-size:15px"><b>Gate <span style="color:{_LABEL_COLOURS.get(g.label, "#333")}">'
        f"{g.label}</span></b> · t_inf <b>{fmt(g.t_inf)}</b> "
        f'(truth <span style="color:#1565c0">{fmt(truth)}</span>) · H ≤ {th.tau_t_low:g} &lt; U &lt; '
        f"{th.tau_t_high:g} ≤ F{no_pose}</div>"
        + _meter(
            g.t_inf,
            0.0,
            hi,
            [
                (0.0, th.tau_t_low, _PASS, "H"),
                (th.tau_t_low, th.tau_t_high, _GREY, "U"),
                (th.tau_t_high, hi, "#ffe0b2", "F"),
            ],
            truth=truth,
        )
    )


def _background_html(rec: ClipRecord, th: Thresholds) -> str:
    bg = rec.background
    state = {True: "passes", False: "FAILS", None: "cannot be judged by"}[bg.consistent]
    colour = {True: "#2e7d32", False: "#b00020", None: "#555"}[bg.consistent]
    h, f = family(rec, "H"), family(rec, "F")
    ge_hi = max(5.0, 1.2 * th.ge_gate)
    return (
        f'<div style="font-size:15px;margin-top:10px"><b>Background <span style="color:{colour}">{state}</span></b> '
        f"the report gate · model <b>{bg.model}</b> · valid pairs {bg.valid_pairs} of {bg.total_pairs}</div>"
        '<div style="display:flex;gap:18px"><div style="flex:1">'
        f"IR <b>{fmt(bg.ir)}</b> (gate ≥ {th.ir_gate:g})"
        + _meter(bg.ir, 0.5, 1.0, [(0.5, th.ir_gate, _FAIL, ""), (th.ir_gate, 1.0, _PASS, "")])
        + f'</div><div style="flex:1">GE <b>{fmt(bg.ge, ".2f")} px</b> (gate ≤ {th.ge_gate:g})'
        + _meter(bg.ge, 0.0, ge_hi, [(0.0, th.ge_gate, _PASS, ""), (th.ge_gate, ge_hi, _FAIL, "")])
        + "</div></div>"
        f'<div style="margin-top:6px">strict IR (one homography, H) <b>{fmt(h.ir if h else None)}</b> · '
        f"fundamental matrix (F) IR {fmt(f.ir if f else None)}"
        + _meter(h.ir if h else None, 0.5, 1.0, [(0.5, th.ir_gate, _FAIL, ""), (th.ir_gate, 1.0, _PASS, "")])
        + "</div>"
        + _multiview_html(rec)
    )


def _multiview_html(rec: ClipRecord) -> str:
    """The multi-view check's line: MV-IR, MV-GE and the drifting layer, if any."""
    mv = rec.multiview
    if mv is None:
        return ""
    if not mv.judged:
        return f'<div style="margin-top:6px">one camera for the clip: cannot judge ({mv.reason})</div>'
    layer = mv.layers[0].describe() if mv.layers else "no layer drifts against it"
    colour = "#b00020" if mv.layers else "#2e7d32"
    return (
        f'<div style="margin-top:6px">one camera for the clip ({mv.model}, {len(mv.registered)} keyframes): '
        f"MV-IR <b>{fmt(mv.mv_ir)}</b>, MV-GE <b>{fmt(mv.mv_ge, '.2f')} px</b> · "
        f'<span style="color:{colour}">{layer}</span></div>'
    )


def _objects_html(update: TeachUpdate, rec: ClipRecord) -> str:
    rendered = update.params.masks == "rendered" and update.clip is not None
    names = update.clip.object_names if update.clip is not None and rendered else {}
    deforming = update.clip.deforming_id if update.clip is not None and rendered else None
    hi = max([3.0, *(1.2 * (o.adadfrc or 0.0) for o in rec.objects)])
    rows = []
    for o in rec.objects:
        r, g, b = object_color(o.object_id)
        tag = " (deformed by the elasticity slider)" if o.object_id == deforming else ""
        rows.append(
            f'<div style="margin-top:4px"><span style="display:inline-block;width:10px;height:10px;'
            f'border-radius:2px;background:rgb({r},{g},{b})"></span> '
            f"{names.get(o.object_id, f'object {o.object_id}')}{tag}: AdaDFRC <b>{fmt(o.adadfrc, '.2f')} px²</b>, "
            f"AdaP90 {fmt(o.adap90, '.2f')} px²" + _meter(o.adadfrc, 0.0, round(hi, 1), []) + "</div>"
        )
    if not rows:
        return '<div style="font-size:15px;margin-top:10px"><b>Objects</b>: none tracked</div>'
    return (
        '<div style="font-size:15px;margin-top:10px"><b>Objects</b> <span style="font-size:12px">(AdaDFRC: how '
        "far each object's flow departs from one affine motion; near 0 when rigid)</span></div>" + "".join(rows)
    )


def numbers_html(update: TeachUpdate) -> str:
    """The numbers of an update as HTML: the gate against its band, IR and GE against the
    report gate, and each object's AdaDFRC, each with its scale."""
    rec = update.record
    if rec is None:
        return f'<div style="color:#b00020">could not score the clip: {update.error}</div>'
    th = Thresholds.of(rec.config)
    return (
        '<div style="font-size:13px;line-height:1.35">'
        + _gate_html(update, rec, th)
        + _background_html(rec, th)
        + _objects_html(update, rec)
        + "</div>"
    )


# --- the frame ---------------------------------------------------------------------------------------


def worst_pair(rec: ClipRecord) -> int | None:
    """The first frame of the adjacent pair with the lowest IR under the record's model (at the
    largest scale, valid fits only), or None when no pair has one."""
    s, g = max(rec.config.scales), min(rec.config.gaps)
    scored = []
    for p in rec.pairs:
        fit = p.fit(rec.background.model) if p.skip is None and p.gap == g and p.scale == s else None
        if fit is not None and fit.valid and fit.ir is not None:
            scored.append((fit.ir, p.t0))
    return min(scored)[1] if scored else None


def pair_matches(rec: ClipRecord, t: int) -> tuple[np.ndarray, np.ndarray] | None:
    """(x_t at working px, inlier mask) of the background matches of the pair (t, t + gap) at the
    largest scale under the record's model and threshold; None when that pair has no fit."""
    s = max(rec.config.scales)
    model = rec.background.model
    for p in rec.pairs:
        if p.t0 == t and p.gap == min(rec.config.gaps) and p.scale == s and p.skip is None:
            fit = p.fit(model)
            if fit is None or fit.model is None:
                return None
            tau = Thresholds.of(rec.config).tau(model)
            return rec.matches.x1[rec.matches.rows(p.index)] / s, pair_inliers(rec, p.index, model, tau)
    return None


def draw_matches(img: np.ndarray, xy: np.ndarray, inliers: np.ndarray, *, radius: int = 3) -> np.ndarray:
    """A copy of ``img`` with matches at ``xy`` (N, 2; px of ``img``): inliers as filled green
    dots, outliers as red rings."""
    out = img.copy()
    for (x, y), ok in zip(xy, inliers, strict=True):
        centre = (int(round(x)), int(round(y)))
        cv2.circle(out, centre, radius, INLIER if ok else OUTLIER, -1 if ok else 2, lineType=cv2.LINE_AA)
    return out


def tinted(rgb: np.ndarray, labels: np.ndarray | None) -> np.ndarray:
    """``rgb`` with each object's pixels (``labels`` > 0) tinted in its colour."""
    if labels is None or not labels.any():
        return rgb
    img = rgb.copy()
    for oid in np.unique(labels[labels > 0]):
        m = labels == oid
        img[m] = (0.6 * img[m] + 0.4 * np.array(object_color(int(oid)))).astype(np.uint8)
    return img
