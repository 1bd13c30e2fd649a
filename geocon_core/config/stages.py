"""The settings of each scoring stage, as frozen sub-configurations of :class:`~geocon_core.config.ScoreConfig`.

Each stage receives its own sub-configuration: the reader (:class:`BarConfig`, :class:`CutConfig`),
the flow backend (:class:`FlowConfig`), the motion segmentation (:class:`MotionConfig`), the
pose backend (:class:`PoseConfig`), the category rule (:class:`CategoryConfig`) and the
threshold scans (:class:`ScanConfig`). Every field can change a recorded number, so every
field is covered by the configuration hash. Lengths are pixels of the images the stage works
on unless a docstring says otherwise.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = [
    "DIS_PRESET_NAMES",
    "BarConfig",
    "CutConfig",
    "IndependentConfig",
    "FlowConfig",
    "MotionConfig",
    "Sam2Config",
    "PoseConfig",
    "Dust3rConfig",
    "CategoryConfig",
    "ScanConfig",
    "MultiViewConfig",
    "SignalsConfig",
    "RegionsConfig",
]

SHIPPED_MODEL_DIGEST = "a2ef81b8baab"
"""The digest of the clip model shipped in the package (``geocon_core/signals/clip_model.json``)."""

DIS_PRESET_NAMES = ("ultrafast", "fast", "medium")
"""The OpenCV DIS presets :class:`FlowConfig` accepts."""


@dataclass(frozen=True)
class BarConfig:
    """Burned-in black bars and the content box (reader, SPEC section 0)."""

    min_content_share: float = 0.3
    """Bars that would leave less than this share (0..1) of the height or width mean a dark clip: no bars."""
    margin_px: int = 2
    """Working pixels dropped from the content box on each side that has a bar (codec ringing at the edge)."""

    def __post_init__(self) -> None:
        if not 0 <= self.min_content_share <= 1 or self.margin_px < 0:
            raise ValueError("bars: min_content_share must be in [0, 1] and margin_px non-negative")


@dataclass(frozen=True)
class CutConfig:
    """Hard-cut detection of the reader: a cut between two frames needs every test below."""

    thumb_width: int = 64
    """Width (px) of the grey thumbnails compared; the height keeps the aspect ratio."""
    hist_bins: int = 32
    """Grey-level histogram bins of a thumbnail."""
    min_distance: float = 0.1
    """Bhattacharyya distance (0..1) between the two thumbnails' histograms must exceed this."""
    min_mad: float = 20.0
    """Mean absolute thumbnail difference (grey levels) must exceed this."""
    median_factor: float = 2.5
    """The distance must exceed this many times the median distance of the clip's other pairs."""
    neighbour_factor: float = 2.0
    """The distance, or the mean absolute difference, must exceed this many times the larger one of the
    adjacent pairs (a cut is an isolated spike; a fast pan or a passing occluder raises several
    consecutive distances, and a change of exposure just before a cut raises the histogram distance
    of the pair before it but not its picture difference)."""
    lone_distance: float = 0.35
    """The distance a pair needs when the clip has no other pair to compare it with."""
    fade_frames: int = 0
    """Cross-fades (dissolves) up to this many frames long are found (:func:`~geocon_core.media.reader.find_fades`):
    the frames between a fade's two ends are blends of them, so no pair that touches them is scored and
    the shots on either side are judged on their own. 0 (the paper): fades are not looked for."""
    fade_residual: float = 0.15
    """A frame inside a fade is the blend of the fade's two end frames that fits it best, to within
    this share (RMS) of the two ends' difference, on grey thumbnails ``fade_width`` px wide."""
    fade_width: int = 32
    """Width (px) of the grey thumbnails the fade test compares."""
    fade_max_ncc: float = 0.5
    """A fade's two ends are different pictures: the normalised cross-correlation of their
    thumbnails (mean removed) is below this. A change of light keeps the picture (0.9 and more on
    the generated clips whose sunlight or lightning comes and goes) and is no fade."""

    def __post_init__(self) -> None:
        if self.thumb_width < 1 or self.hist_bins < 1 or self.fade_width < 1:
            raise ValueError("cuts: thumb_width, hist_bins and fade_width must be positive")
        if self.fade_frames < 0 or not 0 < self.fade_residual < 1 or not -1 <= self.fade_max_ncc <= 1:
            raise ValueError("cuts: fade_frames must be >= 0, fade_residual in (0, 1) and fade_max_ncc in [-1, 1]")


