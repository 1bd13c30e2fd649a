"""Foreground rigidity: AdaDFRC-W2 (SPEC section 4), pure functions on numpy arrays.

For one object in one frame pair (t, t+1) the dense forward flow over the object's mask is
summarised on an N x N grid of cells, a weighted affine motion model is fitted to the cell
vectors, and the weighted mean squared residual ``D_t`` (px^2) is the paper's AdaDFRC score.
The exact squared Wasserstein-2 transport cost between the weighted predicted and observed cell
vector sets is reported alongside (``adadfrc_w2``); it never exceeds ``D_t``.

Decisions, made exact:

- **Coordinates.** Pixel centres sit at integer coordinates, ``x`` = column and ``y`` = row of the
  region passed in, plus ``origin = (x0, y0)`` so that positions are frame coordinates when the
  region is a crop (the convention of :mod:`geocon_core.geometry`).
- **Grid.** The N x N grid is laid over the bounding box of the *mask* ``M_t^k`` (SPEC: "bounding
  box of M_t^k"), not of the reliable pixels, so that occlusion does not move the grid. With the
  box spanning rows ``r0..r0+H-1`` and columns ``c0..c0+W-1``, pixel ``(r, c)`` lies in cell
  ``i = floor((r - r0) * N / H)``, ``j = floor((c - c0) * N / W)`` (integer arithmetic): cell edges
  at equal fractions of the box and every pixel in exactly one cell. Boxes smaller than N pixels
  simply leave some cells empty.
- **Reliable pixels.** A pixel contributes when it is in the mask, in ``reliable`` (forward-backward
  consistent; ``None`` means all) and its flow is finite (non-finite flow is treated as unreliable).
  Cells with no contributing pixel are dropped; ``w_ij`` is the number of contributing pixels.
- **Per-cell "median flow" is a medoid.** The component-wise median ``m`` of the cell's contributing
  flow vectors is computed (``numpy.median``), and the contributing pixel whose flow is nearest to
  ``m`` (Euclidean; ties broken by the lowest flat index in the region, i.e. row-major first) is
  the cell's representative: ``v_ij`` is *its* flow and ``p_ij`` is *its* position. Pairing a
  component-wise median flow with the cell centroid would not do: the median of an affine function
  over an irregular (masked) cell is in general not its value at the centroid, so a perfectly
  rigid (affine) motion would score ``D_t > 0``. With the medoid, ``v_ij`` is a sample of the
  field at ``p_ij``, so an exactly affine field gives ``v_ij = M p_ij + b`` and ``D_t = 0`` to
  float precision at every grid size, while keeping the median's robustness to outlier pixels.
- **Affine fit.** ``v_pred(p) = M p + b`` with ``M = A - I``, six parameters fitted by weighted
  least squares (positions centred and scaled internally for conditioning). Rank-deficient designs
  (all cells collinear, too few cells) take the minimum-norm ``lstsq`` solution and are still
  scored; a result is flagged ``"degenerate_fit"`` only when the fit or score is not finite.
- **Scores.** ``D_t = sum w ||v_pred - v||^2 / sum w``. ``w2`` is the exact discrete optimal transport
  cost ``min_pi sum pi_ab ||pred_a - obs_b||^2 / sum w`` over couplings with both marginals ``w``:
  solved by POT's network simplex (``ot.emd2``, exact; on the 5-64 cells of a grid it agrees with a
  general LP solver (HiGHS) to 1e-15 relative and is about 15x faster). The identity coupling is
  feasible, so ``w2 <= D_t`` mathematically; the reported value is clipped into ``[0, D_t]`` to
  remove round-off.
- **Object scores.** ``S`` is the mean of the valid ``D_t`` of a track and ``AdaP90`` their 0.9
  quantile with numpy's default (``"linear"``, type 7) interpolation.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Collection, Sequence

import cv2
import numpy as np

from ..record import ObjectEntry, ObjectScaleSummary, ObjectSummary

__all__ = [
    "CellVectors",
    "RigidityResult",
    "adadfrc_pair",
    "weighted_affine_fit",
    "refine_object_mask",
    "mask_interior",
    "weighted_mse",
    "w2_cost",
    "object_scores",
    "ObjectPairScore",
    "object_summaries",
    "mask_jumps",
    "MASK_JUMP",
]

_EMD_MAX_ITER = 1_000_000
"""Network-simplex iteration cap of ``ot.emd2``; a 64-cell problem needs a few hundred, and a
result that hits the cap raises instead of being used."""


@dataclass(frozen=True, eq=False)
class CellVectors:
    """Per-cell data of one object in one frame pair, C non-empty cells (row-major cell order).

    cells: (C, 2) int64 grid indices (row i, col j) in the N x N grid over the object's box.
    positions: (C, 2) float64 p_ij, pixel position (x, y) where the cell's flow vector was observed
        (the cell's medoid pixel, frame coordinates).
    observed: (C, 2) float64 v_ij, the cell's median (medoid) flow (px).
    predicted: (C, 2) float64 v_pred(p_ij) from the weighted affine fit (px).
    weights: (C,) float64 w_ij = number of reliable object pixels in the cell.
    """

    cells: np.ndarray
    positions: np.ndarray
    observed: np.ndarray
    predicted: np.ndarray
    weights: np.ndarray

    def __post_init__(self) -> None:
        c = len(self.weights)
        shapes = {"cells": (c, 2), "positions": (c, 2), "observed": (c, 2), "predicted": (c, 2), "weights": (c,)}
        for name, shape in shapes.items():
            if np.shape(getattr(self, name)) != shape:
                raise ValueError(f"CellVectors.{name} must have shape {shape}, got {np.shape(getattr(self, name))}")

    @property
    def num_cells(self) -> int:
        return len(self.weights)


@dataclass(frozen=True, eq=False)
class RigidityResult:
    """AdaDFRC-W2 of one object in one frame pair.

    valid: whether the pair was scored.
    reason: when not valid, one of ``"empty_mask"``, ``"too_few_cells"``, ``"degenerate_fit"``.
    d_t: weighted MSE (px^2) of the affine fit, the paper's AdaDFRC score for this pair.
    w2: exact squared Wasserstein-2 transport cost (px^2) between the weighted predicted and observed
        cell vector sets; always ``<= d_t``.
    affine: (2, 3) ``[M | b]`` with ``v_pred(p) = M p + b`` (``M = A - I``), frame coordinates.
    cells: the per-cell vectors of a valid result.
    n_pixels: reliable object pixels used (in the mask, reliable, finite flow).
    ``d_t``, ``w2``, ``affine`` and ``cells`` are all None exactly when ``valid`` is False.
    """

    valid: bool
    reason: str | None
    d_t: float | None
    w2: float | None
    affine: np.ndarray | None
    cells: CellVectors | None
    n_pixels: int


def _invalid(reason: str, n_pixels: int) -> RigidityResult:
    return RigidityResult(
        valid=False, reason=reason, d_t=None, w2=None, affine=None, cells=None, n_pixels=int(n_pixels)
    )


def _cell_arrays(
    a: np.ndarray, b: np.ndarray, weights: np.ndarray, names: tuple[str, str]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    w = np.asarray(weights, np.float64)
    if w.ndim != 1 or len(w) == 0:
        raise ValueError(f"weights must be a non-empty 1-D array, got shape {w.shape}")
    for name, arr in zip(names, (a, b), strict=True):
        if arr.shape != (len(w), 2):
            raise ValueError(f"{name} must have shape ({len(w)}, 2), got {arr.shape}")
    if not np.all(np.isfinite(w)) or np.any(w < 0) or not w.sum() > 0:
        raise ValueError("weights must be finite, non-negative and not all zero")
    return a, b, w


def weighted_affine_fit(positions: np.ndarray, vectors: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Weighted least-squares affine model ``v = M p + b`` (6 parameters).

    positions, vectors: (C, 2); weights: (C,) non-negative, not all zero. Returns (2, 3) ``[M | b]``.
    Minimises ``sum w ||M p + b - v||^2``; a rank-deficient design (collinear positions, C < 3) gets
    the minimum-norm solution (in centred, scaled coordinates). Non-finite inputs give a non-finite
    result, not an exception.
    """
    p, v, w = _cell_arrays(positions, vectors, weights, ("positions", "vectors"))
    total = w.sum()
    mu = (w[:, None] * p).sum(axis=0) / total
    pc = p - mu
    scale = math.sqrt(float((w * (pc * pc).sum(axis=1)).sum() / total))
    if not (scale > 0 and math.isfinite(scale)):
        scale = 1.0
    sw = np.sqrt(w)
    design = np.column_stack([pc / scale, np.ones(len(w))]) * sw[:, None]
    target = v * sw[:, None]
    if not (np.all(np.isfinite(design)) and np.all(np.isfinite(target))):
        return np.full((2, 3), np.nan)
    sol, *_ = np.linalg.lstsq(design, target, rcond=None)  # (3, 2): rows x', y', 1
    m = sol[:2].T / scale
    b = sol[2] - m @ mu
    return np.column_stack([m, b])


def weighted_mse(predicted: np.ndarray, observed: np.ndarray, weights: np.ndarray) -> float:
    """``sum w ||pred - obs||^2 / sum w`` (px^2)."""
    p, o, w = _cell_arrays(predicted, observed, weights, ("predicted", "observed"))
    return float((w * ((p - o) ** 2).sum(axis=1)).sum() / w.sum())


def w2_cost(predicted: np.ndarray, observed: np.ndarray, weights: np.ndarray) -> float:
    """Exact squared Wasserstein-2 cost between ``{(pred_a, w_a)}`` and ``{(obs_b, w_b)}`` in R^2.

    ``min_pi sum_ab pi_ab ||pred_a - obs_b||^2 / sum w`` over couplings ``pi >= 0`` with row and
    column sums ``w``, solved exactly by POT's network simplex (``ot.emd2``). The result is clipped
    into ``[0, weighted_mse]`` (the identity coupling is feasible, so this only removes round-off).
    """
    p, o, w = _cell_arrays(predicted, observed, weights, ("predicted", "observed"))
    keep = w > 0
    p, o, w = p[keep], o[keep], w[keep]
    total = w.sum()
    cost = ((p[:, None, :] - o[None, :, :]) ** 2).sum(axis=2)
    identity = float((w * np.diag(cost)).sum() / total)
    if not math.isfinite(identity):
        return identity
    if identity == 0.0 or len(w) == 1:
        return identity
    value = _transport(cost, w / total)
    return min(max(value, 0.0), identity)


POT_BACKENDS_OFF = (
    "POT_BACKEND_DISABLE_PYTORCH",
    "POT_BACKEND_DISABLE_JAX",
    "POT_BACKEND_DISABLE_CUPY",
    "POT_BACKEND_DISABLE_TENSORFLOW",
)
"""POT's switches for its optional array backends. AdaDFRC hands POT NumPy arrays; with its
backends on, importing POT imports every array library it finds (PyTorch: about 180 MiB of
memory and two seconds), so the scorer switches them off unless the environment says otherwise."""


def quiet_pot_backends() -> None:
    """Set :data:`POT_BACKENDS_OFF` in the environment, where not already set, before POT is imported."""
    for key in POT_BACKENDS_OFF:
        os.environ.setdefault(key, "1")


def _transport(cost: np.ndarray, marginal: np.ndarray) -> float:
    """Optimal transport value with equal row and column marginals (summing to 1)."""
    quiet_pot_backends()
    import ot  # POT: imported where used (about 1 s on first import)

    value, log = ot.emd2(marginal, marginal, np.ascontiguousarray(cost), numItermax=_EMD_MAX_ITER, log=True)
    if log.get("result_code") != 1:  # 1: optimal; anything else (iteration cap, unbounded) is a bug
        raise RuntimeError(f"optimal transport failed: {log.get('warning')}")
    return float(value)


def refine_object_mask(
    flow: np.ndarray, mask: np.ndarray, others: np.ndarray, *, min_keep: float = 0.5, iters: int = 2
) -> np.ndarray:
    """The object's pixels in ``mask`` (h, w) bool whose flow the object's own motion explains
    better than the background's: a two-layer assignment on one pair's flow (h, w, 2).

    The object's motion is an affine flow fitted to its mask pixels (refitted ``iters`` times on
    the pixels kept), the background's an affine flow fitted to the region's pixels outside
    ``mask`` and ``others`` (other objects); a pixel stays when its flow is closer to the object's
    prediction than to the background's. A motion segmentation's mask spills over the object's
    edge (flow is smooth across it), and the spilled background pixels, which move with the
    background, would read as a deformation of the object. When fewer than ``min_keep`` of the mask
    would stay (an object that moves like its background cannot be told apart by motion), or
    either layer has fewer than 20 pixels, the mask is returned unchanged."""
    mask = np.asarray(mask, bool)
    bg = ~mask & ~np.asarray(others, bool)
    finite = np.isfinite(flow).all(axis=2)
    mask_f, bg = mask & finite, bg & finite
    if mask_f.sum() < 20 or bg.sum() < 20:
        return mask
    ys, xs = np.nonzero(mask_f)
    pos = np.column_stack([xs, ys]).astype(np.float64)
    vec = flow[ys, xs].astype(np.float64)
    by, bx = np.nonzero(bg)
    bpos = np.column_stack([bx, by]).astype(np.float64)
    background = weighted_affine_fit(bpos, flow[by, bx].astype(np.float64), np.ones(len(bx)))
    d_bg = np.linalg.norm(vec - (pos @ background[:, :2].T + background[:, 2]), axis=1)
    keep = np.ones(len(xs), bool)
    for _ in range(max(1, iters)):
        obj = weighted_affine_fit(pos[keep], vec[keep], np.ones(int(keep.sum())))
        keep = np.linalg.norm(vec - (pos @ obj[:, :2].T + obj[:, 2]), axis=1) < d_bg
        if not np.isfinite(obj).all() or keep.sum() < max(20, min_keep * len(xs)):
            return mask
    out = np.zeros_like(mask)
    out[ys[keep], xs[keep]] = True
    return out


def mask_interior(mask: np.ndarray, margin: int) -> np.ndarray:
    """The pixels of ``mask`` (H, W bool) farther than ``margin`` pixels from its edge: those
    whose disc of radius ``margin`` lies inside the mask (pixels outside the array count as
    outside the mask). ``margin = 0`` returns the mask."""
    m = np.asarray(mask, dtype=bool)
    if margin <= 0:
        return m.copy()
    size = 2 * int(margin) + 1
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))
    return cv2.erode(m.astype(np.uint8), kernel, borderType=cv2.BORDER_CONSTANT, borderValue=0) > 0


