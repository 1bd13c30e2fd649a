"""Scoring configuration: one frozen dataclass, named presets, and a stable hash.

Every number a record reports names the hash of the full configuration it came from. The
top-level fields are the paper's protocol; the settings of each stage sit in frozen
sub-configurations (:mod:`geocon_core.config.stages`) that the stage receives, e.g.
``config.motion`` for the motion segmentation. :func:`config_hash` covers all of them.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass, field, fields, is_dataclass, replace
from typing import Any

from .stages import (
    BarConfig,
    CategoryConfig,
    CutConfig,
    Dust3rConfig,
    FlowConfig,
    IndependentConfig,
    MotionConfig,
    MultiViewConfig,
    PoseConfig,
    RegionsConfig,
    Sam2Config,
    ScanConfig,
    SignalsConfig,
)

SUB_CONFIGS: dict[str, type] = {
    "bars": BarConfig,
    "cuts": CutConfig,
    "independent": IndependentConfig,
    "flow_params": FlowConfig,
    "motion": MotionConfig,
    "sam2": Sam2Config,
    "pose": PoseConfig,
    "dust3r": Dust3rConfig,
    "category": CategoryConfig,
    "scans": ScanConfig,
    "multiview": MultiViewConfig,
    "signals": SignalsConfig,
    "regions": RegionsConfig,
}
"""The nested sub-configurations of :class:`ScoreConfig` by field name."""

__all__ = [
    "ScoreConfig",
    "PRESETS",
    "DEFAULT_PRESET",
    "FOV_RANGE_DEG",
    "preset",
    "config_hash",
    "config_items",
    "UNUSED_BACKENDS",
]
__all__ += [sub.__name__ for sub in SUB_CONFIGS.values()]

FOV_RANGE_DEG = (10.0, 150.0)
"""Fields of view (horizontal, degrees) a config accepts: from a long telephoto to a wide
action camera; outside it the pinhole model the scorer assumes does not describe the clip."""


@dataclass(frozen=True)
class ScoreConfig:
    """All settings of a scoring run. Pixel thresholds are in working-resolution pixels of the
    scale being evaluated (SPEC section 0)."""

    preset: str = "paper"
    """Name of the preset this configuration started from (informative)."""
    # reading
    working_size: tuple[int, int] = (1024, 720)
    """Largest working canvas (width, height), px: a larger clip is downscaled to fit inside it,
    aspect kept; a smaller one is processed at its own size (never upscaled, see
    :mod:`geocon_core.media.reader`)."""
    bar_luma: float = 16.0
    """A border row/column whose mean luma (grey levels) never exceeds this in any frame is a burned-in bar."""
    duplicate_mad: float = 0.05
    """Consecutive frames whose mean absolute grey difference (grey levels) is at most this are duplicates."""
    # correspondences
    matcher: str = "sift"
    """Feature matcher by name (:func:`geocon_core.geometry.features.make_matcher`)."""
    scales: tuple[float, ...] = (0.25, 0.5, 1.0)
    """Scales (shares of the working resolution, in (0, 1]) every pair is scored at."""
    min_scale_side: int = 128
    """A scale below the largest is scored only when the shorter side of the clip's content is at
    least this many pixels there; smaller images hold too few features to fit a model, and their
    pairs are skipped (``scale_too_small``), which the coverage rule does not count against the clip."""
    gaps: tuple[int, ...] = (1,)
    """Frame gaps of the scored pairs (t, t + gap)."""
    aggregation: str = "median"
    """How pair scores become the clip's IR/GE. ``median`` (the paper): per gap, the median over
    valid (pair, scale); ``worst``: per gap and scale, the median over pairs, and the clip takes
    the worst cell, so a failure visible only at full resolution or long gaps is not averaged away.
    With several gaps the headline is the worst gap in both modes."""
    ratio: float = 0.8
    """Lowe ratio of the mutual nearest-neighbour matching."""
    max_features: int = 2000
    """Features per frame at scale 1; ``max_features * scale`` at smaller scales."""
    gross_match_share: float = 0.0
    """Gross-mismatch rule: a match whose displacement differs by more than this share of the
    image diagonal from the median displacement of its ``gross_match_neighbours`` nearest matches,
    in both frames, is a matcher's error (repeated structure) and is dropped before the background
    fits (:func:`~geocon_core.geometry.features.gross_mismatches`); counted per pair as ``n_gross``. 0 (the
    paper) keeps every match."""
    gross_match_neighbours: int = 8
    """Neighbours whose median displacement a match is compared with (gross-mismatch rule)."""
    # mask-first separation and object rigidity (SPEC sections 2, 4)
    masks: str = "motion"
    """Where object masks come from: ``motion`` (built-in segmentation, no weights), ``sam2``
    (SAM-2 prompted by the motion segmentation's movers, :attr:`sam2`; a checkpoint is given to
    :func:`~geocon_core.scoring.scorer.score_clip`) or ``none``; external masks are given as a path
    (``geocon score --masks DIR``)."""
    flow: str = "dis"
    """Dense flow backend by name (:func:`geocon_core.flow.dense.make_flow_backend`); its settings are
    :attr:`flow_params`."""
    grid: int = 8
    """AdaDFRC grid: N x N cells on each object's box."""
    min_cells: int = 3
    """Least valid AdaDFRC cells for an object pair to be scored."""
    # background models (SPEC section 3)
    tau_h: float = 2.0
    """Homography inlier threshold: symmetric transfer error, px."""
    tau_f: float = 0.1
    """Fundamental-matrix inlier threshold: normalised Sampson distance."""
    min_inliers: int = 30
    """Least inliers of a valid background model."""
    ir_gate: float = 0.97
    """Report gate: a clip passes with an inlier ratio of at least this (0..1)..."""
    ge_gate: float = 3.5
    """...and a geometric error (px) of at most this. The paper's 3.5 px never binds under
    ``tau_h`` = 2 px (GE is a median over inliers); ``audit`` uses 0.6 px, above the 0.44 px the
    noisiest real or clean clip of the validation reaches and below the 0.8 px of a 2 px
    breathing background."""
    min_coverage: float = 0.5
    """Coverage rule: a frame gap is judged only when at least this share (0..1) of its judgeable
    (pair, scale) rows (all but duplicate-frame and hard-cut pairs) has a valid background fit; a
    clip with no judged gap cannot be judged. Keeps a verdict from resting on a few lucky fits."""
    min_object_pairs: int = 3
    """Coverage rule for objects: an object gets AdaDFRC headline values only when at least this
    many of its pairs are valid at the largest scale; otherwise it is listed, not scored."""
    max_mask_jump: float = 0.0
    """Object pairs whose mask area departs from the median of the track's neighbouring frames
    (``mask_jump_window`` on each side) by more than the factor ``1 + max_mask_jump`` are left
    out of the object's scores and counted as ``mask_jump`` (a segmentation glitch, not a
    deformation); 0 (the paper) keeps every pair."""
    refine_object_masks: bool = False
    """Before AdaDFRC, each object pair's mask keeps only the pixels whose flow the object's own
    affine motion explains better than the background's (:func:`~geocon_core.scoring.rigidity.refine_object_mask`):
    a motion mask that spills over the object's edge would read as deformation. False (the paper)
    scores the masks as given."""
    object_gap: int = 1
    """AdaDFRC scores each object on the pair ``(t, t + object_gap)``, with the flow composed from
    the consecutive frames' flows (:func:`~geocon_core.flow.dense.chained_flow`) over the box of the
    object's masks in those frames. 1 (the paper) scores adjacent frames; a deformation that
    oscillates over many frames changes a few tenths of a pixel per frame, under the flow's
    noise, and grows with the gap while the noise of a rigid object grows far less."""
    object_scales: str = "all"
    """The scales AdaDFRC scores objects at: ``all`` (the paper: every scale of ``scales``) or
    ``top`` (the largest only: an object's headline scores are those of the largest scale, so the
    others are reported but decide nothing)."""
    object_edge_px: int = 0
    """AdaDFRC leaves out the object pixels within this many pixels (of the image the flow is
    computed on, at every scale) of the mask's edge: a dense flow mixes the motions on both sides
    of an occluding edge over about its patch (DIS ``medium``: 8 px patches on the half-resolution
    level, so 8 px either side at full resolution), and a rigid object's rim then reads as
    deformation. The grid stays on the mask's box (SPEC); cells left without a pixel drop out.
    0 (the paper) scores every reliable pixel of the mask."""
    mask_jump_window: int = 3
    """Frames on each side of a track's frame that set its expected mask area."""
    ransac_iters: int = 2000
    """Iteration budget of the background RANSAC fits."""
    ransac_confidence: float = 0.9999
    """Confidence (0..1) of the background RANSAC fits."""
    # translation gate (SPEC section 1)
    pose_backend: str = "classical"
    """Pose backend by name (:func:`geocon_core.pose.make_pose_backend`); its settings are :attr:`pose`."""
    fov_x_deg: float = 60.0
    """Horizontal field of view (degrees) assumed when intrinsics are unknown (principal point at the
    centre of the content); :data:`FOV_RANGE_DEG` bounds it (a pinhole camera near 180 degrees has
    a focal length near zero, and every residual in pixels loses its meaning)."""
    tau_t: float = 0.04
    """Binary translation gate: F when ``t_inf`` exceeds this (unit mean scene distance)."""
    tau_t_low: float = 0.03
    """Hysteresis gate: H when ``t_inf`` is at most this."""
    tau_t_high: float = 0.05
    """Hysteresis gate: F when ``t_inf`` is at least this; U in between."""
    untrusted_share: float = 0.0
    """A background that fails the report gate while at least this share of its matches (median
    over its pairs, :attr:`~geocon_core.record.FamilySummary.independent_share`) moved on their
    own cannot be judged: a mover the masks did not cover whole breaks a fit on a rigid scene as
    surely as a broken scene does, so the failure says nothing. A background that passes keeps
    its verdict (leaking movers only lower IR). 0 (the paper): off."""
    tau_t_window: float = 0.0
    """Gate windows: a clip (or shot) that the first-last ``t_inf`` gates H is in the gray zone
    when one of its gate windows (``gate_window`` frames, every ``gate_stride``) reads ``t_inf``
    above this (:func:`~geocon_core.scoring.verdict.gate_decision`). The background is judged on pairs a
    few frames apart; a camera that translates inside the clip and ends near where it started
    (a tracking shot, a walk that turns back) shows those pairs parallax that the first-last pose
    does not see. 0 (the paper): the first-last pose alone."""
    gate_window: int = 16
    """Frames between the two ends of a windowed gate estimate."""
    gate_stride: int = 8
    """Frames between the starts of consecutive gate windows."""
    chain_hop: int = 0
    """When the first-last pose fails, the gate composes the poses of consecutive hops of this
    many frames (:mod:`geocon_core.pose.chain`); 0 (the paper) leaves such a clip to fail->F."""
    chain_longest: int = 0
    """With a chain, also hops of 2, 4, ... times ``chain_hop`` frames up to this many, the
    longest with a pose taken at each frame (:func:`~geocon_core.pose.chain.select_hops`): hops of
    one frame see a pixel of parallax or less and read a translating camera as a rotation. 0 (or
    at most ``chain_hop``): hops of ``chain_hop`` frames only."""
    judge_shots: bool = False
    """A clip with hard cuts is judged shot by shot: each shot's gate on its own first and last
    frame, each shot's background on its own pairs, the clip's verdict the worst shot's
    (:func:`~geocon_core.scoring.verdict.combine_shots`). False (the paper): one gate on the clip's first
    and last frame; pairs across a cut are skipped either way."""
    still_share: float = 0.0
    """Still-camera test of the gate (:mod:`geocon_core.pose.still`): when at least this share
    (0..1) of the content, moving objects left out, moves by at most ``still_px`` between the
    first and last frame (dense flow at ``motion.analysis_size``), the camera is still and the
    gate takes that pose wherever its own would not gate H (movers that hold most of the matches
    read as a translation). 0 (the paper): never."""
    still_px: float = 1.0
    """Largest motion (px at ``motion.analysis_size``) of a pixel that counts as still."""
    still_keep_px: float = 0.5
    """A still camera is judged on its still pixels: a pair's match on a pixel that moved between
    the first and last frame is left out of IR and GE (a mover), unless it lies within this many
    px (the pair's scale) of the background model in that pair (the mover stood still there)."""
    chain_min_share: float = 0.5
    """Least share (0..1) of the clip's frame steps the hops with a pose must span for a chain
    to stand in for the first-last pose."""
    seed: int = 0
    """Seed of every random choice (RANSAC, sampling)."""
    # settings of the stages
    bars: BarConfig = field(default_factory=BarConfig)
    """Burned-in bars and the content box (reader)."""
    cuts: CutConfig = field(default_factory=CutConfig)
    """Hard-cut detection (reader)."""
    independent: IndependentConfig = field(default_factory=IndependentConfig)
    """Independent motion left out of the background fits' IR (off in ``paper``)."""
    flow_params: FlowConfig = field(default_factory=FlowConfig)
    """Settings of the dense flow backend."""
    motion: MotionConfig = field(default_factory=MotionConfig)
    """Settings of the built-in motion segmentation (also the prompts of ``masks = "sam2"``)."""
    sam2: Sam2Config = field(default_factory=Sam2Config)
    """Settings of the SAM-2 masks (``masks = "sam2"``)."""
    pose: PoseConfig = field(default_factory=PoseConfig)
    """Settings of the classical pose backend."""
    dust3r: Dust3rConfig = field(default_factory=Dust3rConfig)
    """Settings of the DUSt3R pose backend (``pose_backend = "dust3r"``)."""
    category: CategoryConfig = field(default_factory=CategoryConfig)
    """Thresholds of the scene family rule."""
    scans: ScanConfig = field(default_factory=ScanConfig)
    """Grids of the threshold-sensitivity scan."""
    multiview: MultiViewConfig = field(default_factory=MultiViewConfig)
    """One reconstruction per clip and the layers that drift against it (:mod:`geocon_core.reconstruction.multiview`;
    beyond the paper, on in ``audit``)."""
    signals: SignalsConfig = field(default_factory=SignalsConfig)
    """The clip's appearance readings (:mod:`geocon_core.signals`; beyond the paper)."""
    regions: RegionsConfig = field(default_factory=RegionsConfig)
    """Region-by-region readings over the whole clip (:mod:`geocon_core.regions`; beyond the paper)."""

    def __post_init__(self) -> None:
        if not self.scales or any(not 0 < s <= 1 for s in self.scales):
            raise ValueError(f"scales must be in (0, 1], got {self.scales}")
        if not self.gaps or any(g < 1 for g in self.gaps):
            raise ValueError(f"gaps must be positive integers, got {self.gaps}")
        if self.masks not in ("motion", "sam2", "none", "external"):
            raise ValueError(f"masks must be 'motion', 'sam2', 'none' or 'external', got {self.masks!r}")
        if self.grid < 1 or self.min_cells < 1:
            raise ValueError("grid and min_cells must be positive")
        if not 0.0 <= self.min_coverage <= 1.0:
            raise ValueError(f"min_coverage must be a share in [0, 1], got {self.min_coverage}")
        if self.max_mask_jump < 0 or self.mask_jump_window < 1:
            raise ValueError(
                "max_mask_jump must be >= 0 and mask_jump_window >= 1, "
                f"got {self.max_mask_jump}, {self.mask_jump_window}"
            )
        if self.object_scales not in ("all", "top"):
            raise ValueError(f"object_scales must be 'all' or 'top', got {self.object_scales!r}")
        if self.object_gap < 1 or self.object_edge_px < 0 or self.min_object_pairs < 1:
            raise ValueError(
                "object_gap and min_object_pairs must be at least 1 and object_edge_px >= 0, got "
                f"{self.object_gap}, {self.min_object_pairs}, {self.object_edge_px}"
            )
        if self.min_inliers < 1:
            raise ValueError(f"min_inliers must be at least 1, got {self.min_inliers}")
        if self.aggregation not in ("median", "worst"):
            raise ValueError(f"aggregation must be 'median' or 'worst', got {self.aggregation!r}")
        self._check_gate()
        if not 0.0 <= self.gross_match_share < 1.0 or self.gross_match_neighbours < 3:
            raise ValueError("gross_match_share must be in [0, 1) and gross_match_neighbours at least 3")
        if min(self.working_size) < 32:
            raise ValueError(f"working_size too small: {self.working_size}")
        lo, hi = FOV_RANGE_DEG
        if not lo <= self.fov_x_deg <= hi:
            raise ValueError(
                f"the field of view (fov_x_deg, --fov) must be between {lo:g} and {hi:g} degrees, "
                f"got {self.fov_x_deg:g}"
            )

    def _check_gate(self) -> None:
        """The gate's settings: thresholds in order, chains and the still-camera test."""
        if not self.tau_t_low <= self.tau_t_high:
            raise ValueError("tau_t_low must not exceed tau_t_high")
        if self.tau_t_window < 0:
            raise ValueError("tau_t_window must be >= 0 (0: off)")
        if not 0.0 <= self.untrusted_share <= 1.0:
            raise ValueError("untrusted_share must be in [0, 1] (0: off)")
        if self.chain_hop < 0 or self.chain_longest < 0 or not 0.0 < self.chain_min_share <= 1.0:
            raise ValueError("chain_hop and chain_longest must be >= 0 and chain_min_share in (0, 1]")
        if not 0.0 <= self.still_share <= 1.0 or self.still_px <= 0 or self.still_keep_px < 0:
            raise ValueError("still_share must be in [0, 1], still_px positive and still_keep_px >= 0")

    def to_dict(self) -> dict[str, Any]:
        """JSON-able nested dict (tuples become lists); :meth:`from_dict` inverts it exactly."""
        return _lists(asdict(self))

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "ScoreConfig":
        """The configuration of a :meth:`to_dict` dict. A dict of the earlier flat layout (no
        sub-configurations) gives their defaults; an unknown key raises ValueError."""
        kw: dict[str, Any] = _fields_of(cls, d, "config")
        for name, sub in SUB_CONFIGS.items():
            if name in kw:
                value = kw[name]
                if not isinstance(value, dict):
                    raise ValueError(f"config key {name!r} must be a mapping of {sub.__name__} fields, got {value!r}")
                kw[name] = sub(**_fields_of(sub, value, f"config.{name}"))
        return cls(**kw)

    def with_(self, **changes: Any) -> "ScoreConfig":
        """A copy with the given top-level fields replaced (sub-configurations as whole values)."""
        return replace(self, **changes)