@dataclass(frozen=True)
class IndependentConfig:
    """Independent motion in the background fits (:func:`~geocon_core.geometry.models.independent_motion`):
    the outliers of a pair's background model that jump away from the background around them (a
    mover the object masks did not cover whole) are left out of the pair's IR and counted. Off in
    ``paper`` (every match counts, as the paper's IR)."""

    enabled: bool = False
    """Look for independent motion in every pair's fits."""
    neighbours: int = 8
    """Nearest inliers an outlier is compared with."""
    jump: float = 4.0
    """An outlier is independent when its residual is at least this many times the median
    residual of its nearest inliers (a motion boundary: the background beside it fits)."""
    max_share: float = 0.5
    """A pair whose matches move on their own for more than this share (0..1] cannot be judged
    (``independent_motion``): what is left is not the scene's background."""

    def __post_init__(self) -> None:
        if self.neighbours < 1 or self.jump <= 0 or not 0 < self.max_share <= 1:
            raise ValueError("independent: neighbours must be at least 1, jump positive and max_share in (0, 1]")


@dataclass(frozen=True)
class FlowConfig:
    """Dense optical flow (:class:`~geocon_core.flow.DisFlow`), shared by the motion
    segmentation and the object rigidity (AdaDFRC)."""

    preset: str = "medium"
    """OpenCV DIS preset, one of :data:`DIS_PRESET_NAMES`."""
    fb_abs: float = 0.5
    """Constant part (px) of the forward-backward threshold ``fb_abs + fb_rel * |F|``."""
    fb_rel: float = 0.05
    """Share of the flow length added to the forward-backward threshold."""
    margin: int = 16
    """Context (px) computed around a box on every side."""
    min_side: int = 16
    """Regions narrower or lower than this (px) are padded (edge pixels repeated) before DIS."""

    def __post_init__(self) -> None:
        if self.preset not in DIS_PRESET_NAMES:
            raise ValueError(f"unknown DIS preset {self.preset!r}; valid: {', '.join(DIS_PRESET_NAMES)}")
        if not (self.fb_abs >= 0 and self.fb_rel >= 0):
            raise ValueError(f"fb_abs and fb_rel must be non-negative, got {self.fb_abs}, {self.fb_rel}")
        if self.margin < 0:
            raise ValueError(f"margin must be non-negative, got {self.margin}")
        if self.min_side < 1:
            raise ValueError(f"min_side must be positive, got {self.min_side}")


