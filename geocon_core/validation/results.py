"""One row per validation case: what was expected (synthetic truth or a person's annotation)
and what the saved record says. Everything here is read from ``record.json`` and the clip's
``.gt.json``; no score is recomputed."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np

from .cases import Annotation, CaseSpec

if TYPE_CHECKING:
    from ..record import ClipRecord

__all__ = [
    "peer_score",
    "epipolar_peer_score",
    "CaseResult",
    "case_result",
    "worst_pair_note",
    "track_coverage",
    "VERDICTS",
    "MIN_VISIBLE_PX",
    "MIN_IOU",
]

F_PX_STEPS = (0.5, 1.0, 2.0, 4.0)
"""Source-pixel thresholds at which the validation reports the share of background matches an F
model keeps (:attr:`CaseResult.f_within`)."""

MIN_VISIBLE_PX = 100
"""A true object counts as visible in a frame when its mask covers at least this many pixels at
the working size."""
MIN_IOU = 0.5
"""A track covers a true object in a frame when their masks overlap with at least this IoU."""

VERDICTS = ("consistent", "inconsistent", "not judged", "failed")
"""A case's verdict: the record's finding (:meth:`~geocon_core.record.ClipRecord.finding`: the clip
model's where the record has readings, else the report gate's), ``not judged`` for ``cannot
judge``, or ``failed`` when it could not be scored."""

_SYNTH_GATE = {"H", "F"}


@dataclass(frozen=True)
class CaseResult:
    """One case. Expected: ``truth_gate`` (H / F; None = gray zone or unknown), ``truth_category``,
    ``truth_movers`` (moving things), ``source`` (``synthetic``, ``real``, ``rendered`` or
    ``generated``), ``static_camera``, ``stable_scene``. Found: ``verdict`` (:data:`VERDICTS`),
    the gate label and its statistic ``t_inf``, whether the gate had a pose, background IR (0..1)
    and GE (px), objects tracked and the highest object AdaDFRC (px^2), the category."""

    case_id: str
    kind: str
    clip: str
    family: str | None
    failure: str | None
    level: str | None
    severity: float | None
    height: int | None
    codec: str | None
    source: str
    truth_gate: str | None
    truth_category: str | None
    truth_movers: int | None
    static_camera: bool | None
    stable_scene: bool | None
    verdict: str
    gate: str | None = None
    t_inf: float | None = None
    pose_present: bool | None = None
    pose_method: str | None = None
    ir: float | None = None
    ge: float | None = None
    model: str | None = None
    objects: int | None = None
    max_adadfrc: float | None = None
    category: str | None = None
    seconds: float | None = None
    error: str | None = None
    worst_pair: str | None = None
    """Where the background fits worst (:func:`worst_pair_note`); set on flagged scored cases."""
    track_coverage: float | None = None
    """Synthetic clips with movers: over the true movers, the least share of visible frames that a
    single track covers (:func:`track_coverage`); None without true masks or saved labels."""
    group: str = "synthetic"
    """Which set the case is reported in: ``synthetic``, ``data`` (the shared test footage, on
    which earlier rules were chosen), ``tune`` or ``check`` (the halves of the other annotated
    clips, :func:`~.cases.split_of`), or ``unannotated``."""
    camera: str = ""
    mover_size: str = ""
    dynamic: str = ""
    artifact_kinds: tuple[str, ...] = ()
    """Annotated: the camera, how large the movers are, the non-rigid background and the kinds of
    visible generation artifacts (:class:`~.cases.Annotation`)."""
    truth_cuts: tuple[int, ...] | None = None
    """Annotated first frames of new shots within the scored frames (None: not annotated)."""
    cuts: tuple[int, ...] | None = None
    """The cuts the reader found (first frames of new shots)."""
    report_margin: float | None = None
    """Headroom of the background to the report gate (negative when it fails,
    :func:`~geocon_core.scoring.verdict.report_margin`): how confident a flag is."""
    verdict_note: str | None = None
    """Why the background could not be judged, or what decided the verdict (the record's note)."""
    clip_score: float | None = None
    """The record's clip score (0 sound .. 1 broken; None: cannot judge), :mod:`geocon_core.record.finding`."""
    f_within: tuple[float, ...] | None = None
    """Share of the background matches (largest scale, movers left out) within each of
    :data:`F_PX_STEPS` source pixels of their pair's fundamental matrix (median over pairs): how
    loose the F test is (:func:`f_within_px`); None without a valid F fit."""
    tau_f_px: float | None = None
    """The source-pixel equivalent of the record's tau_F (median over the largest-scale F fits)."""
    peer_score: float | None = None
    """The peer's score on the same clip: 1 - GVGC keep rate (:mod:`.peer`); None when not run."""
    epipolar_score: float | None = None
    """The second peer's on the same clip: Epipolar-DPO's mean squared Sampson distance, px^2
    (higher = more broken, :func:`~.peer.epipolar_score`); None when not run."""
    posed: bool = False
    """The clip comes with its camera poses (a RealEstate10K walk-through): its expected gate is
    known from them, not only seen."""
    scene: str | None = None
    """Annotated clips: the clip's key (``root:clip``, :attr:`~.cases.Annotation.key`), shared by a
    real clip, the failures planted into it and its clean re-encode."""

    @property
    def reencode(self) -> bool:
        """The clean re-encode of a real clip (the planted family's counterpart of the original)."""
        return self.kind == "planted" and self.failure is None

    @property
    def planted(self) -> bool:
        """A failure planted into a real clip (:mod:`geocon_core.plant`)."""
        return self.kind == "planted" and self.failure is not None

    @property
    def flagged(self) -> bool:
        """Not called consistent (inconsistent, not judged, or failed to score)."""
        return self.verdict != "consistent"

    @property
    def clean(self) -> bool:
        return self.kind == "synthetic" and self.failure is None

    @property
    def false_flag(self) -> bool:
        """Called inconsistent (or failed to score): what a clip that obeys geometry must never be."""
        return self.verdict in ("inconsistent", "failed")

    @property
    def generated(self) -> bool:
        return self.source == "generated"

    @property
    def artifact(self) -> bool:
        """A generated clip with any visible artifact annotated."""
        return bool(self.artifact_kinds)

    @property
    def geometric_artifact(self) -> bool:
        """A visible artifact of a geometric kind (:func:`~.cases.is_geometric`)."""
        from .cases import is_geometric

        return is_geometric(self.artifact_kinds)


def worst_pair_note(rec: ClipRecord) -> str | None:
    """The valid pair (largest scale, the record's background model) with the lowest IR, in
    words: frames, gap, matches, and how far its outliers lie from the model (px of the scale).
    A flag from a handful of far-off matches on a pair with few matches reads differently from
    a flag from many matches a pixel or two off."""
    from ..geometry import family_spec

    model = rec.background.model
    if model is None or not rec.pairs:
        return None
    s_max = max(p.scale for p in rec.pairs)
    fits = []
    for p in rec.pairs:
        f = p.fit(model) if p.scale == s_max and p.skip is None else None
        if f is not None and f.valid and f.ir is not None:
            fits.append((f.ir, p.t0, p.gap, p))
    if not fits:
        return None
    ir, _, _, pair = min(fits, key=lambda x: x[:3])
    spec = family_spec(model)
    rows = rec.matches.rows(pair.index)
    res = getattr(rec.matches, spec.residual_px)[rows]
    moving = getattr(rec.matches, spec.independent)[rows]
    out = res[~getattr(rec.matches, spec.inliers)[rows] & ~moving]
    note = f"pair ({pair.t0}, {pair.t1}), gap {pair.gap}: IR {ir:.3f} of {pair.n_matches - int(moving.sum())} matches"
    if len(out):
        note += f"; {len(out)} outliers {out.min():.1f}-{out.max():.1f} px off the {model} model"
    if moving.any():
        note += f" ({int(moving.sum())} matches that move on their own left out)"
    if pair.n_gross:
        note += f" ({pair.n_gross} gross mismatches dropped before the fit)"
    return note


def track_coverage(labels: np.ndarray, truth_masks: Sequence[np.ndarray]) -> float | None:
    """How well single tracks follow the true movers: for each true object, the largest share of
    the frames where it is visible (at least :data:`MIN_VISIBLE_PX` pixels) that one track id
    covers (IoU >= :data:`MIN_IOU` with the object, the best-overlapping track in that frame);
    the least such share over the objects. ``labels``: (T, H, W) track ids (0 = background);
    ``truth_masks``: T true id images at any size (resized to the labels', nearest). None when
    no object is ever visible."""
    h, w = labels.shape[1:]
    visible: dict[int, int] = {}
    covered: dict[int, dict[int, int]] = {}
    for lab, truth in zip(labels, truth_masks, strict=True):
        if truth.shape != (h, w):
            truth = cv2.resize(truth, (w, h), interpolation=cv2.INTER_NEAREST)
        track_area = np.bincount(lab.ravel())
        for oid in (int(i) for i in np.unique(truth) if i):
            obj = truth == oid
            area = int(obj.sum())
            if area < MIN_VISIBLE_PX:
                continue
            visible[oid] = visible.get(oid, 0) + 1
            ids, inter = np.unique(lab[obj], return_counts=True)
            best, best_iou = 0, 0.0
            for tid, n in zip(ids.tolist(), inter.tolist(), strict=True):
                if tid == 0:
                    continue
                iou = n / (area + int(track_area[tid]) - n)
                if iou > best_iou:
                    best, best_iou = tid, iou
            if best and best_iou >= MIN_IOU:
                covered.setdefault(oid, {})[best] = covered.get(oid, {}).get(best, 0) + 1
    if not visible:
        return None
    return min(max(covered.get(oid, {0: 0}).values()) / n for oid, n in visible.items())


def _coverage_of(folder: Path, truth_path: str | None, rec: ClipRecord) -> float | None:
    """:func:`track_coverage` of a scored synthetic case: its saved labels against the scene's
    true label images, read into the record's working canvas as external masks are."""
    from ..masks import ExternalMasks
    from ..synth import load_ground_truth
    from .runner import LABELS_FILE

    labels_file = folder / LABELS_FILE
    if truth_path is None or not labels_file.is_file():
        return None
    gt = load_ground_truth(truth_path)
    if not gt.objects or gt.masks_path is None:
        return None
    with np.load(labels_file, allow_pickle=False) as z:
        labels = z["labels"]
    truth = ExternalMasks(Path(truth_path).parent / gt.masks_path, rec.video)
    return track_coverage(labels, [truth.labels(t) for t in range(len(labels))])


def f_within_px(rec: ClipRecord, steps: Sequence[float] = F_PX_STEPS) -> tuple[tuple[float, ...] | None, float | None]:
    """(share within each of ``steps`` source px, tau_F in source px) of the record's F fits at the
    largest scale: per valid pair, the share of its matches (independent movers left out) whose
    Sampson distance to the pair's F is within the step; the median over pairs. The F models were
    fitted at the record's tau_F, so a tighter step reads the same model's residuals (a refit at
    that step could keep a little more)."""
    if not rec.pairs:
        return None, None
    s_max = max(p.scale for p in rec.pairs)
    to_source = 1.0 / (s_max * rec.video.scale)
    m = rec.matches
    shares, taus = [], []
    for p in rec.pairs:
        f = p.fit("F") if p.scale == s_max and p.skip is None else None
        if f is None or not f.valid:
            continue
        rows = m.rows(p.index)
        keep = ~m.f_ind[rows] if m.f_ind is not None else np.ones(rows.stop - rows.start, bool)
        res = m.f_res_px[rows][keep] * to_source
        if len(res):
            shares.append([float(np.mean(res <= t)) for t in steps])
        if f.tau_px is not None:
            taus.append(f.tau_px * to_source)
    if not shares:
        return None, None
    return tuple(float(v) for v in np.median(np.array(shares), axis=0)), float(np.median(taus)) if taus else None


def peer_score(folder: Path) -> float | None:
    """``1 - keep rate`` of the peer saved in a case folder (:func:`~.peer.read_peer`), None when
    absent, of another peer version, or without a keep rate."""
    from .peer import read_peer

    saved = read_peer(folder)
    keep = None if saved is None else saved.get("keep_rate")
    return None if keep is None else 1.0 - float(keep)


def epipolar_peer_score(folder: Path) -> float | None:
    """Epipolar-DPO's mean Sampson distance saved in a case folder's ``peer.json``, None when absent."""
    from .peer import read_peer

    saved = read_peer(folder)
    second = None if saved is None else saved.get("epipolar")
    value = second.get("sampson") if isinstance(second, dict) else None
    return None if value is None else float(value)


def _report_margin(rec: ClipRecord) -> float | None:
    from ..scoring import report_margin

    return report_margin(rec.background.ir, rec.background.ge, rec.config.ir_gate, rec.config.ge_gate)


def _expected(case: dict[str, Any], truth_path: str | None) -> dict[str, Any]:
    """The expected fields of a case from its ground truth or its annotation."""
    if case["kind"] == "synthetic":
        from ..synth import load_ground_truth

        gt = load_ground_truth(truth_path) if truth_path else None
        gate = gt.expected_gate if gt is not None else None
        return {
            "source": "synthetic",
            "truth_gate": gate if gate in _SYNTH_GATE else None,
            "truth_category": case["family"],
            "truth_movers": None if gt is None else len(gt.objects),
            "static_camera": case["family"] in ("C1", "C4"),
            "stable_scene": True,
        }
    ann = case.get("annotation")
    if ann is None:
        return dict.fromkeys(("truth_gate", "truth_category", "truth_movers", "static_camera", "stable_scene")) | {
            "source": "unannotated",
            "group": "unannotated",
        }
    fields: dict[str, Any] = {k: tuple(v) if isinstance(v, list) else v for k, v in ann.items()}
    a = Annotation(**fields)
    return {
        "source": a.source,
        "truth_gate": a.gate,
        "truth_category": a.category,
        "truth_movers": a.movers,
        "static_camera": a.static_camera,
        "stable_scene": a.stable_scene,
        "group": "data" if a.root == "data" else a.split,
        "camera": a.camera,
        "mover_size": a.mover_size,
        "dynamic": a.dynamic,
        "artifact_kinds": a.artifact_kinds,
        "posed": bool(a.pose_file),
        "scene": a.key,
    }


def _scored_cuts(case: dict[str, Any], frames: int) -> tuple[int, ...] | None:
    """The annotated cuts that fall inside the scored frames (a real clip is cut to its first
    frames), or None when the clip is not annotated."""
    ann = case.get("annotation")
    if ann is None:
        return None
    return tuple(int(c) for c in ann.get("cuts", ()) if 1 <= int(c) < frames)


def case_result(status: dict[str, Any], folder: Path, spec: CaseSpec | None = None) -> CaseResult:
    """The row of a scored (or failed) case from its ``case.json`` status and record folder; the
    expectations come from ``spec`` when given (the current annotation), else from ``case.json``."""
    case = asdict(spec) if spec is not None else status["case"]
    clip = case["source"] if case["kind"] == "real" else case["case_id"]
    base = {
        "case_id": case["case_id"],
        "kind": case["kind"],
        "clip": clip if case.get("annotation") is None else case["annotation"]["clip"],
        **{k: case[k] for k in ("family", "failure", "level", "severity", "height", "codec")},
        **_expected(case, status.get("truth")),
        "seconds": status.get("seconds"),
    }
    if status["status"] != "ok":
        return CaseResult(**base, verdict="failed", error=status.get("error"))
    from ..record import read_record

    rec = read_record(folder)
    scores = [o.adadfrc for o in rec.objects if o.adadfrc is not None]
    finding = rec.finding()
    verdict = "not judged" if finding.verdict == "cannot judge" else finding.verdict
    within, tau_px = f_within_px(rec) if case["kind"] == "real" else (None, None)
    return CaseResult(
        **base,
        truth_cuts=_scored_cuts(case, rec.video.num_frames) if case["kind"] == "real" else None,
        cuts=rec.video.cuts,
        report_margin=_report_margin(rec),
        clip_score=finding.clip_score,
        peer_score=peer_score(folder),
        epipolar_score=epipolar_peer_score(folder),
        f_within=within,
        tau_f_px=tau_px,
        verdict_note=finding.reason if rec.readings is not None else rec.background.choice_note,
        verdict=verdict,
        gate=rec.gate.label,
        t_inf=rec.gate.t_inf,
        pose_present=rec.gate.pose_present,
        pose_method=rec.gate.pose.method,
        ir=rec.background.ir,
        ge=rec.background.ge,
        model=rec.background.model,
        objects=len(rec.objects),
        max_adadfrc=max(scores) if scores else None,
        category=None if rec.category is None else rec.category.label,
        worst_pair=worst_pair_note(rec) if verdict != "consistent" else None,
        track_coverage=_coverage_of(folder, status.get("truth"), rec) if case["kind"] == "synthetic" else None,
    )