PRESETS: dict[str, tuple[str, ScoreConfig]] = {
    "paper": ("the paper's protocol: adjacent frames (gap 1), scales 1/4, 1/2, 1, SIFT", ScoreConfig()),
    "strict": (
        "paper plus frame gaps 4 and 8, which expose slow drift (breathing) that adjacent pairs miss; "
        "the clip takes its worst (gap, scale) median",
        ScoreConfig(preset="strict", gaps=(1, 4, 8), aggregation="worst"),
    ),
    "audit": (
        "strict's worst-cell aggregation over frame gaps 1 and 8 at the canvas's own scale (the gap 4 and "
        "the 1/4 and 1/2 scales were dropped: on the tune half of the annotated and planted clips they "
        "moved no detection row beyond one clip), plus a gate that has a pose (when the first and last "
        "frames share too few matches, "
        "the relative poses of consecutive frames are composed; fail->F only without any evidence), "
        "Lowe's ratio 0.7, so that false matches, which grow with the frame gap, do not read as "
        "inconsistency, a GE gate of 0.6 px: a background whose inliers sit half a pixel off "
        "their model is bending (breathing), whatever its inlier ratio, and a canvas whose long side "
        "is at most 1280 px, so a clip up to 1280x720 is scored in its own pixels and a larger one is "
        "resized once at decode (the record says so and gives the background's GE in source px); "
        "an object's pairs whose mask jumps in area by more than 25% "
        "against its neighbouring frames are left out of its AdaDFRC (a segmentation glitch reads "
        "as deformation), and each object's mask keeps only the pixels its own motion explains better "
        "than the background's (a mask that spills over the edge reads as deformation too); matches "
        "that disagree with all their neighbours by more than 4% of the image diagonal (repeated "
        "structure) are dropped before the background fits; AdaDFRC scores object pairs 4 frames apart "
        "(flow composed hop by hop), where a slow deformation exceeds the flow's noise, leaving out the "
        "object pixels within 8 px of the mask's edge, where the flow mixes the object's motion with "
        "the background's; background outliers that jump away from the background around them (a mover "
        "the masks did not cover whole) are left out of IR and counted; a camera whose frame stays still "
        "between its first and last frame (dense flow, 15% of the content or more, movers left out) is "
        "gated as still and judged on its still pixels; clips with hard cuts or cross-fades (up to 30 "
        "frames) are judged shot by shot; objects are scored at the largest scale only (their headline "
        "scores); "
        "a clip the first-last pose gates H whose 16-frame gate window reads t_inf above 0.03 is in the "
        "gray zone (both families fitted); a failing background half of whose matches moved on their "
        "own cannot be judged; the verdict is a clip model's over readings beyond the background (dense-flow "
        "failures, appearance the flow does not explain, the keep reading), fitted on annotated clips; "
        "region-by-region readings over the whole clip (long tracks, each region's motion against the "
        "clip's camera and its look against its start) are recorded and drawn, not yet read by the verdict; "
        "the default of `geocon score` and `geocon bench`",
        ScoreConfig(
            preset="audit",
            working_size=(1280, 1280),
            gaps=(1, 8),
            scales=(1.0,),
            aggregation="worst",
            chain_hop=1,
            ratio=0.7,
            ge_gate=0.6,
            max_mask_jump=0.25,
            gross_match_share=0.04,
            refine_object_masks=True,
            object_gap=4,
            object_edge_px=8,
            object_scales="top",
            independent=IndependentConfig(enabled=True),
            still_share=0.15,
            judge_shots=True,
            tau_t_window=0.03,
            untrusted_share=0.5,
            cuts=CutConfig(fade_frames=30),
            multiview=MultiViewConfig(enabled=True),
            signals=SignalsConfig(enabled=True),
            regions=RegionsConfig(enabled=True),
        ),
    ),
    "fast": (
        "live teaching demos and first-pass triage of large benchmarks: a 512x360 canvas scored at its "
        "own size only (one scale; a larger clip is downscaled, a smaller one kept), KLT tracks kept alive "
        "across frames instead of SIFT (each frame tracked once; a pair matches the tracks alive in both), "
        "1000 tracks, DIS `fast` flow, motion segmentation analysed at 256x180 and gate windows every "
        "16 frames, SAM-2 masks (when chosen) at 512 px; otherwise the paper's protocol (its thresholds "
        "apply to the 512x360 canvas as they do to the paper's half-size scale)",
        ScoreConfig(
            preset="fast",
            working_size=(512, 360),
            matcher="klt_tracks",
            max_features=1000,
            scales=(1.0,),
            gate_stride=16,
            flow_params=FlowConfig(preset="fast"),
            motion=MotionConfig(analysis_size=(256, 180)),
            sam2=Sam2Config(image_size=512),
        ),
    ),
    "reward": (
        "a reward for training loops (geocon_core.reward): an 854x480 canvas scored at its own size, "
        "frame gaps 1 and 4 of at most 32 frames sampled evenly over the clip, KLT tracks kept alive across "
        "frames (1000; SIFT costs five times as much per frame), the built-in motion masks analysed at "
        "256x180, independent motion left "
        "out of IR, a gate that has a pose (consecutive hops when the first-last pose fails), gate windows "
        "every 16 frames; no objects' rigidity, no clip model, no multi-view check and no region readings "
        "(their cost buys no preference on the planted pairs at this size); the record gives the reward its "
        "verdict, gate and background readings, the reward itself reads windows of fresh tracks on the same "
        "frames (RewardConfig), with a bootstrap interval, and guards make frozen, repeated, blurred, "
        "textureless and cut clips cannot judge",
        ScoreConfig(
            preset="reward",
            working_size=(854, 480),
            matcher="klt_tracks",
            max_features=1000,
            scales=(1.0,),
            gaps=(1, 4),
            chain_hop=1,
            gate_stride=16,
            gross_match_share=0.04,
            independent=IndependentConfig(enabled=True),
            flow_params=FlowConfig(preset="fast"),
            motion=MotionConfig(analysis_size=(256, 180)),
            object_scales="top",
        ),
    ),
}
"""The presets by name: a one-line description and the configuration (:func:`preset` builds them)."""