@dataclass(frozen=True)
class MotionConfig:
    """Built-in motion segmentation (:class:`~geocon_core.masks.MotionSegmenter`). *Reduced* px
    are pixels of the analysis scale; other lengths are working pixels per frame."""

    analysis_size: tuple[int, int] = (512, 360)
    """(width, height), px: the content is analysed at the largest size that fits inside this,
    never above the working size (a 1024x576 clip at half size, a 320x180 clip at its own)."""
    px_reference: tuple[int, int] = (1024, 720)
    """(width, height), px: the pixel settings below (``fit_tau_px``, ``static_px``, ``min_px``,
    ``merge_px``, ``merge_speed_px``, ``link_speed_px``) are pixels of the content fitted inside
    this size (never up). The segmentation analyses an image of at most ``analysis_size`` whatever
    the scoring canvas, so its settings must not follow the canvas: a 1280x720 clip scored on a
    1920x1080 canvas is segmented exactly as on a 1024x720 one."""
    fit_step: int = 12
    """Spacing (reduced px) of the grid of flow vectors that the background models are fitted to."""
    fit_tau_px: float = 1.0
    """Inlier tolerance (px) of the background model fits."""
    fit_min_inliers: int = 30
    """Least reliable grid vectors for a background fit, and least inliers of a valid fit."""
    fit_iters: int = 1000
    """RANSAC iteration budget of each background fit."""
    f_fit_tau: float = 0.1
    """Inlier threshold (normalised Sampson distance) of the fundamental-matrix fit."""
    static_px: float = 0.5
    """The background is static when the homography moves 95 % of the grid vectors by at most this (px)."""
    f_gain: float = 0.05
    """Share of all grid vectors a fundamental matrix must explain beyond the homography to be used."""
    k_sigma: float = 4.0
    """Residual threshold in robust standard deviations of the background residual."""
    min_px: float = 2.0
    """Lower bound (px) of the residual threshold."""
    parallax_share: float = 0.25
    """With a fundamental-matrix background (a translating camera), this share of a pixel's parallax
    (px: its displacement from the homography's prediction) is subtracted from its residual before
    thresholding: flow errors grow with the displacement, and near surfaces move most. 0 disables it."""
    slow_gap: int = 4
    """With a still camera, frame t is also compared with the distinct frame this many frames earlier
    (its residual thresholded like an adjacent pair's), so movers slower than ``min_px`` per frame are
    found; 0 or 1 disables it."""
    min_area: float = 0.001
    """Smallest object, a share of the content area."""
    max_area: float = 0.35
    """Largest object, a share of the content area."""
    min_solidity: float = 0.5
    """Smallest object solidity (area over convex-hull area)."""
    min_thickness: float = 2.0
    """Smallest distance (reduced px) of an object's core from its edge."""
    edge_ratio: float = 0.5
    """Largest ratio of the median score in the ring around an object to the median score inside."""
    refine: float = 0.5
    """A pixel is kept where its score reaches this share of the highest score within ``halo_px``."""
    halo_px: int = 6
    """Radius (reduced px) of the local-maximum window that trims the flow halo around objects."""
    min_reliable: float = 0.3
    """Smallest share of an object's pixels that pass the forward-backward check."""
    fov_deg: float = 60.0
    """Horizontal field of view (degrees) over the content width assumed for the cheirality residual."""
    match_overlap: float = 0.3
    """Smallest overlap ``|A & B| / min(|A|, |B|)`` between a track's predicted mask and a detection."""
    max_gap: int = 2
    """Frames a track survives without a detection."""
    min_track: int = 6
    """Distinct frames a track must be detected in to become an object (shorter tracks are flicker)."""
    lookahead: int = 7
    """Frames after t that must be pushed before the labels of frame t are final (at least 2); a track
    is labelled in frame t when its ``min_track``-th detection comes by frame t + lookahead - 1."""
    merge_px: float = 16.0
    """Regions of one frame at most this far apart (px) and moving alike are parts of one mover."""
    merge_speed_px: float = 1.0
    """Parts of one mover: their velocities differ by at most this (px per frame) plus ``merge_speed_share``."""
    merge_speed_share: float = 1.0
    """Parts of one mover: allowed velocity difference as a share of the faster part's speed."""
    link_gap: int = 60
    """A newly confirmed track takes over the id of a track lost at most this many frames before it began."""
    link_radius: float = 1.5
    """Re-identification: largest distance from the lost track's expected position, in object sizes
    (square root of its last area)."""
    link_speed_px: float = 6.0
    """Re-identification: extra distance allowed per frame of the gap (px per frame)."""
    link_hist: float = 0.5
    """Re-identification: largest Bhattacharyya distance (0..1) between the two tracks' colour histograms."""
    cheirality_min_share: float = 0.6
    """Share of the fundamental matrix's inlier vectors the cheirality pose must put in front of both
    cameras; otherwise that residual is not used."""
    f_fit_points: int = 600
    """About this many grid vectors feed a fundamental-matrix fit (every k-th one)."""
    dynamic_open_px: int = 5
    """Pixels whose flow fails the forward-backward check count as a dynamic background
    (``MotionSegmenter.dynamic``) in blobs at least this many reduced px across (thinner bands
    are the background uncovered along an occluding edge)."""

    def __post_init__(self) -> None:
        if min(self.px_reference) < 16:
            raise ValueError(f"px_reference must be at least 16x16 px, got {self.px_reference}")
        if min(self.analysis_size) < 16:
            raise ValueError(f"analysis_size must be at least 16x16 px, got {self.analysis_size}")
        if self.min_track < 1:
            raise ValueError(f"min_track must be at least 1, got {self.min_track}")
        if self.lookahead < 2:
            raise ValueError(f"lookahead must be at least 2, got {self.lookahead}")
        if not 1.0 < self.fov_deg < 179.0:
            raise ValueError(f"fov_deg must be in (1, 179), got {self.fov_deg}")
        if min(self.fit_step, self.f_fit_points, self.fit_iters, self.fit_min_inliers) < 1 or self.halo_px < 0:
            raise ValueError(
                "fit_step, f_fit_points, fit_iters, fit_min_inliers must be positive, halo_px non-negative"
            )


MAX_SAM2_SIZE = 4096
"""The largest side SAM-2 may see the frames at (four times its training size; a larger square
image would not fit a machine's memory)."""


@dataclass(frozen=True)
class Sam2Config:
    """SAM-2 masks (:class:`~geocon_core.masks.sam2.Sam2Masks`): the model, the size it sees and
    how the motion segmentation's movers become its prompts."""

    model: str = "sam2.1_hiera_t"
    """Model configuration shipped in the ``sam2`` package (``sam2.1_hiera_t``, ``sam2_hiera_s``,
    ..., with or without ``.yaml`` and ``configs/<family>/``); it must match the checkpoint."""
    image_size: int = 1024
    """Side (px) of the square image SAM-2 sees (the content box resized to it). 1024 is the
    models' training size; 512 is about 4x faster on a CPU with masks at half the detail."""
    box_margin: float = 0.05
    """A prompt box is the mover's motion-mask box grown by this share of its size on each side
    (motion masks are trimmed to the sharp part of the motion and can miss an object's rim)."""
    prompt_cover: float = 0.5
    """A new motion id whose mask lies at least this share (0..1] inside objects SAM-2 already
    tracks in that frame is one of them (a mover the motion segmentation re-detected), not a new
    prompt."""
    mask_threshold: float = 0.0
    """A pixel belongs to an object where SAM-2's mask logit exceeds this (0: probability 1/2)."""

    def __post_init__(self) -> None:
        if not self.model.strip():
            raise ValueError("sam2.model must name a SAM-2 model configuration, e.g. sam2.1_hiera_t")
        if not 64 <= self.image_size <= MAX_SAM2_SIZE or self.image_size % 32:
            raise ValueError(
                f"sam2.image_size must be a multiple of 32 from 64 to {MAX_SAM2_SIZE} px (--sam2-size), "
                f"got {self.image_size}"
            )
        if self.box_margin < 0 or not 0.0 < self.prompt_cover <= 1.0:
            raise ValueError("sam2.box_margin must be >= 0 and sam2.prompt_cover in (0, 1]")


