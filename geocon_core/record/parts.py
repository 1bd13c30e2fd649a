"""The parts of a :class:`~geocon_core.record.ClipRecord`: per-pair fits, per-match and per-cell
arrays, object summaries, the background verdict and the translation gate. Frozen dataclasses;
:mod:`geocon_core.record` writes and reads them.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, Literal

import numpy as np

from ..pose import PointMaps as PointMaps  # re-exported: a record part
from ..pose import PoseEstimate

__all__ = [
    "Family",
    "FitSummary",
    "PairRecord",
    "MatchArrays",
    "GapSummary",
    "ScaleSummary",
    "FamilySummary",
    "BackgroundSummary",
    "ShotRecord",
    "GateWindow",
    "GateRecord",
    "ObjectEntry",
    "ObjectScaleSummary",
    "ObjectSummary",
    "CellArrays",
    "Category",
    "PointCloud",
    "PointMaps",
]

Family = Literal["H", "F"]
"""A background model family: homography (H) or fundamental matrix (F)."""


@dataclass(frozen=True)
class FitSummary:
    """One family's fit on one pair at one scale. ``model`` is ``H_2from1`` or ``F_21`` (3x3 as
    nested lists, pixels of the scale); ``ge`` and ``tau_px`` in pixels of the scale."""

    valid: bool
    reason: str | None
    ir: float | None
    ge: float | None
    n_inliers: int
    tau: float
    tau_px: float | None
    model: list[list[float]] | None
    n_independent: int = 0
    """Outliers that move on their own, left out of ``ir`` (:attr:`MatchArrays.h_ind`)."""


@dataclass(frozen=True)
class PairRecord:
    """Frames (t0, t1) at one scale. ``skip`` names why the pair was not scored (then ``h`` and
    ``f`` are None). ``index`` addresses the pair's rows in :class:`MatchArrays`."""

    index: int
    t0: int
    t1: int
    gap: int
    scale: float
    n_matches: int
    skip: str | None
    h: FitSummary | None
    f: FitSummary | None
    n_gross: int = 0
    """Matches dropped as gross mismatches before the fits (not in ``n_matches``)."""

    def fit(self, family: Family) -> FitSummary | None:
        return self.h if family == "H" else self.f