def adadfrc_pair(
    flow: np.ndarray,
    mask: np.ndarray,
    reliable: np.ndarray | None = None,
    *,
    grid: int = 8,
    min_cells: int = 3,
    origin: tuple[float, float] = (0.0, 0.0),
) -> RigidityResult:
    """AdaDFRC-W2 of one object over one frame pair.

    flow: (h, w, 2) forward flow ``I_t -> I_{t+1}`` (px, (dx, dy)) over a region; mask: (h, w) object
    pixels ``M_t^k`` in the same region; reliable: (h, w) forward-backward-consistent pixels (None =
    all). The N x N grid (``grid``) is laid over the bounding box of ``mask``; see the module
    docstring for the cells, medoids and scores. ``origin`` (x0, y0) is added to pixel coordinates.
    Data problems return an invalid result ("empty_mask", "too_few_cells", "degenerate_fit");
    malformed arguments (shapes, grid < 1, min_cells < 1) raise ValueError.
    """
    flow = np.asarray(flow)
    mask = np.asarray(mask).astype(bool, copy=False)
    if flow.ndim != 3 or flow.shape[2] != 2:
        raise ValueError(f"flow must have shape (h, w, 2), got {flow.shape}")
    if mask.shape != flow.shape[:2]:
        raise ValueError(f"mask shape {mask.shape} does not match flow {flow.shape[:2]}")
    if reliable is not None:
        reliable = np.asarray(reliable).astype(bool, copy=False)
        if reliable.shape != mask.shape:
            raise ValueError(f"reliable shape {reliable.shape} does not match mask {mask.shape}")
    grid = int(grid)
    if grid < 1 or int(min_cells) < 1:
        raise ValueError(f"grid and min_cells must be >= 1, got grid={grid}, min_cells={min_cells}")
    x0, y0 = float(origin[0]), float(origin[1])

    ys, xs = np.nonzero(mask)
    if ys.size == 0:
        return _invalid("empty_mask", 0)
    r0, c0 = int(ys.min()), int(xs.min())
    box_h, box_w = int(ys.max()) - r0 + 1, int(xs.max()) - c0 + 1

    width = mask.shape[1]
    flow2 = flow.reshape(-1, 2)
    use = mask.ravel().copy()
    if reliable is not None:
        use &= reliable.ravel()
    idx = np.flatnonzero(use)  # ascending flat index
    f = flow2[idx].astype(np.float64)
    finite = np.isfinite(f).all(axis=1)
    idx, f = idx[finite], f[finite]
    n_pixels = int(idx.size)
    if n_pixels == 0:
        return _invalid("too_few_cells", 0)

    r, c = np.divmod(idx, width)
    ci = ((r - r0) * grid) // box_h
    cj = ((c - c0) * grid) // box_w
    cell_id = ci * grid + cj
    order = np.argsort(cell_id, kind="stable")  # groups by cell, ascending flat index inside
    cell_sorted = cell_id[order]
    ids, starts, counts = np.unique(cell_sorted, return_index=True, return_counts=True)
    n_cells = len(ids)

    pick = np.empty(n_cells, np.int64)  # position in idx / f of each cell's medoid
    with np.errstate(over="ignore", invalid="ignore"):  # absurd flows overflow here; caught below
        for k, (s, n) in enumerate(zip(starts, counts, strict=True)):
            members = order[s : s + n]
            fk = f[members]
            med = np.median(fk, axis=0)
            d = ((fk - med) ** 2).sum(axis=1)
            pick[k] = members[int(np.argmin(d))]  # first minimum = lowest flat index
    positions = np.column_stack([c[pick] + x0, r[pick] + y0]).astype(np.float64)
    observed = f[pick]
    weights = counts.astype(np.float64)
    cells_ij = np.column_stack([ids // grid, ids % grid]).astype(np.int64)

    if n_cells < int(min_cells):
        return _invalid("too_few_cells", n_pixels)

    with np.errstate(all="ignore"):
        affine = weighted_affine_fit(positions, observed, weights)
        predicted = positions @ affine[:, :2].T + affine[:, 2]
        cv = CellVectors(cells_ij, positions, observed, predicted, weights)
        if not (np.all(np.isfinite(affine)) and np.all(np.isfinite(predicted))):
            return _invalid("degenerate_fit", n_pixels)
        d_t = weighted_mse(predicted, observed, weights)
        if not math.isfinite(d_t):
            return _invalid("degenerate_fit", n_pixels)
        w2 = w2_cost(predicted, observed, weights)
        if not math.isfinite(w2):
            return _invalid("degenerate_fit", n_pixels)
    return RigidityResult(valid=True, reason=None, d_t=d_t, w2=min(w2, d_t), affine=affine, cells=cv, n_pixels=n_pixels)


def object_scores(d_ts: Sequence[float]) -> tuple[float, float]:
    """``(S, AdaP90)`` of one object's track: the mean of its per-pair ``D_t`` and their 0.9 quantile
    (``numpy.quantile`` default "linear" interpolation). Raises ValueError on an empty sequence or
    non-finite values (pass only the ``d_t`` of valid pairs)."""
    d = np.asarray(list(d_ts), np.float64).ravel()
    if d.size == 0:
        raise ValueError("object_scores needs at least one D_t (the object has no valid pair)")
    if not np.all(np.isfinite(d)):
        raise ValueError("object_scores got a non-finite D_t; pass only valid pairs' scores")
    return float(d.mean()), float(np.quantile(d, 0.9))


@dataclass(frozen=True, eq=False)
class ObjectPairScore:
    """AdaDFRC of object ``object_id`` of frame ``t0`` on the pair ``(t0, t1)`` at one scale: the
    :class:`RigidityResult` when the pair was scored, else ``skip``, why it was not (the pair
    crosses a cut, the object's mask is empty at this scale)."""

    object_id: int
    t0: int
    t1: int
    scale: float
    result: RigidityResult | None
    skip: str | None = None

    @property
    def key(self) -> tuple[int, int, float]:
        """The record's order of object entries: object, then frame, then scale."""
        return (self.object_id, self.t0, self.scale)


MASK_JUMP = "mask_jump"
"""Skip reason of an object pair whose mask area departs from its track's neighbours
(:func:`mask_jumps`)."""


def mask_jumps(shares: dict[int, float], *, window: int, max_jump: float) -> set[int]:
    """Frames of one track whose mask is implausible: the mask's area (``shares``: frame -> share
    of the content) departs from the median of up to ``window`` of the track's frames on each side
    by more than the factor ``1 + max_jump`` (either way). A rigid object changes its image area
    slowly; a mask that swells by a neighbour's region, or loses half the object, for one frame is
    a segmentation glitch, and its flow would read as deformation. ``max_jump <= 0`` turns the
    rule off; a frame needs two neighbours to be judged."""
    if max_jump <= 0 or window < 1:
        return set()
    frames = sorted(shares)
    limit = 1.0 + max_jump
    out = set()
    for i, t in enumerate(frames):
        around = frames[max(0, i - window) : i] + frames[i + 1 : i + 1 + window]
        if len(around) < 2:
            continue
        ref = float(np.median([shares[k] for k in around]))
        area = shares[t]
        if ref > 0 and (area > limit * ref or area * limit < ref):
            out.add(t)
    return out


def _scale_summary(mine: list[ObjectEntry], s: float, jumps: Collection[int] = ()) -> ObjectScaleSummary:
    valid: list[ObjectEntry] = []
    skipped: dict[str, int] = {}
    for e in (e for e in mine if e.scale == s):
        if not e.valid:
            skipped[e.reason or "invalid"] = skipped.get(e.reason or "invalid", 0) + 1
        elif e.t0 in jumps:
            skipped[MASK_JUMP] = skipped.get(MASK_JUMP, 0) + 1
        else:
            valid.append(e)
    S: float | None = None
    p90: float | None = None
    w2: float | None = None
    if valid:
        S, p90 = object_scores([e.d_t for e in valid if e.d_t is not None])
        w2 = float(np.mean([e.w2 for e in valid]))
    return ObjectScaleSummary(s, S, w2, p90, len(valid), dict(sorted(skipped.items())))


def object_summaries(
    entries: Sequence[ObjectEntry],
    scales: Sequence[float],
    object_share: dict[int, dict[int, float]],
    *,
    min_pairs: int = 1,
    jump_window: int = 3,
    max_jump: float = 0.0,
) -> list[ObjectSummary]:
    """Per object (in id order): frames seen (with a mask in ``object_share``, or starting a
    scored pair), mean masked share over them (``object_share[t][id]``, a share of the content
    area), and per scale ``S`` (mean ``D_t``), mean W2 and AdaP90 (:func:`object_scores`) over
    its valid pairs; the headline values are those of the largest
    scale, None when it has fewer than ``min_pairs`` valid pairs there (the coverage rule,
    ``ScoreConfig.min_object_pairs``). With ``max_jump > 0``, pairs whose mask jumps in area
    (:func:`mask_jumps`) are left out and counted as skipped (``mask_jump``)."""
    summaries = []
    s_max = max(scales)
    for oid in sorted({e.object_id for e in entries}):
        mine = [e for e in entries if e.object_id == oid]
        starts = sorted({e.t0 for e in mine})
        # frames seen: with the object's mask, including the last ones, which start no pair
        frames = sorted(set(starts) | {t for t, shares in object_share.items() if oid in shares})
        areas = {t: object_share[t][oid] for t in starts if oid in object_share.get(t, {})}
        jumps = mask_jumps(areas, window=jump_window, max_jump=max_jump)
        per_scale = [_scale_summary(mine, s, jumps) for s in scales]
        head = next(p for p in per_scale if p.scale == s_max)
        judged = head.valid_frames >= min_pairs
        shares = [object_share.get(t, {}).get(oid, 0.0) for t in frames]
        summaries.append(
            ObjectSummary(
                object_id=oid,
                frames=len(frames),
                first_frame=frames[0],
                last_frame=frames[-1],
                masked_share=float(np.mean(shares)) if shares else 0.0,
                adadfrc=head.adadfrc if judged else None,
                adadfrc_w2=head.adadfrc_w2 if judged else None,
                adap90=head.adap90 if judged else None,
                per_scale=tuple(per_scale),
            )
        )
    return summaries