@dataclass(frozen=True)
class PoseConfig:
    """Classical two-view pose backend (:class:`~geocon_core.pose.ClassicalPose`); pixels are
    pixels of the images the matches come from."""

    min_matches: int = 30
    """Fewer finite matches give the failure ``too_few_matches``."""
    min_inliers: int = 15
    """Least inliers of a model, and least points triangulated in front of both cameras."""
    min_inlier_share: float = 0.25
    """A model needs at least this share of the matches as inliers (and ``min_inliers``)."""
    essential_px: float = 1.0
    """Inlier threshold (px, Sampson distance) of the essential-matrix RANSAC."""
    rot_ransac_px: float = 2.0
    """Inlier threshold (px, transfer error) of the rotation-only RANSAC."""
    rot_median_px: float = 1.0
    """The rotation-only model explains the matches when their median parallax (px) is at most this..."""
    rot_share_px: float = 2.0
    """...and a share of at least ``rot_share`` of them lies within this parallax (px)."""
    rot_share: float = 0.8
    """Share of the consistent matches that must lie within ``rot_share_px``."""
    fit_focal: bool = True
    """Self-calibrate a common focal scale (principal point fixed)."""
    focal_sigma: float = 0.2
    """Standard deviation of the prior on the log focal scale."""
    focal_min_gain: float = 100.0
    """Least likelihood-ratio statistic for adopting a fitted focal scale in the essential model."""
    max_focal_ratio: float = 1.6
    """Bound on the focal scale (and on its inverse)."""
    fit_zoom: bool = False
    """Let the rotation-only model zoom: the second frame's focal length is the first's times a
    free factor (``x1 ~ K_z R K^-1 x0``), so a rotating and zooming camera, whose images a
    homography relates exactly, is not read as a forward translation. Off in every preset: on real
    footage a camera backing down a room read as a zoom (see the README)."""
    max_zoom: float = 3.0
    """Bound on the zoom factor between the two frames (and on its inverse)."""
    trim: float = 0.0
    """Share of the sorted triangulated distances dropped at each end before the mean (a symmetric
    trim biases the mean of the skewed distances of a multi-depth scene; ``scale_fence_iqr`` is the
    outlier rule)."""
    scale_fence_iqr: float = 4.0
    """Triangulated distances whose logarithm lies more than this many interquartile ranges (of the
    log distances) outside the quartiles are dropped before the mean (wild near-epipole points)."""
    scale_area_grid: int = 64
    """Samples along the longer side of the first frame's matched area: each triangulated point is
    weighted by the share of the samples nearest to it (its image area), so the mean scene distance
    is a mean over the image, as the truth is, not over where the features cluster; 0 weights every
    point equally."""
    ransac_iters: int = 5000
    """Iteration budget of the essential-matrix RANSAC."""
    rot_hypotheses: int = 300
    """Two-point hypotheses of the rotation-only RANSAC."""
    confidence: float = 0.9999
    """RANSAC confidence of the essential-matrix fit (0..1)."""

    def __post_init__(self) -> None:
        if self.min_matches < 8:
            raise ValueError(f"min_matches must be at least 8, got {self.min_matches}")
        if self.min_inliers < 6:
            raise ValueError(f"min_inliers must be at least 6, got {self.min_inliers}")
        if not 0 <= self.trim < 0.5:
            raise ValueError(f"trim must be in [0, 0.5), got {self.trim}")
        if not (self.scale_fence_iqr > 0 and self.scale_area_grid >= 0):
            raise ValueError("scale_fence_iqr must be positive and scale_area_grid non-negative")
        if not min(self.essential_px, self.rot_ransac_px, self.rot_median_px, self.rot_share_px) > 0:
            raise ValueError("pixel thresholds must be positive")
        if not (0 < self.rot_share <= 1 and 0 <= self.min_inlier_share <= 1):
            raise ValueError("rot_share must be in (0, 1] and min_inlier_share in [0, 1]")
        if self.max_zoom < 1:
            raise ValueError(f"max_zoom must be at least 1, got {self.max_zoom}")
        if not (self.focal_sigma > 0 and self.max_focal_ratio >= 1 and self.focal_min_gain >= 0):
            raise ValueError("focal_sigma must be positive, max_focal_ratio >= 1, focal_min_gain >= 0")
        if self.ransac_iters < 1 or self.rot_hypotheses < 1 or not 0 < self.confidence < 1:
            raise ValueError("ransac_iters and rot_hypotheses must be positive, confidence in (0, 1)")