DEFAULT_PRESET = "audit"
"""The preset ``geocon score`` and ``geocon bench`` use unless told otherwise; ``paper`` is the
exact reproduction of the paper's protocol."""


def preset(name: str) -> ScoreConfig:
    """The configuration of a named preset; an unknown name lists the valid ones."""
    try:
        return PRESETS[name][1]
    except KeyError:
        raise ValueError(f"unknown preset {name!r}; valid: {', '.join(PRESETS)}") from None


def config_items(config: ScoreConfig) -> list[tuple[str, Any]]:
    """Every setting as (dotted name, value), sub-configurations expanded (``motion.min_area``)."""
    out: list[tuple[str, Any]] = []
    for f in fields(config):
        value = getattr(config, f.name)
        if is_dataclass(value):
            out.extend((f"{f.name}.{g.name}", getattr(value, g.name)) for g in fields(value))
        else:
            out.append((f.name, value))
    return out


def _lists(value: Any) -> Any:
    """Tuples -> lists, recursively through dicts (the JSON form)."""
    if isinstance(value, dict):
        return {k: _lists(v) for k, v in value.items()}
    if isinstance(value, (tuple, list)):
        return [_lists(v) for v in value]
    return value


def _fields_of(cls: type, d: dict[str, Any], where: str) -> dict[str, Any]:
    """Keyword arguments of ``cls`` from the JSON dict ``d`` (lists -> tuples); unknown keys raise."""
    names = {f.name for f in fields(cls)}
    unknown = set(d) - names
    if unknown:
        raise ValueError(f"unknown {where} keys: {', '.join(sorted(unknown))}")
    return {k: tuple(v) if isinstance(v, list) else v for k, v in d.items()}


