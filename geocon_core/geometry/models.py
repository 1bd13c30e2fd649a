"""Background models per SPEC section 3: homography (H) with the symmetric transfer error and
fundamental matrix (F) with the Sampson distance in Hartley-normalised coordinates.

OpenCV's USAC (seeded MAGSAC++ for H, the fixed-state 8-point preset for F) only *proposes* a
model; the model is then refined on
its inliers, and the reported inlier set is exactly ``{i : r_i <= tau}`` under the paper's
residual for the final model. Residuals are rounded to float32 before anything is computed
from them, so re-gating the stored residuals reproduces IR and GE exactly.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Literal

import cv2
import numpy as np

from .twoview import sampson_distance, symmetric_transfer_error, to_homogeneous

__all__ = [
    "usac_params",
    "ModelFit",
    "fit_homography",
    "fit_fundamental",
    "hartley_normalisation",
    "inlier_mask",
    "inlier_stats",
    "independent_motion",
    "with_independent",
    "segment_order",
    "segment_inlier_stats",
    "FamilySpec",
    "FAMILIES",
    "family_spec",
    "PairFits",
]

Family = Literal["H", "F"]


@dataclass(frozen=True, eq=False)
class ModelFit:
    """One robust model fit on one pair's correspondences (N matches).

    model: (3, 3) ``H_2from1`` or ``F_21`` in pixel coordinates of the scale, or None.
    residuals: (N,) float32 residual under the family's inlier rule: H: symmetric transfer
        error (px); F: Sampson distance in Hartley-normalised units.
    residuals_px: (N,) float32 residual in pixels (H: same as ``residuals``; F: Sampson
        distance of the denormalised F on pixel coordinates).
    inliers: (N,) bool, exactly ``residuals <= tau``.
    ir: inlier ratio (of the matches that are not ``independent``); ge: median of
        ``residuals_px`` over the inliers (px).
    tau_px: the pixel equivalent of ``tau`` (H: tau itself; F: tau divided by the geometric
        mean of the two images' Hartley scales).
    valid: False when the pair cannot be judged (``reason`` says why).
    """

    family: Family
    valid: bool
    reason: str | None
    model: np.ndarray | None
    residuals: np.ndarray
    residuals_px: np.ndarray
    inliers: np.ndarray
    ir: float | None
    ge: float | None
    tau: float
    tau_px: float | None
    independent: np.ndarray | None = None
    """(N,) bool: outliers that move on their own (:func:`independent_motion`), left out of
    ``ir`` (None: none were looked for)."""

    @property
    def n_inliers(self) -> int:
        return int(np.count_nonzero(self.inliers))

    @property
    def n_independent(self) -> int:
        return 0 if self.independent is None else int(np.count_nonzero(self.independent))


def inlier_mask(residuals: np.ndarray, tau: float) -> np.ndarray:
    """The inlier rule of the fits and of every re-gating: stored float32 residual <= ``tau``."""
    return residuals <= np.float32(tau)


def inlier_stats(
    residuals: np.ndarray, residuals_px: np.ndarray, tau: float, exclude: np.ndarray | None = None
) -> tuple[np.ndarray, float | None, float | None]:
    """Inlier mask (:func:`inlier_mask`), IR and GE from stored float32 residuals at threshold
    ``tau``; matches marked in ``exclude`` (independent motion) count neither as inliers nor in
    the ratio's denominator."""
    inl = inlier_mask(residuals, tau)
    n = residuals.shape[0]
    if exclude is not None:
        inl &= ~exclude
        n -= int(np.count_nonzero(exclude))
    if n <= 0:
        return inl, None, None
    k = int(np.count_nonzero(inl))
    ge = float(np.median(residuals_px[inl])) if k else None
    return inl, k / n, ge


def independent_motion(
    x: np.ndarray,
    residuals_px: np.ndarray,
    inliers: np.ndarray,
    *,
    neighbours: int,
    jump: float,
    floor_px: float = 0.05,
) -> np.ndarray:
    """(N,) bool: the outliers of a background fit that move on their own: a mover the object
    masks did not cover whole (SPEC section 2 leaves incomplete masks to the scorer).

    ``x``: (N, 2) positions in the first frame (px); ``residuals_px``: (N,) the family's residual
    in pixels; ``inliers``: (N,) the fit's inlier mask. An outlier is independent when its
    residual is at least ``jump`` times the median residual of its ``neighbours`` nearest inliers
    (at least ``floor_px``): the background around it fits the model, it does not, so a motion
    boundary lies between them. A background that bends (breathing, warping) fails smoothly: its
    outliers lie just past the threshold beside inliers almost as far off, are not independent,
    and count against the inlier ratio, as its inliers' spread counts in GE. Deterministic (exact
    nearest neighbours)."""
    out = ~inliers
    mask = np.zeros(len(x), bool)
    k = min(neighbours, int(np.count_nonzero(inliers)))
    if k < 1 or not out.any() or jump <= 0:
        return mask
    from scipy.spatial import cKDTree

    pts = np.asarray(x, np.float64)
    _, near = cKDTree(pts[inliers]).query(pts[out], k=k)
    local = np.median(residuals_px[inliers][np.reshape(near, (int(np.count_nonzero(out)), k))], axis=1)
    mask[np.flatnonzero(out)[residuals_px[out] >= jump * np.maximum(local, floor_px)]] = True
    return mask


def with_independent(fit: ModelFit, independent: np.ndarray, *, min_inliers: int, max_share: float) -> ModelFit:
    """``fit`` with the matches of ``independent`` left out of its inlier ratio. The pair cannot
    be judged (``independent_motion``) when more than ``max_share`` of its matches move on
    their own: the background left is not the scene's."""
    if fit.model is None:
        return fit
    inl, ir, ge = inlier_stats(fit.residuals, fit.residuals_px, fit.tau, exclude=independent)
    k = int(np.count_nonzero(inl))
    n = len(independent)
    valid: bool = k >= min_inliers
    reason: str | None = None if valid else "too_few_inliers"
    if n and np.count_nonzero(independent) > max_share * n:
        valid, reason = False, "independent_motion"
    return ModelFit(
        fit.family, valid, reason, fit.model, fit.residuals, fit.residuals_px, inl, ir, ge, fit.tau, fit.tau_px,
        independent,
    )  # fmt: skip


def segment_order(residuals_px: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """The permutation that sorts each pair's rows (``offsets[i]:offsets[i + 1]``) by
    ``residuals_px``, pairs kept in place (NaN last within a pair). Compute it once per clip and
    pass it to :func:`segment_inlier_stats` to re-gate at many thresholds."""
    n: np.ndarray = np.diff(np.asarray(offsets, dtype=np.int64))
    return np.lexsort((residuals_px, np.repeat(np.arange(len(n)), n)))


def segment_inlier_stats(
    residuals: np.ndarray,
    residuals_px: np.ndarray,
    offsets: np.ndarray,
    tau: float,
    *,
    order: np.ndarray | None = None,
    exclude: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`inlier_stats` of many pairs at once: the matches of pair ``i`` are rows
    ``offsets[i]:offsets[i + 1]``. Returns the inlier counts, the match counts and GE per pair
    (NaN where a pair has no inlier), equal to the per-pair results bit for bit (same float32
    inlier rule, same float32 median) without a Python loop over pairs. ``order`` is
    :func:`segment_order` of the same arrays (computed here when not given); ``exclude`` marks
    matches left out of both counts (independent motion, :func:`inlier_stats`)."""
    offsets = np.asarray(offsets, dtype=np.int64)
    n = np.diff(offsets)
    if order is None:
        order = segment_order(residuals_px, offsets)
    vals = residuals_px[order]
    inl = inlier_mask(residuals[order], tau)  # a permutation within pairs: counts per pair unchanged
    if exclude is not None:
        inl &= ~exclude[order]
        gone = np.concatenate(([0], np.cumsum(exclude, dtype=np.int64)))
        n = n - (gone[offsets[1:]] - gone[offsets[:-1]])
    cum = np.concatenate(([0], np.cumsum(inl, dtype=np.int64)))
    k = cum[offsets[1:]] - cum[offsets[:-1]]
    ge = np.full(len(n), np.nan)
    has = k > 0
    if not has.any():
        return k, n, ge
    rank = np.flatnonzero(inl)  # the inliers, each pair's sorted by residual
    start, kh = cum[offsets[:-1]][has], k[has]
    lo, hi = vals[rank[start + (kh - 1) // 2]], vals[rank[start + kh // 2]]
    mid = np.where(lo == hi, lo, (lo + hi) / vals.dtype.type(2))  # the two middle values' mean, as np.median takes it
    last = vals[rank[start + kh - 1]]  # NaN sorts last: a pair with a NaN inlier has a NaN median, as np.median gives
    ge[has] = np.where(np.isnan(last), np.nan, mid.astype(np.float64))
    return k, n, ge


def _failed(family: Family, reason: str, n: int, tau: float) -> ModelFit:
    z = np.full(n, np.inf, np.float32)
    return ModelFit(family, False, reason, None, z, z.copy(), np.zeros(n, bool), None, None, tau, None)


def usac_params(
    threshold: float,
    seed: int,
    iters: int,
    confidence: float,
    *,
    lo_method: int = cv2.LOCAL_OPTIM_SIGMA,
    polisher: int = cv2.MAGSAC,
) -> cv2.UsacParams:
    """Seeded, single-threaded OpenCV USAC settings (uniform sampling, MAGSAC++ scoring): the
    same input and seed give the same model."""
    p = cv2.UsacParams()
    p.threshold = float(threshold)
    p.confidence = float(confidence)
    p.maxIterations = int(iters)
    p.randomGeneratorState = int(seed) & 0x7FFFFFFF
    p.sampler = cv2.SAMPLING_UNIFORM
    p.score = cv2.SCORE_METHOD_MAGSAC
    p.loMethod = lo_method
    p.loIterations = 10
    p.loSampleSize = 14
    p.final_polisher = polisher
    p.final_polisher_iterations = 10
    p.isParallel = False
    return p


def _finish(
    family: Family,
    model: np.ndarray,
    res: np.ndarray,
    res_px: np.ndarray,
    tau: float,
    tau_px: float | None,
    min_inliers: int,
) -> ModelFit:
    inl, ir, ge = inlier_stats(res, res_px, tau)
    k = int(np.count_nonzero(inl))
    valid, reason = (True, None) if k >= min_inliers else (False, "too_few_inliers")
    return ModelFit(family, valid, reason, model, res, res_px, inl, ir, ge, tau, tau_px)


def fit_homography(
    x1: np.ndarray,
    x2: np.ndarray,
    *,
    tau: float = 2.0,
    min_inliers: int = 30,
    seed: int = 0,
    iters: int = 2000,
    confidence: float = 0.9999,
    refine_steps: int = 3,
) -> ModelFit:
    """Robust homography ``H_2from1`` from (N, 2) correspondences; inliers are matches with
    symmetric transfer error <= ``tau`` px."""
    n = x1.shape[0]
    if n < max(4, min_inliers):
        return _failed("H", "too_few_matches", n, tau)
    try:
        H, _ = cv2.findHomography(x1, x2, usac_params(tau, seed, iters, confidence))
    except cv2.error:  # USAC asserts on degenerate samples
        H = None
    if H is None or not np.isfinite(H).all() or abs(np.linalg.det(H)) < 1e-12:
        return _failed("H", "model_failed", n, tau)
    best = _h_residuals(H, x1, x2)
    best_k = int(np.count_nonzero(inlier_mask(best, tau)))
    for _ in range(refine_steps):  # least-squares refit on the inliers, kept while it helps
        inl = inlier_mask(best, tau)
        if np.count_nonzero(inl) < 8:
            break
        try:
            H_ref, _ = cv2.findHomography(x1[inl], x2[inl], 0)
        except cv2.error:
            break
        if H_ref is None or abs(np.linalg.det(H_ref)) < 1e-12:
            break
        res = _h_residuals(H_ref, x1, x2)
        k = int(np.count_nonzero(inlier_mask(res, tau)))
        if k < best_k or (k == best_k and np.median(res[res <= tau]) >= np.median(best[best <= tau])):
            break
        H, best, best_k = H_ref, res, k
    return _finish("H", H / H[2, 2], best, best, tau, tau, min_inliers)


def _h_residuals(H: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    r = symmetric_transfer_error(H, x1, x2)
    return np.where(np.isfinite(r), r, np.inf).astype(np.float32)


def hartley_normalisation(x: np.ndarray) -> np.ndarray:
    """Similarity T (3x3) moving the centroid of (N, 2) points to the origin with mean
    distance sqrt(2)."""
    c = x.mean(axis=0)
    d = np.linalg.norm(x - c, axis=1).mean()
    s = np.sqrt(2.0) / d if d > 0 else 1.0
    return np.array([[s, 0.0, -s * c[0]], [0.0, s, -s * c[1]], [0.0, 0.0, 1.0]])


def _rank2(F: np.ndarray) -> np.ndarray:
    U, S, Vt = np.linalg.svd(F)
    S[2] = 0.0
    F = U @ np.diag(S) @ Vt
    return F / np.linalg.norm(F)


def _eight_point(x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    """Linear 8-point F on already-normalised points, rank 2 enforced."""
    h1, h2 = to_homogeneous(x1), to_homogeneous(x2)
    A = (h2[:, :, None] * h1[:, None, :]).reshape(-1, 9)
    _, _, Vt = np.linalg.svd(A, full_matrices=False)
    return _rank2(Vt[-1].reshape(3, 3))


def fit_fundamental(
    x1: np.ndarray,
    x2: np.ndarray,
    *,
    tau: float = 0.1,
    min_inliers: int = 30,
    iters: int = 2000,
    confidence: float = 0.9999,
    refine_steps: int = 3,
    proposal_px: float = 1.0,
    seed: int = 0,
) -> ModelFit:
    """Robust fundamental matrix ``F_21`` from (N, 2) pixel correspondences. Each image's points
    are Hartley-normalised; inliers have normalised Sampson distance <= ``tau``; GE is the
    median Sampson distance in pixels of the denormalised ``F = T2^T F_hat T1``. USAC proposes
    the model in pixels with threshold ``proposal_px``, using OpenCV's 8-point preset: its
    random state is fixed inside OpenCV (so results are reproducible without a seed), and
    unlike the 7-point configuration it does not stall for seconds on degenerate pairs (a
    static background, where every match lies on one homography). ``seed`` is accepted so both
    families' fitters share one signature (:data:`FAMILIES`) and is unused."""
    n = x1.shape[0]
    if n < max(8, min_inliers):
        return _failed("F", "too_few_matches", n, tau)
    T1, T2 = hartley_normalisation(x1), hartley_normalisation(x2)
    n1 = (to_homogeneous(x1) @ T1.T)[:, :2]
    n2 = (to_homogeneous(x2) @ T2.T)[:, :2]
    # USAC proposes in pixels (its scoring assumes pixel-scale coordinates); the paper's rule is
    # then applied to the proposal expressed in normalised coordinates.
    try:
        F_px, _ = cv2.findFundamentalMat(x1, x2, cv2.USAC_FM_8PTS, proposal_px, confidence, iters)
    except cv2.error:  # USAC asserts on degenerate samples
        F_px = None
    if F_px is None or F_px.shape != (3, 3) or not np.isfinite(F_px).all():
        return _failed("F", "model_failed", n, tau)
    F_hat = _rank2(np.linalg.inv(T2).T @ F_px @ np.linalg.inv(T1))
    best = sampson_distance(F_hat, n1, n2).astype(np.float32)
    best_k = int(np.count_nonzero(inlier_mask(best, tau)))
    for _ in range(refine_steps):  # 8-point refit on the inliers, kept only if it gains inliers
        inl = inlier_mask(best, tau)
        if np.count_nonzero(inl) < 8:
            break
        F_ref = _eight_point(n1[inl], n2[inl])
        res = sampson_distance(F_ref, n1, n2).astype(np.float32)
        k = int(np.count_nonzero(inlier_mask(res, tau)))
        if k <= best_k:
            break
        F_hat, best, best_k = F_ref, res, k
    F = T2.T @ F_hat @ T1
    F /= np.linalg.norm(F)
    res_px = sampson_distance(F, x1, x2).astype(np.float32)
    tau_px = tau / float(np.sqrt(T1[0, 0] * T2[0, 0]))
    return _finish("F", F, best, res_px, tau, tau_px, min_inliers)


@dataclass(frozen=True)
class FamilySpec:
    """Where one background family's rule lives: ``threshold`` names its inlier threshold in
    :class:`~geocon_core.config.ScoreConfig` (and re-gating ``Thresholds``), ``fit`` is its robust
    fitter, ``residual`` / ``residual_px`` / ``inliers`` / ``independent`` name its columns of the
    record's ``MatchArrays`` (the inlier rule's residual, the residual in pixels, the fit's inlier
    mask, the outliers that move on their own), and ``attr`` names its fit on a pair
    (``PairRecord.h`` / ``.f``, :attr:`PairFits.h` / ``.f``)."""

    name: Family
    threshold: str
    fit: Callable[..., ModelFit]
    residual: str
    residual_px: str
    inliers: str
    attr: str
    independent: str


FAMILIES: dict[str, FamilySpec] = {
    "H": FamilySpec("H", "tau_h", fit_homography, "h_res", "h_res", "h_inl", "h", "h_ind"),
    "F": FamilySpec("F", "tau_f", fit_fundamental, "f_res", "f_res_px", "f_inl", "f", "f_ind"),
}
"""The background families, in scoring order."""


def family_spec(family: str) -> FamilySpec:
    """The :class:`FamilySpec` of ``family``; raises ValueError naming the valid families."""
    try:
        return FAMILIES[family]
    except (KeyError, TypeError):
        valid = " or ".join(repr(name) for name in FAMILIES)
        raise ValueError(f"family must be {valid}, got {family!r}") from None


@dataclass(frozen=True, eq=False)
class PairFits:
    """Both families' fits on one frame pair ``(t0, t1)`` at one scale: ``x1``/``x2`` are the (N, 2)
    float32 matches (pixels of the scale); ``skip`` is why the pair was not scored (a cut, a
    duplicated frame), and then there are no matches and ``h``/``f`` are None."""

    t0: int
    t1: int
    gap: int
    scale: float
    skip: str | None
    x1: np.ndarray
    x2: np.ndarray
    h: ModelFit | None
    f: ModelFit | None
    n_gross: int = 0
    """Matches dropped before the fits as gross mismatches (``ScoreConfig.gross_match_share``)."""

    def fit(self, family: str) -> ModelFit | None:
        """This pair's fit of ``family`` (None when the pair was skipped)."""
        fit: ModelFit | None = getattr(self, family_spec(family).attr)
        return fit