@dataclass(frozen=True)
class Dust3rConfig:
    """DUSt3R pose backend (:class:`~geocon_core.pose.dust3r.Dust3rPose`): how its point maps of
    the first and last frame become the gate's pose and the record's point maps."""

    min_conf: float = 3.0
    """Least DUSt3R confidence (``1 + exp(.)``, so at least 1) of a pixel used for the pose and
    for the mean scene distance; DUSt3R's own demo keeps points from 3 up."""
    min_points: int = 100
    """Fewer confident pixels in both point maps give the failure ``too_few_points``."""
    record_side: int = 128
    """Longest side (points) of the point maps stored in the record (subsampled on a grid)."""

    def __post_init__(self) -> None:
        if not self.min_conf >= 1.0:
            raise ValueError(f"dust3r.min_conf must be at least 1 (DUSt3R's least confidence), got {self.min_conf}")
        if self.min_points < 3 or self.record_side < 1:
            raise ValueError("dust3r.min_points must be at least 3 and dust3r.record_side at least 1")


@dataclass(frozen=True)
class CategoryConfig:
    """The post-hoc scene family rule (:func:`~geocon_core.scoring.category.categorize`, SPEC section 5)."""

    static_motion_px: float = 0.5
    """Median background displacement between adjacent frames (working px, largest scale) below which
    the camera counts as static."""
    static_rotation_deg: float = 1.0
    """First-last rotation (degrees) below which the camera counts as static."""
    complex_rotation_deg: float = 3.0
    """First-last rotation (degrees) from which a translating camera is C5 (complex)."""
    min_object_frames: int = 3
    """Frames a moving object must be tracked for to make a static scene C4."""
    min_matches: int = 50
    """Fewer median background matches per valid pair (largest scale) make the clip C6 (low texture)."""
    stress_ir: float = 0.8
    """A translating camera whose background IR stays below this is C6."""
    min_valid_share: float = 0.5
    """A smaller share of judgeable adjacent pairs with a valid background fit at the largest scale
    makes the clip C6."""


@dataclass(frozen=True)
class ScanConfig:
    """The threshold-sensitivity scan recorded next to each clip's scores."""

    tau_h_grid: tuple[float, ...] = (0.5, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0)
    """Symmetric transfer error thresholds (px) of the homography scan."""
    tau_f_grid: tuple[float, ...] = (0.025, 0.05, 0.075, 0.1, 0.15, 0.2, 0.3)
    """Normalised Sampson thresholds of the fundamental-matrix scan."""

    def __post_init__(self) -> None:
        if not self.tau_h_grid or not self.tau_f_grid or min(*self.tau_h_grid, *self.tau_f_grid) <= 0:
            raise ValueError("scans: the tau grids must be non-empty and positive")