LATER_DEFAULTS: dict[str, Any] = {"object_scales": "all"}
"""Settings added after configurations were first hashed, with the value that behaves as before
they existed: at that value a setting is left out of the hash, so earlier records keep theirs."""

UNUSED_BACKENDS: dict[str, tuple[str, str]] = {"sam2": ("masks", "sam2"), "dust3r": ("pose_backend", "dust3r")}
"""Settings of an optional backend (key) that count only when the field names it (field, value)."""


def config_hash(config: ScoreConfig) -> str:
    """First 16 hex digits of the SHA-256 of the canonical JSON of the configuration, without the
    settings of an optional backend that is not selected (they cannot change a number, and a
    configuration's hash does not change when such a backend is added)."""
    d = config.to_dict()
    for key, (name, value) in UNUSED_BACKENDS.items():
        if d.get(name) != value:
            d.pop(key, None)
    if not config.multiview.enabled:  # off: its settings cannot change a number
        d.pop("multiview", None)
    if not config.signals.enabled:  # off: likewise
        d.pop("signals", None)
    if not config.regions.enabled:  # off: likewise
        d.pop("regions", None)
    for name, default in LATER_DEFAULTS.items():  # at the earlier behaviour: the earlier hash
        if d.get(name) == default:
            d.pop(name, None)
    blob = json.dumps(d, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(blob.encode()).hexdigest()[:16]