@dataclass(frozen=True, eq=False)
class MatchArrays:
    """Per-match arrays of all pairs, concatenated; rows of pair i are
    ``offsets[i]:offsets[i+1]`` (P+1 offsets, int64).

    x1, x2: (M, 2) float32 pixels of the pair's scale.
    h_res: (M,) float32 symmetric transfer error (px).
    f_res: (M,) float32 Sampson distance in Hartley-normalised units.
    f_res_px: (M,) float32 Sampson distance of the denormalised F (px).
    h_inl, f_inl: (M,) bool inlier masks at the recorded thresholds.
    h_ind, f_ind: (M,) bool, outliers of each family's fit that move on their own (a mover the
        masks missed, :func:`~geocon_core.geometry.models.independent_motion`), left out of IR; all False
        when the preset does not look for them (then not written to ``matches.npz``).
    """

    offsets: np.ndarray
    x1: np.ndarray
    x2: np.ndarray
    h_res: np.ndarray
    f_res: np.ndarray
    f_res_px: np.ndarray
    h_inl: np.ndarray
    f_inl: np.ndarray
    h_ind: np.ndarray | None = None
    f_ind: np.ndarray | None = None

    NAMES = ("offsets", "x1", "x2", "h_res", "f_res", "f_res_px", "h_inl", "f_inl")
    OPTIONAL = ("h_ind", "f_ind")
    """Arrays that older records (and presets that do not look for independent motion) lack."""

    def __post_init__(self) -> None:
        m = int(self.offsets[-1]) if len(self.offsets) else 0
        for name in self.OPTIONAL:
            if getattr(self, name) is None:
                object.__setattr__(self, name, np.zeros(m, bool))
        shapes = {
            "x1": (m, 2),
            "x2": (m, 2),
            "h_res": (m,),
            "f_res": (m,),
            "f_res_px": (m,),
            "h_inl": (m,),
            "f_inl": (m,),
            "h_ind": (m,),
            "f_ind": (m,),
        }
        for name, shape in shapes.items():
            if getattr(self, name).shape != shape:
                raise ValueError(f"MatchArrays.{name} must have shape {shape}, got {getattr(self, name).shape}")

    def rows(self, index: int) -> slice:
        return slice(int(self.offsets[index]), int(self.offsets[index + 1]))

    def pair(self, index: int) -> dict[str, np.ndarray]:
        """All arrays of one pair (views)."""
        sl = self.rows(index)
        return {name: getattr(self, name)[sl] for name in (*self.NAMES[1:], *self.OPTIONAL)}

    @property
    def any_independent(self) -> bool:
        """Whether any match was found to move on its own (the optional arrays are worth writing)."""
        return any(bool(a is not None and a.any()) for a in (self.h_ind, self.f_ind))

    @classmethod
    def concatenate(cls, per_pair: list[dict[str, np.ndarray]]) -> "MatchArrays":
        counts = [len(p["x1"]) for p in per_pair]
        offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        cat = {}
        for name, dtype, shape in (
            ("x1", np.float32, (0, 2)),
            ("x2", np.float32, (0, 2)),
            ("h_res", np.float32, (0,)),
            ("f_res", np.float32, (0,)),
            ("f_res_px", np.float32, (0,)),
            ("h_inl", bool, (0,)),
            ("f_inl", bool, (0,)),
            ("h_ind", bool, (0,)),
            ("f_ind", bool, (0,)),
        ):
            parts = [np.asarray(p[name], dtype) if name in p else np.zeros(len(p["x1"]), dtype) for p in per_pair]
            cat[name] = np.concatenate(parts) if parts else np.zeros(shape, dtype)
        return cls(offsets=offsets, **cat)


@dataclass(frozen=True, eq=False)
class CellArrays:
    """Per-cell AdaDFRC vectors of all object entries, concatenated; rows of entry i are
    ``offsets[i]:offsets[i+1]``.

    cells: (C, 2) int16 grid indices (row, col); positions: (C, 2) float32 pixel where the
    cell's flow was observed (pixels of the entry's scale); observed, predicted: (C, 2) float32
    median and affine-predicted flow (px); weights: (C,) float32 reliable pixel counts.
    """

    offsets: np.ndarray
    cells: np.ndarray
    positions: np.ndarray
    observed: np.ndarray
    predicted: np.ndarray
    weights: np.ndarray

    NAMES = ("offsets", "cells", "positions", "observed", "predicted", "weights")

    def entry(self, index: int) -> dict[str, np.ndarray]:
        sl = slice(int(self.offsets[index]), int(self.offsets[index + 1]))
        return {name: getattr(self, name)[sl] for name in self.NAMES[1:]}

    @classmethod
    def concatenate(cls, per_entry: list[dict[str, np.ndarray] | None]) -> "CellArrays":
        counts = [0 if e is None else len(e["weights"]) for e in per_entry]
        offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        out = {}
        for name, dtype, shape in (
            ("cells", np.int16, (0, 2)),
            ("positions", np.float32, (0, 2)),
            ("observed", np.float32, (0, 2)),
            ("predicted", np.float32, (0, 2)),
            ("weights", np.float32, (0,)),
        ):
            parts = [np.asarray(e[name], dtype).reshape((-1,) + shape[1:]) for e in per_entry if e is not None]
            out[name] = np.concatenate(parts) if parts else np.zeros(shape, dtype)
        return cls(offsets=offsets, **out)