@dataclass(frozen=True)
class MultiViewConfig:
    """One reconstruction per clip (:mod:`geocon_core.reconstruction.multiview`): long tracks, one bundle
    adjustment, and the background layers that drift against it. Off in ``paper`` and
    ``strict`` (beyond the paper's protocol)."""

    enabled: bool = False
    """Build the reconstruction and let a drifting layer fail the background."""
    track_side: int = 1280
    """Long side of the image the tracks are followed on, px (a smaller clip at its own size)."""
    max_tracks: int = 1200
    """Tracks kept alive at once."""
    min_distance: int = 8
    """Least distance between two tracks' corners, px of the tracking image."""
    fb_px: float = 0.5
    """A track is kept when tracking back lands within this many px (tracking image) of its start."""
    max_views: int = 32
    """Keyframes (spread evenly, first and last included) the reconstruction holds."""
    min_views: int = 4
    """A track seen at fewer registered keyframes is not judged."""
    min_tracks: int = 40
    """Fewer judged tracks: the clip cannot be judged."""
    min_init_tracks: int = 40
    """Tracks the first and the start keyframe must share (F)."""
    min_angle_deg: float = 1.0
    """Median triangulation angle of the start pair (F), degrees; points need half of it."""
    min_registered: float = 0.6
    """Share of keyframes that must be posed for the clip to be judged."""
    max_iterations: int = 30
    """Bundle adjustment iterations (Ceres)."""
    zoom_share: float = 0.01
    """H: a focal length per keyframe when the chained zoom moves the focal more than this share;
    one shared otherwise."""
    rotation_rounds: int = 3
    """H: rounds of adjusting the cameras with the points held, then the points (the mean of their rays)."""
    keep_factor: float = 3.0
    """A track joins the next adjustment when its residual is at most ``tau_px`` and this many
    times the median residual."""
    ba_tracks: int = 400
    """Tracks the bundle adjustment holds (the longest-lived of each cell of an 8x8 grid, in
    turn); every other track is triangulated with the adjusted cameras."""
    refine_intrinsics: bool = True
    """F: a second adjustment refines the shared focal length and one radial distortion term ..."""
    max_focal_ratio: float = 1.6
    """... kept when the focal stays within this factor of the prior's ..."""
    refine_gain: float = 0.1
    """... and the median residual of the adjusted tracks drops by at least this share (a focal
    the clip cannot pin down, a near-pure translation, wanders to fit noise)."""
    loss_px: float = 1.0
    """Scale of the Cauchy loss, source px."""
    tau_px: float = 1.5
    """A track is consistent with the reconstruction when its RMS residual is at most this, source px (MV-IR)."""
    max_floor_px: float = 0.4
    """The tracks outside any layer must fit the reconstruction this well (median residual, source
    px) for the clip to be judged: above it, noise (rolling shutter, lens, compression, tracking on
    low-resolution footage) hides a drift of a few pixels (measured on the tune half of the
    real-camera clips, see the validation report)."""
    max_outlier_share: float = 0.5
    """More inconsistent tracks than this share: the reconstruction failed, the clip cannot be judged."""
    track_drift_px: float = 1.0
    """A track drifts when the line fitted to its residual moves it this far over its life, source px ..."""
    slope_sigmas: float = 3.0
    """... and the line's slope is this many standard errors from zero."""
    layer_radius: float = 0.1
    """Inconsistent tracks closer than this share of the tracks' extent (diagonal) are neighbours."""
    layer_cosine: float = 0.7
    """Neighbours join one layer when their drifts' directions agree this well (cosine)."""
    layer_core_share: float = 0.5
    """A drifting track is a layer's core when at least this share of its neighbours drift with it;
    layers grow from cores (stray drifting tracks do not chain regions together)."""
    layer_min_tracks: int = 12
    """A layer holds at least this many tracks ..."""
    layer_min_share: float = 0.05
    """... and at least this share of the judged tracks ..."""
    drift_px: float = 3.0
    """... and its tracks' median slope carries it this far over the frames they span, source px."""

    def __post_init__(self) -> None:
        if self.max_views < 3 or self.min_views < 2 or self.max_tracks < 16 or self.track_side < 64:
            raise ValueError("multiview: max_views >= 3, min_views >= 2, max_tracks >= 16 and track_side >= 64")
        if not (self.tau_px > 0 and self.loss_px > 0 and self.drift_px >= 0 and 0 < self.max_outlier_share <= 1):
            raise ValueError("multiview: tau_px and loss_px positive, drift_px >= 0, max_outlier_share in (0, 1]")