@dataclass(frozen=True)
class ObjectEntry:
    """AdaDFRC of one object on frames (t0, t1) at one scale. ``d_t`` (the paper's score) and
    ``w2`` in px^2 of the scale; ``affine`` is [M | b] (2x3) with v_pred(p) = M p + b; ``index``
    addresses the entry's cells in :class:`CellArrays`. ``reason`` says why an entry is skipped."""

    index: int
    object_id: int
    t0: int
    t1: int
    scale: float
    valid: bool
    reason: str | None
    d_t: float | None
    w2: float | None
    n_pixels: int
    affine: list[list[float]] | None


@dataclass(frozen=True)
class ObjectScaleSummary:
    """One object at one scale: mean ``D_t`` (``adadfrc`` = S) and mean W2 over its valid frame
    pairs (px^2 of the scale), AdaP90 (px^2), the number of valid pairs and the skip reasons with
    their counts."""

    scale: float
    adadfrc: float | None
    adadfrc_w2: float | None
    adap90: float | None
    valid_frames: int
    skipped: dict[str, int]


@dataclass(frozen=True)
class ObjectSummary:
    """One tracked object: frames where it is visible, its mean masked share of the content,
    and per scale the mean ``D_t`` (``adadfrc`` = S), mean W2 and AdaP90; the headline values are
    those of the largest scale."""

    object_id: int
    frames: int
    first_frame: int
    last_frame: int
    masked_share: float
    adadfrc: float | None
    adadfrc_w2: float | None
    adap90: float | None
    per_scale: tuple[ObjectScaleSummary, ...]


@dataclass(frozen=True, eq=False)
class PointCloud:
    """Two-view point cloud of the first/last pair: background matches triangulated with the
    gate's pose (in front of both cameras, reprojection <= 2 px).

    xyz: (N, 3) float32 in first-camera coordinates, on the pose's translation scale (unit mean
    scene distance); rgb: (N, 3) uint8 colours sampled from the first frame; note: how it was
    made, or why it is empty (no pose, rotation only: no parallax to triangulate).
    """

    xyz: np.ndarray
    rgb: np.ndarray
    note: str

    def __post_init__(self) -> None:
        n = self.xyz.shape[0]
        if self.xyz.shape != (n, 3) or self.rgb.shape != (n, 3):
            raise ValueError(f"PointCloud needs xyz (N, 3) and rgb (N, 3), got {self.xyz.shape} and {self.rgb.shape}")


@dataclass(frozen=True)
class Category:
    """Post-hoc scene family (SPEC section 5) with the inputs of the decision and the rule that
    fired."""

    label: str
    rule: str
    inputs: dict[str, Any]


@dataclass(frozen=True)
class GapSummary:
    """One family at one frame gap: the aggregated IR (share, 0..1) and GE (px) over its valid
    (pair, scale) entries, with the valid and total entry counts, and whether the gap met the
    coverage rule (``ScoreConfig.min_coverage``): only judged gaps enter the clip's headline."""

    gap: int
    ir: float | None
    ge: float | None
    valid_pairs: int
    total_pairs: int
    judgeable_pairs: int | None = None
    """Entries that could be judged at all (not duplicate-frame or hard-cut pairs); None in
    records made before the coverage rule."""
    judged: bool = True
    """Valid entries make up at least ``min_coverage`` of the judgeable ones."""

    @property
    def coverage(self) -> float | None:
        """Valid share of the judgeable entries (None when there are none or it is unknown)."""
        n = self.judgeable_pairs
        return None if not n else self.valid_pairs / n


@dataclass(frozen=True)
class ScaleSummary:
    """One family at one scale: the median IR (share, 0..1) and GE (px of the scale) over its valid
    pairs, their count, and the pixel equivalent of tau_F at this scale (median over valid F fits)."""

    scale: float
    ir: float | None
    ge: float | None
    valid_pairs: int
    tau_f_px: float | None


@dataclass(frozen=True)
class FamilySummary:
    """Clip-level aggregation of one family (see ``ScoreConfig.aggregation``): per gap, the median
    IR and GE over its valid (pair, scale) entries (``median``) or the worst per-scale median
    (``worst``); headline ``ir`` is the lowest per-gap IR and ``ge`` the highest per-gap GE, which
    for the paper preset (gap 1, median) is exactly the paper's median over (t, s)."""

    family: Family
    ir: float | None
    ge: float | None
    valid_pairs: int
    total_pairs: int
    per_gap: tuple[GapSummary, ...]
    per_scale: tuple[ScaleSummary, ...]
    invalid_reasons: dict[str, int]
    independent_share: float = 0.0
    """Median over the pairs with a model of the share of their matches that moved on their own
    (independent motion, a still camera's moved pixels), left out of IR."""


@dataclass(frozen=True)
class BackgroundSummary:
    """The background verdict. ``model`` is the family the gate chose (for U: the one with the
    higher IR); ``consistent`` is the report gate ``ir >= ir_gate and ge <= ge_gate`` (None when
    no pair is valid). ``tau_f_px``: pixel equivalent of tau_F (median over valid F fits at the
    largest scale). ``other`` is the other family, kept for best-of analysis."""

    model: Family
    ir: float | None
    ge: float | None
    valid_pairs: int
    total_pairs: int
    consistent: bool | None
    tau_f_px: float | None
    chosen: FamilySummary
    other: FamilySummary
    choice_note: str


@dataclass(frozen=True)
class ShotRecord:
    """One shot of a clip with hard cuts (frames ``start .. end``, inclusive), judged on its own:
    the gate on its first and last frame (``label`` H / F / U, ``t_inf``, whether it had a pose
    and how it was found), the family that gate chose, that family's IR (0..1) and GE (px) over
    the shot's pairs, the report gate (None: not judged) and a note saying why."""

    start: int
    end: int
    label: str | None
    t_inf: float | None
    pose_present: bool
    pose_method: str | None
    model: Family
    ir: float | None
    ge: float | None
    consistent: bool | None
    note: str


@dataclass(frozen=True)
class GateWindow:
    """The gate statistic on frames (start, end)."""

    start: int
    end: int
    t_inf: float | None
    label: str | None
    pose_present: bool


@dataclass(frozen=True, eq=False)
class GateRecord:
    """The translation gate: ``label`` H / F / U under the hysteresis rule, ``binary_label`` under
    the single threshold, ``model`` the family used (U -> decided by IR, fail -> F), ``t_inf`` the
    gate statistic (unit-mean-distance scale; None without a pose), ``margin`` (``tau_t_low -
    t_inf`` for H, ``t_inf - tau_t_high`` for F, minus the distance to the nearer threshold for U,
    None without a pose), ``backend`` the pose backend (``classical`` or ``log``), ``thresholds``
    the gate thresholds used by name, ``pose`` the pose estimate it came from and ``timeline`` the
    gate statistic on sliding windows of frames.

    Compared by identity: ``pose`` holds an array (compare ``pose.to_dict()`` for equality)."""

    label: str
    binary_label: str
    model: Family
    t_inf: float | None
    pose_present: bool
    margin: float | None
    backend: str
    thresholds: dict[str, float]
    pose: PoseEstimate
    timeline: tuple[GateWindow, ...] = ()

    def to_json_dict(self) -> dict[str, Any]:
        """The JSON form stored in ``record.json`` (:meth:`from_json_dict` inverts it exactly)."""
        return {
            "label": self.label,
            "binary_label": self.binary_label,
            "model": self.model,
            "t_inf": self.t_inf,
            "pose_present": self.pose_present,
            "margin": self.margin,
            "backend": self.backend,
            "thresholds": dict(self.thresholds),
            "pose": self.pose.to_dict(),
            "timeline": [asdict(w) for w in self.timeline],
        }

    @classmethod
    def from_json_dict(cls, d: dict[str, Any]) -> "GateRecord":
        return cls(
            **{
                **d,
                "pose": PoseEstimate.from_dict(d["pose"]),
                "timeline": tuple(GateWindow(**w) for w in d["timeline"]),
            }
        )