@dataclass(frozen=True)
class SignalsConfig:
    """The clip's appearance readings (:mod:`geocon_core.signals`): dense flow on a small canvas at a
    few pairs spread over the clip. Off in ``paper`` and ``strict`` (beyond the paper's protocol)."""

    enabled: bool = False
    """Read them (they feed the clip score where a clip model is on)."""
    long_side: int = 384
    """Long side of the canvas the readings are made on, px (a smaller clip at its own size)."""
    gap: int = 4
    """Frames between the two frames of a pair the flow failures are read on."""
    max_pairs: int = 24
    """Pairs read at most, of each kind (``gap`` apart, neighbours), spread evenly over the clip."""
    flow_preset: str = "medium"
    """OpenCV DIS preset of the readings' flow."""
    fb_abs: float = 1.0
    """Constant part (px) of the forward-backward threshold ``fb_abs + fb_rel * |F|``."""
    fb_rel: float = 0.05
    """Share of the flow length added to the forward-backward threshold."""
    boundary_gradient: float = 0.3
    """A pixel is on a motion boundary where the flow's gradient exceeds this, px per px ..."""
    boundary_px: int = 3
    """... widened by this many px on every side."""
    texture_gradient: float = 8.0
    """Census distances are read on pixels whose mean gradient (5x5) is at least this, grey levels per px."""
    census_radius: int = 2
    """Half the side of the census window (2: 5x5, 24 comparisons)."""
    mover_px: float = 2.0
    """A pixel moves on its own when its flow departs from the frame's homography by more than this, px."""
    keep_px: float = 1.0
    """The keep reading: a background match is kept when its distance to its pair's fundamental
    matrix is at most this many px of a frame ``keep_width`` px wide (the GVGC study's 1 px at 854 px) ..."""
    keep_width: int = 854
    """... (the threshold scales with the pair's image width)."""
    keep_min_matches: int = 20
    """Pairs with fewer background matches are not read."""
    model: str = "clip_model.json"
    """The clip model (:mod:`geocon_core.signals.model`) whose score and threshold decide the verdict:
    a file of the package or a path ..."""
    decisive_shortfall: float = 6.0
    """A background that fails its report gate by more than this many times the gate's range (the
    reading ``shortfall``: IR below 0.79 or GE above 4.2 px at audit's gates) fails the clip whatever
    the model says; chosen on the tune half (docs: Scoring)."""
    drift_fails_with_background: bool = True
    """A drifting layer the multi-view check finds fails the clip when the background also fails its
    report gate (the reading ``shortfall`` above 0), whatever the model says; alone it is one
    reading among the others. Chosen on the tune half (docs: Scoring)."""
    model_sha256: str = SHIPPED_MODEL_DIGEST
    """... whose digest (:meth:`~geocon_core.signals.ClipModel.digest`) must be this one, so the
    configuration hash covers the model (empty: any model, for trying one out)."""

    def __post_init__(self) -> None:
        if self.flow_preset not in DIS_PRESET_NAMES:
            raise ValueError(f"unknown DIS preset {self.flow_preset!r}; valid: {', '.join(DIS_PRESET_NAMES)}")
        if self.long_side < 32 or self.gap < 1 or self.max_pairs < 1 or self.census_radius < 1:
            raise ValueError(
                "signals need long_side >= 32, gap >= 1, max_pairs >= 1 and census_radius >= 1, got "
                f"{self.long_side}, {self.gap}, {self.max_pairs}, {self.census_radius}"
            )
        if (
            min(self.fb_abs, self.fb_rel, self.boundary_gradient, self.texture_gradient, self.mover_px) < 0
            or self.boundary_px < 0
        ):
            raise ValueError("signals thresholds must be non-negative")


@dataclass(frozen=True)
class RegionsConfig:
    """Region-by-region readings over the whole clip (:mod:`geocon_core.regions`): long tracks over
    the whole frame, movers included, and per region its motion against the clip's one camera over
    long baselines. Off in ``paper`` and ``strict``; on in ``audit``, where the readings are
    reported and drawn (the clip model does not read them yet)."""

    enabled: bool = False
    """Follow the tracks and read the regions."""
    track_side: int = 960
    """Long side of the image the tracks are followed on, px (a smaller clip at its own size)."""
    max_tracks: int = 900
    """Tracks kept alive at once."""
    reseed_share: float = 0.8
    """Corners are found again when fewer than this share of ``max_tracks`` are alive."""
    min_distance: int = 10
    """Least distance between two tracks' corners, px of the tracking image."""
    fb_px: float = 0.5
    """A track is kept when tracking back lands within this many px (tracking image) of its start."""
    patch_px: int = 11
    """Side of the patch compared with the track's patch at birth, px of the tracking image."""
    keyframe_step: int = 4
    """The readings compare every ``keyframe_step``-th frame (and the last)."""
    min_baseline: int = 12
    """Pairs of keyframes read are at least this many frames apart (a slow failure needs time)."""
    min_tracks: int = 40
    """Fewer background tracks alive at both keyframes: the pair is not read."""
    min_region_tracks: int = 10
    """A region holds at least this many tracks."""
    radius: float = 0.12
    """A region: the tracks within this share of the frame diagonal of one track."""
    mover_radius_share: float = 0.5
    """On a mover, regions are this share of ``radius`` across."""
    ransac_px: float = 1.0
    """Inlier threshold of the camera fits, px of the working canvas."""
    ransac_iterations: int = 2000
    """Iterations of each camera fit (MAGSAC)."""
    h_share: float = 0.7
    """The homography is the camera when it explains this share of the background tracks within
    ``ransac_px``; otherwise the camera translates and a fundamental matrix is fitted."""
    mover_speed_px: float = 1.5
    """A track moving faster than this against the camera between two keyframes, px per frame, is
    a mover (nothing slower moves far over a clip)."""
    drift_px: float = 2.0
    """A region whose median residual exceeds the frame's by this many px drifts."""
    deformation_px: float = 2.0
    """A mover's region this many px off its own best homography deforms."""
    appearance_change: float = 0.3
    """A region whose median patch change (1 - NCC) exceeds the frame's by this much is redrawn."""
    breathing_px: float = 2.0
    """A residual field whose regions' 90th percentile reaches this many px breathes."""


@dataclass(frozen=True)
class RewardConfig:
    """A reward for training loops (:mod:`geocon_core.reward`): how a clip's frames are sampled
    before the ``reward`` preset scores them, the guards that make a clip "cannot judge" before
    it could be rewarded for doing nothing, and the noise a preference pair must clear."""

    max_frames: int = 32
    """At most this many frames, sampled evenly over the clip (first and last kept)."""
    guard_side: int = 480
    """Long side of the grey image the guards read, px (a smaller clip at its own size)."""
    min_motion_px: float = 2.0
    """Too little motion: the 90th percentile of the tracked corners' displacement from the first
    frame, at its largest over the clip, below this (px of the 854-px canvas). A frozen or nearly
    static clip fits any geometry perfectly and must never win."""
    max_repeated_share: float = 0.25
    """Repeated frames (a slideshow, a slowed copy): more than this share of the frame steps
    repeat the frame before."""
    min_corners: int = 60
    """Too little texture: fewer corners than this on the first frame (guard image)."""
    corner_quality: float = 0.01
    """Corner quality level of the texture guard and the motion tracks (OpenCV's qualityLevel)."""
    min_sharpness: float = 8.0
    """Too blurred: the median over sampled frames of the variance of the Laplacian of the grey
    guard image below this."""
    soft_px: float = 1.0
    """The reward's scale: each background match weighs ``1 / (1 + (r / soft_px)^2)`` (``r`` its
    residual to the pair's model, px of the canvas), so a residual of a fraction of a pixel
    counts, where an inlier ratio at a threshold saturates at 1 on most real clips and ties.
    0: the inlier ratio at the preset's threshold."""
    reading: str = "windows"
    """What the score averages: ``windows`` (:mod:`geocon_core.reward.windows`: corners seeded anew
    every ``window_step`` frames, tracked ``window`` frame steps, each window's soft share against
    one model of the gate's family; every track counts) or ``pairs`` (the soft share of the
    preset's record, per frame pair, movers masked)."""
    canvas: tuple[int, int] = (854, 480)
    """The windows' canvas (w, h): frames are scaled down to fit it, never up; a portrait clip
    fits it turned."""
    window: int = 4
    """Frame steps (of the sampled frames) a window's tracks span."""
    window_step: int = 2
    """A window starts every this many sampled frames."""
    window_corners: int = 1000
    """At most this many corners seeded per window (OpenCV's maxCorners)."""
    window_quality: float = 0.005
    """Corner quality level of the windows' seeds (OpenCV's qualityLevel)."""
    window_spacing: int = 6
    """Least distance between two seeds, px of the canvas."""
    window_lk_side: int = 21
    """Side of the Lucas-Kanade window, px."""
    window_lk_levels: int = 3
    """Pyramid levels above the canvas the tracker uses."""
    window_fb_px: float = 0.5
    """A track survives a step when tracking it back lands within this of where it was, px."""
    window_fit_px: float = 1.0
    """Threshold of the window's robust fit (MAGSAC), px of the canvas."""
    window_min_tracks: int = 30
    """A window with fewer surviving tracks is left out."""
    window_models: str = "both"
    """The model each window's tracks are read against: ``both`` (the mean of the soft shares
    under a homography and under a fundamental matrix), ``H``, ``F``, or ``gate`` (the family the
    preset's translation gate chose for the clip). See :mod:`geocon_core.reward.windows`."""
    judge_cuts: bool = False
    """A clip with a hard cut or a cross-fade is judged; False: it cannot be judged (a cut makes
    two scenes, and a generator rewarded on it learns to cut)."""
    bootstrap: int = 400
    """Resamples of the frame pairs behind the score's interval (seeded)."""
    level: float = 0.95
    """Level of the score's interval and of a pair's margin."""
    seed: int = 0
    """Seed of the bootstrap."""

    def __post_init__(self) -> None:
        if self.max_frames < 2:
            raise ValueError(f"max_frames must be at least 2, got {self.max_frames}")
        if not 0.0 < self.level < 1.0:
            raise ValueError(f"level must lie in (0, 1), got {self.level}")
        if self.bootstrap < 50:
            raise ValueError(f"bootstrap needs at least 50 resamples, got {self.bootstrap}")
        if self.reading not in ("windows", "pairs"):
            raise ValueError(f"reading must be 'windows' or 'pairs', got {self.reading!r}")
        if self.window < 1 or self.window_step < 1:
            raise ValueError(f"window and window_step must be at least 1, got {self.window} and {self.window_step}")
        if self.window_models not in ("both", "H", "F", "gate"):
            raise ValueError(f"window_models must be 'both', 'H', 'F' or 'gate', got {self.window_models!r}")
        if self.reading == "windows" and self.soft_px <= 0.0:
            raise ValueError("the windows reading needs soft_px > 0")
