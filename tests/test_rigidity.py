"""AdaDFRC-W2 (geocon_core.scoring.rigidity): exactness on affine fields, analytic non-affine scores,
optimal-transport bounds and exactness, invalid inputs, serialisation."""

from __future__ import annotations

import itertools
import math
import time

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.optimize import linear_sum_assignment

from geocon_core.record import ObjectEntry
from geocon_core.scoring import (
    MASK_JUMP,
    CellVectors,
    RigidityResult,
    adadfrc_pair,
    mask_interior,
    mask_jumps,
    object_scores,
    object_summaries,
    refine_object_mask,
    w2_cost,
    weighted_affine_fit,
    weighted_mse,
)

# ---------------------------------------------------------------- helpers (independent of the module)


def affine_flow(h: int, w: int, m: np.ndarray, b: np.ndarray, origin=(0.0, 0.0)) -> np.ndarray:
    """v(p) = M p + b at every pixel centre p = (col + x0, row + y0)."""
    yy, xx = np.mgrid[:h, :w].astype(np.float64)
    x, y = xx + origin[0], yy + origin[1]
    return np.stack([m[0, 0] * x + m[0, 1] * y + b[0], m[1, 0] * x + m[1, 1] * y + b[1]], axis=-1)


def disc(h, w, cx, cy, r):
    yy, xx = np.mgrid[:h, :w]
    return (xx - cx) ** 2 + (yy - cy) ** 2 <= r * r


def make_masks(rng: np.random.Generator) -> dict[str, np.ndarray]:
    h, w = 70, 90
    ring = disc(h, w, 45, 35, 30) & ~disc(h, w, 45, 35, 18)
    ell = np.zeros((h, w), bool)
    ell[5:65, 8:25] = True
    ell[48:65, 8:80] = True
    blob = np.zeros((h, w), bool)
    for _ in range(6):
        blob |= disc(h, w, rng.uniform(20, 70), rng.uniform(15, 55), rng.uniform(5, 14))
    return {"disc": disc(h, w, 44, 33, 27), "ring": ring, "L": ell, "blob": blob}


def random_affine(rng: np.random.Generator, scale: float = 0.08) -> tuple[np.ndarray, np.ndarray]:
    return rng.normal(0, scale, (2, 2)), rng.normal(0, 4.0, 2)


def brute_w2(pred: np.ndarray, obs: np.ndarray, counts: np.ndarray) -> float:
    """Exact W2^2 for integer weights: expand each cell into `count` unit atoms and solve the assignment."""
    reps = counts.astype(int)
    p, o = np.repeat(pred, reps, axis=0), np.repeat(obs, reps, axis=0)
    cost = ((p[:, None, :] - o[None, :, :]) ** 2).sum(axis=2)
    r, c = linear_sum_assignment(cost)
    return float(cost[r, c].sum() / reps.sum())


def check_cell_structure(
    res: RigidityResult, flow: np.ndarray, mask: np.ndarray, reliable: np.ndarray | None, grid: int, origin=(0.0, 0.0)
):
    """Cells/positions/observed/weights follow the documented grid and medoid rules."""
    use = mask.copy() if reliable is None else mask & reliable
    use &= np.isfinite(flow).all(axis=2)
    ys, xs = np.nonzero(mask)
    r0, c0 = ys.min(), xs.min()
    bh, bw = ys.max() - r0 + 1, xs.max() - c0 + 1
    cv = res.cells
    assert cv.weights.sum() == res.n_pixels == use.sum()
    for (i, j), (px, py), v, wgt in zip(cv.cells, cv.positions, cv.observed, cv.weights, strict=True):
        col, row = int(round(px - origin[0])), int(round(py - origin[1]))
        assert px == col + float(origin[0]) and py == row + float(origin[1])  # pixel centre + origin
        assert use[row, col]
        # the pixel lies in cell (i, j): i*H/N <= row - r0 < (i+1)*H/N
        assert i * bh <= (row - r0) * grid < (i + 1) * bh
        assert j * bw <= (col - c0) * grid < (j + 1) * bw
        assert np.array_equal(v, flow[row, col])
        rr, cc = np.nonzero(use)
        in_cell = ((rr - r0) * grid // bh == i) & ((cc - c0) * grid // bw == j)
        assert wgt == in_cell.sum()


# ---------------------------------------------------------------- 1. exactly affine flow


@pytest.mark.parametrize("shape", ["disc", "ring", "L", "blob"])
def test_affine_flow_scores_zero_at_every_grid_size(shape):
    rng = np.random.default_rng(hash(shape) % 2**32)
    mask = make_masks(rng)[shape]
    for grid in range(2, 13):
        m, b = random_affine(rng)
        origin = (float(rng.uniform(-300, 800)), float(rng.uniform(-200, 500)))
        flow = affine_flow(*mask.shape, m, b, origin)
        res = adadfrc_pair(flow, mask, grid=grid, origin=origin)
        assert res.valid and res.reason is None
        scale = 1.0 + float(np.mean(np.sum(flow[mask] ** 2, axis=1)))
        assert 0.0 <= res.d_t <= 1e-20 * scale, (grid, res.d_t)
        assert 0.0 <= res.w2 <= res.d_t
        assert np.allclose(res.affine, np.column_stack([m, b]), rtol=0, atol=1e-9)
        assert np.allclose(res.cells.predicted, res.cells.observed, rtol=0, atol=1e-9)
        assert res.n_pixels == mask.sum()
        check_cell_structure(res, flow, mask, None, grid, origin)


def test_affine_flow_float32_input():
    rng = np.random.default_rng(1)
    mask = make_masks(rng)["blob"]
    m, b = random_affine(rng)
    flow = affine_flow(*mask.shape, m, b).astype(np.float32)
    res = adadfrc_pair(flow, mask, grid=8)
    # the medoid reproduces the float32 samples exactly; only float32 rounding of the field remains
    assert res.valid and res.d_t < 1e-9
    assert res.cells.observed.dtype == np.float64


def test_componentwise_median_at_centroid_would_not_be_exact():
    """Regression guard for the medoid choice: on an irregular cell, the component-wise median flow is
    not the field at the cell centroid, so that construction would score an affine field > 0."""
    rng = np.random.default_rng(2)
    mask = make_masks(rng)["ring"]
    m, b = np.array([[0.05, 0.03], [-0.02, 0.04]]), np.array([1.0, -2.0])
    flow = affine_flow(*mask.shape, m, b)
    grid = 5
    ys, xs = np.nonzero(mask)
    r0, c0 = ys.min(), xs.min()
    bh, bw = ys.max() - r0 + 1, xs.max() - c0 + 1
    cell = ((ys - r0) * grid // bh) * grid + (xs - c0) * grid // bw
    pos, vec, wts = [], [], []
    for k in np.unique(cell):
        sel = cell == k
        pos.append([xs[sel].mean(), ys[sel].mean()])
        vec.append(np.median(flow[ys[sel], xs[sel]], axis=0))
        wts.append(sel.sum())
    pos, vec, wts = np.array(pos), np.array(vec), np.array(wts, float)
    naive = weighted_mse(
        pos @ weighted_affine_fit(pos, vec, wts)[:, :2].T + weighted_affine_fit(pos, vec, wts)[:, 2], vec, wts
    )
    assert naive > 1e-6
    assert adadfrc_pair(flow, mask, grid=grid).d_t < 1e-20


# ---------------------------------------------------------------- 2. analytic non-affine scores


@pytest.mark.parametrize("grid,s", [(2, 5), (4, 3), (6, 7), (8, 5)])
def test_checkerboard_offset_gives_delta_squared(grid, s):
    """Full square box of N x N cells of s x s pixels (s odd), affine field + per-cell checkerboard
    +-delta on the x-flow. For odd s the median of an affine field over a full s x s cell is its value
    at the centre pixel, so the medoids are the cell centres: a regular, symmetric grid to which the
    checkerboard (N even) is orthogonal together with 1, x and y. The affine fit therefore recovers
    the affine part and D_t = delta^2 exactly."""
    rng = np.random.default_rng(grid * 100 + s)
    m, b = random_affine(rng)
    delta = 1.7
    origin = (37.0, -12.0)
    size = grid * s
    flow = affine_flow(size, size, m, b, origin)
    ii, jj = np.mgrid[:size, :size] // s
    flow[..., 0] += delta * np.where((ii + jj) % 2 == 0, 1.0, -1.0)
    mask = np.ones((size, size), bool)
    res = adadfrc_pair(flow, mask, grid=grid, origin=origin)
    assert res.valid and res.cells.num_cells == grid * grid
    centres = np.array(
        [[j * s + s // 2 + origin[0], i * s + s // 2 + origin[1]] for i in range(grid) for j in range(grid)]
    )
    assert np.array_equal(res.cells.positions, centres)
    assert np.array_equal(res.cells.cells, np.array(list(itertools.product(range(grid), range(grid)))))
    assert np.all(res.cells.weights == s * s)
    assert res.d_t == pytest.approx(delta**2, rel=1e-12)
    assert np.allclose(res.affine, np.column_stack([m, b]), atol=1e-9)
    assert 0.0 <= res.w2 <= res.d_t
    check_cell_structure(res, flow, mask, None, grid, origin)


def test_checkerboard_on_irregular_mask_matches_independent_projection():
    """Irregular mask: the expected D_t is the weighted residual of the checkerboard offsets after
    their own weighted affine projection at the reported medoid positions (affine part is in the span)."""
    rng = np.random.default_rng(7)
    mask = make_masks(rng)["blob"]
    m, b = random_affine(rng)
    grid, delta = 6, 0.9
    ys, xs = np.nonzero(mask)
    r0, c0 = ys.min(), xs.min()
    bh, bw = ys.max() - r0 + 1, xs.max() - c0 + 1
    rows, cols = np.mgrid[: mask.shape[0], : mask.shape[1]]
    ci, cj = (rows - r0) * grid // bh, (cols - c0) * grid // bw
    sign = np.where((ci + cj) % 2 == 0, 1.0, -1.0)
    flow = affine_flow(*mask.shape, m, b)
    flow[..., 0] += delta * sign
    res = adadfrc_pair(flow, mask, grid=grid)
    check_cell_structure(res, flow, mask, None, grid)
    cv = res.cells
    offs = delta * np.where(cv.cells.sum(axis=1) % 2 == 0, 1.0, -1.0)
    sw = np.sqrt(cv.weights)
    design = np.column_stack([cv.positions, np.ones(len(sw))]) * sw[:, None]
    coef, *_ = np.linalg.lstsq(design, offs * sw, rcond=None)
    resid = offs - np.column_stack([cv.positions, np.ones(len(sw))]) @ coef
    expected = float((cv.weights * resid**2).sum() / cv.weights.sum())
    assert expected > 0.1 * delta**2
    assert res.d_t == pytest.approx(expected, rel=1e-9)


@pytest.mark.parametrize("grid,s,k", [(2, 3, 0.01), (4, 5, 0.003), (8, 3, -0.02)])
def test_quadratic_field_on_symmetric_box(grid, s, k):
    """v = (k x^2, 0) on a full box symmetric about x = 0 (origin x0 = -(W-1)/2). Within a cell the
    x-flow is monotone in the column and each column holds s pixels (s odd), so the median is the
    middle column's value and the medoid is that column's top pixel. With uniform weights on a product
    grid of positions symmetric in x, the affine fit of x^2 is its mean, so
    D_t = k^2 (mean(x^4) - mean(x^2)^2) over the middle-column x of the N cell columns."""
    size = grid * s
    x0 = -(size - 1) / 2
    origin = (x0, 5.0)
    yy, xx = np.mgrid[:size, :size].astype(float)
    x = xx + x0
    flow = np.stack([k * x**2, np.zeros_like(x)], axis=-1)
    mask = np.ones((size, size), bool)
    res = adadfrc_pair(flow, mask, grid=grid, origin=origin)
    xm = np.array([x0 + j * s + (s - 1) / 2 for j in range(grid)])
    expected = k**2 * (np.mean(xm**4) - np.mean(xm**2) ** 2)
    assert res.valid
    assert np.array_equal(np.unique(res.cells.positions[:, 0]), xm)
    assert res.d_t == pytest.approx(expected, rel=1e-10)
    # the fit: v_x ~ k mean(x^2), no x or y dependence
    assert np.allclose(res.affine, [[0, 0, k * np.mean(xm**2)], [0, 0, 0]], atol=1e-10)
    assert 0.0 <= res.w2 <= res.d_t


def test_grid_partition_of_box_not_divisible_by_n():
    """Cell edges at equal fractions of the box: cell i holds rows with i*H/N <= r < (i+1)*H/N."""
    h, w, grid = 10, 7, 3
    mask = np.zeros((14, 12), bool)
    mask[2:12, 3:10] = True
    flow = np.zeros((14, 12, 2))
    res = adadfrc_pair(flow, mask, grid=grid)
    sizes = lambda n: [math.ceil((i + 1) * n / grid) - math.ceil(i * n / grid) for i in range(grid)]  # noqa: E731
    expected = np.outer(sizes(h), sizes(w)).ravel()
    assert list(sizes(h)) == [4, 3, 3] and list(sizes(w)) == [3, 2, 2]
    assert np.array_equal(res.cells.weights, expected.astype(float))
    assert res.d_t == 0.0 and res.w2 == 0.0
    # constant flow: all pixels of a cell tie, the medoid is the cell's first pixel in row-major order
    first_rows = 2 + np.array([0, 4, 7])
    first_cols = 3 + np.array([0, 3, 5])
    assert np.array_equal(res.cells.positions, np.array([[c, r] for r in first_rows for c in first_cols], float))


def test_grid_box_is_the_mask_box_not_the_reliable_box():
    h, w = 20, 20
    mask = np.zeros((h, w), bool)
    mask[0:16, 0:16] = True
    reliable = np.zeros((h, w), bool)
    reliable[0:8, 0:8] = True  # one quadrant of the mask box only
    res = adadfrc_pair(np.zeros((h, w, 2)), mask, reliable, grid=2, min_cells=1)
    assert res.valid and np.array_equal(res.cells.cells, [[0, 0]]) and res.cells.weights.tolist() == [64.0]


# ---------------------------------------------------------------- optimal transport


@pytest.mark.parametrize("seed", range(8))
def test_w2_matches_expanded_assignment(seed):
    rng = np.random.default_rng(seed)
    c = int(rng.integers(2, 9))
    pred = rng.normal(0, 2, (c, 2))
    obs = pred + rng.normal(0, 1.5, (c, 2))
    counts = rng.integers(1, 6, c).astype(float)
    exact = brute_w2(pred, obs, counts)
    assert w2_cost(pred, obs, counts) == pytest.approx(exact, rel=1e-8, abs=1e-12)
    assert w2_cost(pred, obs, counts) <= weighted_mse(pred, obs, counts)
    # equal weights (assignment path) agrees with the brute force too
    ones = np.full(c, 3.0)
    assert w2_cost(pred, obs, ones) == pytest.approx(brute_w2(pred, obs, ones), rel=1e-12, abs=1e-12)


def test_w2_of_a_permuted_set_is_zero_while_wmse_is_not():
    rng = np.random.default_rng(3)
    pred = rng.normal(0, 3, (12, 2))
    perm = rng.permutation(12)
    obs = pred[perm]
    w = np.full(12, 5.0)
    assert weighted_mse(pred, obs, w) > 1.0
    assert w2_cost(pred, obs, w) == 0.0
    # unequal weights, only equal-weight atoms swapped
    w2 = np.array([1.0, 1.0, 2.0, 3.0])
    p4 = np.array([[0.0, 0], [4, 0], [0, 4], [4, 4]])
    o4 = p4[[1, 0, 2, 3]]
    assert weighted_mse(p4, o4, w2) == pytest.approx(2 * 16 / 7)
    assert w2_cost(p4, o4, w2) == pytest.approx(0.0, abs=1e-12)


def test_w2_zero_weight_cells_are_ignored():
    pred = np.array([[0.0, 0.0], [1.0, 0.0], [100.0, 100.0]])
    obs = np.array([[1.0, 0.0], [0.0, 0.0], [-100.0, 5.0]])
    assert w2_cost(pred, obs, np.array([2.0, 2.0, 0.0])) == 0.0


def test_input_validation_of_array_functions():
    p = np.zeros((3, 2))
    with pytest.raises(ValueError):
        weighted_mse(p, np.zeros((4, 2)), np.ones(3))
    with pytest.raises(ValueError):
        w2_cost(p, p, np.zeros(3))
    with pytest.raises(ValueError):
        weighted_affine_fit(p, p, -np.ones(3))
    with pytest.raises(ValueError):
        weighted_affine_fit(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0))


def test_weighted_affine_fit_collinear_uses_min_norm_and_stays_exact():
    pos = np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 2.0], [5.0, 5.0]])
    vec = pos @ np.array([[0.1, 0.2], [0.3, -0.1]]).T + [1.0, 2.0]
    aff = weighted_affine_fit(pos, vec, np.array([1.0, 2.0, 3.0, 4.0]))
    assert np.all(np.isfinite(aff))
    assert np.allclose(pos @ aff[:, :2].T + aff[:, 2], vec, atol=1e-12)
    # minimum norm in centred coordinates: equal split between the x and y columns
    assert aff[0, 0] == pytest.approx(aff[0, 1]) and aff[1, 0] == pytest.approx(aff[1, 1])


# ---------------------------------------------------------------- 3. properties


@st.composite
def flow_cases(draw):
    h = draw(st.integers(1, 14))
    w = draw(st.integers(1, 14))
    flow = draw(arrays(np.float64, (h, w, 2), elements=st.floats(-40, 40, allow_nan=False, allow_infinity=False)))
    mask = draw(arrays(np.bool_, (h, w)))
    reliable = draw(st.one_of(st.none(), arrays(np.bool_, (h, w))))
    grid = draw(st.integers(1, 6))
    origin = (draw(st.floats(-500, 500)), draw(st.floats(-500, 500)))
    return flow, mask, reliable, grid, origin


@settings(max_examples=100, deadline=None)
@given(flow_cases(), st.randoms(use_true_random=False))
def test_properties_random_fields(case, rnd):
    flow, mask, reliable, grid, origin = case
    res = adadfrc_pair(flow, mask, reliable, grid=grid, origin=origin)
    use = mask if reliable is None else mask & reliable
    assert res.n_pixels == int(use.sum())
    if not res.valid:
        assert res.reason in {"empty_mask", "too_few_cells", "degenerate_fit"}
        assert res.d_t is None and res.w2 is None and res.affine is None and res.cells is None
        if not mask.any():
            assert res.reason == "empty_mask"
        return
    assert res.reason is None
    assert math.isfinite(res.d_t) and math.isfinite(res.w2)
    assert 0.0 <= res.w2 <= res.d_t + 1e-9 * max(1.0, res.d_t)
    cv = res.cells
    assert 3 <= cv.num_cells <= grid * grid
    assert np.all(np.isfinite(res.affine)) and np.all(np.isfinite(cv.predicted))
    assert res.d_t == pytest.approx(weighted_mse(cv.predicted, cv.observed, cv.weights), rel=1e-12, abs=1e-300)
    check_cell_structure(res, flow, mask, reliable, grid, origin)
    # permutation invariance of the transport cost over cell order, and symmetry
    perm = list(range(cv.num_cells))
    rnd.shuffle(perm)
    w2p = w2_cost(cv.predicted[perm], cv.observed[perm], cv.weights[perm])
    tol = 1e-9 * max(1.0, res.d_t)
    assert abs(w2p - res.w2) <= tol
    assert abs(w2_cost(cv.observed, cv.predicted, cv.weights) - res.w2) <= tol
    # the fit is a weighted least-squares optimum: no perturbed affine model does better
    for _ in range(3):
        d_aff = np.array([[rnd.uniform(-1, 1) * 1e-3 for _ in range(3)] for _ in range(2)])
        alt = res.affine + d_aff
        alt_pred = cv.positions @ alt[:, :2].T + alt[:, 2]
        assert weighted_mse(alt_pred, cv.observed, cv.weights) >= res.d_t - 1e-9 * max(1.0, res.d_t)


@settings(max_examples=60, deadline=None)
@given(st.integers(2, 7), st.integers(0, 2**32 - 1))
def test_property_w2_exact_against_brute_force(c, seed):
    rng = np.random.default_rng(seed)
    pred = rng.normal(0, 5, (c, 2))
    obs = rng.normal(0, 5, (c, 2))
    counts = rng.integers(1, 5, c).astype(float)
    assert w2_cost(pred, obs, counts) == pytest.approx(brute_w2(pred, obs, counts), rel=1e-8, abs=1e-10)


# ---------------------------------------------------------------- 4. invalid results


def test_empty_mask():
    res = adadfrc_pair(np.zeros((8, 8, 2)), np.zeros((8, 8), bool))
    assert (res.valid, res.reason, res.n_pixels) == (False, "empty_mask", 0)
    assert res.d_t is None and res.w2 is None and res.affine is None and res.cells is None


def test_one_and_two_nonempty_cells():
    flow = np.random.default_rng(0).normal(size=(20, 20, 2))
    one = np.zeros((20, 20), bool)
    one[5, 5] = True
    res = adadfrc_pair(flow, one)
    assert (res.valid, res.reason, res.n_pixels) == (False, "too_few_cells", 1)
    two = np.zeros((20, 20), bool)
    two[0:3, 0:3] = True
    two[17:20, 17:20] = True
    res = adadfrc_pair(flow, two, grid=4)  # 5 px cells: each block in one cell
    assert (res.valid, res.reason, res.n_pixels) == (False, "too_few_cells", 18)
    # with min_cells=2 two cells are scored; two points are fitted exactly (min-norm affine)
    res = adadfrc_pair(flow, two, grid=4, min_cells=2)
    assert res.valid and res.cells.num_cells == 2 and res.d_t < 1e-20 and res.w2 <= res.d_t


def test_all_pixels_unreliable_or_non_finite():
    mask = disc(30, 30, 15, 15, 10)
    res = adadfrc_pair(np.zeros((30, 30, 2)), mask, np.zeros((30, 30), bool))
    assert (res.valid, res.reason, res.n_pixels) == (False, "too_few_cells", 0)
    res = adadfrc_pair(np.full((30, 30, 2), np.nan), mask)
    assert (res.valid, res.reason, res.n_pixels) == (False, "too_few_cells", 0)


def test_overflowing_flow_is_degenerate_fit_not_an_exception():
    rng = np.random.default_rng(4)
    flow = rng.normal(0, 1e200, (30, 30, 2))
    res = adadfrc_pair(flow, disc(30, 30, 15, 15, 12))
    assert (res.valid, res.reason) == (False, "degenerate_fit")
    assert res.d_t is None and res.cells is None and res.n_pixels > 0


def test_malformed_arguments_raise():
    with pytest.raises(ValueError):
        adadfrc_pair(np.zeros((8, 8)), np.ones((8, 8), bool))
    with pytest.raises(ValueError):
        adadfrc_pair(np.zeros((8, 8, 2)), np.ones((8, 9), bool))
    with pytest.raises(ValueError):
        adadfrc_pair(np.zeros((8, 8, 2)), np.ones((8, 8), bool), np.ones((7, 8), bool))
    with pytest.raises(ValueError):
        adadfrc_pair(np.zeros((8, 8, 2)), np.ones((8, 8), bool), grid=0)


# ---------------------------------------------------------------- 5. reliability mask


def test_unreliable_outliers_are_excluded():
    rng = np.random.default_rng(5)
    mask = make_masks(rng)["disc"]
    m, b = random_affine(rng)
    flow = affine_flow(*mask.shape, m, b)
    reliable = rng.random(mask.shape) > 0.3
    # a whole block (several cells) unreliable with wild values, plus scattered wild / NaN pixels
    reliable[10:35, 20:45] = False
    bad = ~reliable
    flow[bad] = rng.normal(0, 1e4, (bad.sum(), 2))
    flow[bad & (rng.random(mask.shape) < 0.2)] = np.nan
    res = adadfrc_pair(flow, mask, reliable, grid=8)
    assert res.valid and res.d_t < 1e-18 and res.w2 <= res.d_t
    assert res.n_pixels == (mask & reliable).sum()
    assert np.allclose(res.affine, np.column_stack([m, b]), atol=1e-9)
    check_cell_structure(res, flow, mask, reliable, 8)
    # without the reliability mask the outliers dominate the cells they fill
    flow_finite = np.nan_to_num(flow, nan=1e4)
    assert adadfrc_pair(flow_finite, mask, None, grid=8).d_t > 1e3


def test_non_finite_flow_on_reliable_pixels_is_dropped():
    m, b = np.array([[0.02, -0.01], [0.03, 0.01]]), np.array([0.5, -1.5])
    mask = disc(40, 40, 20, 20, 15)
    flow = affine_flow(40, 40, m, b)
    flow[::3, ::4] = np.inf
    res = adadfrc_pair(flow, mask, grid=6)
    assert res.valid and res.d_t < 1e-20
    assert res.n_pixels == (mask & np.isfinite(flow).all(axis=2)).sum()


# ---------------------------------------------------------------- 6. object scores


def test_object_scores_known_values():
    # 0.9 quantile, linear interpolation: position 0.9 * (n - 1) in the sorted list
    assert object_scores([4.0, 1.0, 3.0, 2.0]) == pytest.approx((2.5, 3.0 + 0.7 * 1.0))
    assert object_scores([5.0]) == (5.0, 5.0)
    vals = [0.0, 10.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0]  # 0..10: position 9.0 -> 9.0
    s, p90 = object_scores(vals)
    assert s == pytest.approx(5.0) and p90 == pytest.approx(9.0)
    s, p90 = object_scores(np.array([1.0, 100.0]))  # position 0.9 -> 1 + 0.9 * 99
    assert (s, p90) == pytest.approx((50.5, 90.1))
    assert isinstance(s, float) and isinstance(p90, float)


def test_object_scores_rejects_empty_and_non_finite():
    with pytest.raises(ValueError, match="at least one"):
        object_scores([])
    with pytest.raises(ValueError, match="non-finite"):
        object_scores([1.0, float("nan")])


# ---------------------------------------------------------------- 7. result fields


def test_result_fields_and_dtypes():
    rng = np.random.default_rng(6)
    mask = make_masks(rng)["L"]
    flow = affine_flow(*mask.shape, *random_affine(rng)) + rng.normal(0, 3.0, mask.shape + (2,))
    results = [
        adadfrc_pair(flow, mask, grid=7, origin=(0.1, 1 / 3)),
        adadfrc_pair(flow, np.zeros_like(mask)),
        adadfrc_pair(flow, mask, np.zeros_like(mask)),
    ]
    assert results[0].valid and results[0].d_t > 0 and results[0].w2 < results[0].d_t
    for res in results:
        assert isinstance(res.n_pixels, int)
        if not res.valid:
            assert res.reason is not None
            assert res.d_t is None and res.w2 is None and res.affine is None and res.cells is None
            continue
        assert res.reason is None and isinstance(res.d_t, float) and isinstance(res.w2, float)
        assert res.affine.dtype == np.float64 and res.affine.shape == (2, 3)
        cv = res.cells
        assert isinstance(cv, CellVectors) and cv.cells.dtype == np.int64
        for name in ("positions", "observed", "predicted", "weights"):
            assert getattr(cv, name).dtype == np.float64


def test_cell_vectors_shape_check():
    with pytest.raises(ValueError):
        CellVectors(np.zeros((2, 2), int), np.zeros((3, 2)), np.zeros((2, 2)), np.zeros((2, 2)), np.ones(2))


# ---------------------------------------------------------------- 8. speed sanity (printed, not asserted)


def test_speed_sanity_200x200_grid8():
    rng = np.random.default_rng(8)
    h = w = 200
    mask = disc(h, w, 100, 100, 99)
    flow = affine_flow(h, w, *random_affine(rng)) + rng.normal(0, 0.5, (h, w, 2))
    adadfrc_pair(flow, mask, grid=8)  # warm-up (scipy imports)
    reps = 10
    t0 = time.perf_counter()
    for _ in range(reps):
        res = adadfrc_pair(flow, mask, grid=8)
    ms = (time.perf_counter() - t0) / reps * 1e3
    assert res.valid and res.cells.num_cells > 50
    print(f"\nadadfrc_pair 200x200 disc, grid 8, {res.cells.num_cells} cells: {ms:.2f} ms/call")


# --- mask jumps: a one-frame segmentation glitch is not a deformation ---------------------------


def test_mask_jumps_flags_one_frame_swell_and_shrink_not_steady_growth():
    steady = {t: 0.02 * 1.05**t for t in range(20)}  # an object approaching: +5% area per frame
    assert mask_jumps(steady, window=3, max_jump=0.25) == set()
    glitchy = {t: 0.02 for t in range(20)}
    glitchy[7] = 0.03  # swells by half (a neighbour's region joins the mask)
    glitchy[12] = 0.009  # loses half the object
    assert mask_jumps(glitchy, window=3, max_jump=0.25) == {7, 12}
    assert mask_jumps(glitchy, window=3, max_jump=0.0) == set()  # the paper keeps every pair
    assert mask_jumps({0: 0.02, 1: 0.05}, window=3, max_jump=0.25) == set()  # two frames: no neighbours to judge by


def _translating_object_entries(glitch_frame: int, n: int = 12) -> tuple[list, dict]:
    """A rigid square translating by (2, 1) px per frame over a still background; at
    ``glitch_frame`` its mask also swallows a strip of the still background."""
    entries, shares = [], {}
    H = W = 120
    for t in range(n):
        mask = np.zeros((H, W), bool)
        x0, y0 = 20 + 2 * t, 30 + t
        mask[y0 : y0 + 40, x0 : x0 + 40] = True
        flow = np.zeros((H, W, 2))
        flow[mask] = (2.0, 1.0)
        if t == glitch_frame:
            mask[y0 : y0 + 40, x0 + 40 : x0 + 60] = True  # background strip, flow 0
        r = adadfrc_pair(flow, mask)
        entries.append(ObjectEntry(t, 1, t, t + 1, 1.0, r.valid, r.reason, r.d_t, r.w2, r.n_pixels, None))
        shares[t] = {1: float(mask.mean())}
    return entries, shares


def test_object_summary_leaves_out_a_glitched_mask_pair():
    entries, shares = _translating_object_entries(glitch_frame=5)
    assert entries[5].d_t > 0.1 and all(e.d_t < 1e-9 for i, e in enumerate(entries) if i != 5)
    (kept,) = object_summaries(entries, [1.0], shares, max_jump=0.0)
    assert kept.adadfrc == pytest.approx(entries[5].d_t / len(entries))  # the glitch dominates the mean
    (clean,) = object_summaries(entries, [1.0], shares, max_jump=0.25)
    assert clean.adadfrc == pytest.approx(0.0, abs=1e-9)
    assert clean.per_scale[0].skipped == {MASK_JUMP: 1}
    assert clean.per_scale[0].valid_frames == len(entries) - 1


# ---------------------------------------------------------------- two-layer mask refinement


def spilled_scene(rng: np.random.Generator, object_flow: np.ndarray, spill: int = 4):
    """A rigid disc moving by ``object_flow`` (plus a small in-plane rotation) over a static
    background, and a motion mask that spills ``spill`` px over the disc's edge."""
    h, w = 90, 120
    obj = disc(h, w, 60, 45, 22)
    m = np.array([[0.0, -0.02], [0.02, 0.0]])
    flow = np.where(obj[..., None], affine_flow(h, w, m, object_flow - m @ np.array([60.0, 45.0])), 0.0)
    flow = flow + rng.normal(0.0, 0.05, flow.shape)
    return flow, obj, disc(h, w, 60, 45, 22 + spill)


def test_refined_mask_drops_the_spilled_background():
    """The spilled ring moves with the background: the refinement removes it (IoU with the true
    object >= 0.97), and AdaDFRC of the rigid disc falls back to its noise level."""
    rng = np.random.default_rng(0)
    flow, obj, spilled = spilled_scene(rng, np.array([3.0, -1.5]))
    refined = refine_object_mask(flow, spilled, np.zeros_like(spilled))
    iou = (refined & obj).sum() / (refined | obj).sum()
    assert iou >= 0.97
    before = adadfrc_pair(flow, spilled).d_t
    after = adadfrc_pair(flow, refined).d_t
    truth = adadfrc_pair(flow, obj).d_t
    assert before > 20 * truth and after <= 2 * truth + 1e-3


def test_refined_mask_keeps_a_deforming_object():
    """A non-rigid object keeps its mask and its deformation score: the pixels that deviate
    from the affine motion still move with the object, not with the background."""
    rng = np.random.default_rng(1)
    h, w = 90, 120
    obj = disc(h, w, 60, 45, 22)
    yy, xx = np.mgrid[:h, :w].astype(float)
    bend = 1.2 * np.sin((xx - 38) / 44 * 2 * np.pi)
    flow = np.where(obj[..., None], np.stack([np.full((h, w), 4.0), bend - 2.0], axis=-1), 0.0)
    flow = flow + rng.normal(0.0, 0.05, flow.shape)
    refined = refine_object_mask(flow, obj, np.zeros_like(obj))
    assert (refined & obj).sum() >= 0.97 * obj.sum()
    assert adadfrc_pair(flow, refined).d_t == pytest.approx(adadfrc_pair(flow, obj).d_t, rel=0.05)


def test_refinement_leaves_a_mask_it_cannot_judge():
    """An object that moves like its background (here: not at all), a mask without background
    around it, or other objects covering the rest: the mask comes back unchanged."""
    rng = np.random.default_rng(2)
    flow, obj, spilled = spilled_scene(rng, np.array([0.0, 0.0]))
    still = np.zeros_like(flow) + rng.normal(0.0, 0.05, flow.shape)
    assert np.array_equal(refine_object_mask(still, spilled, np.zeros_like(spilled)), spilled)
    full = np.ones_like(spilled)
    assert np.array_equal(refine_object_mask(flow, full, np.zeros_like(full)), full)
    assert np.array_equal(refine_object_mask(flow, spilled, ~spilled), spilled)


# ---------------------------------------------------------------- edge margin


def test_mask_interior_is_the_erosion_by_a_disc():
    mask = np.zeros((40, 50), bool)
    mask[5:26, 10:31] = True  # a 21 x 21 square
    inner = mask_interior(mask, 3)
    expect = np.zeros_like(mask)
    expect[8:23, 13:28] = True  # every pixel whose disc of radius 3 fits: a 15 x 15 square
    assert np.array_equal(inner, expect)
    assert np.array_equal(mask_interior(mask, 0), mask)
    edge = np.zeros((10, 10), bool)
    edge[:, :4] = True  # touching the array's border: outside the array is outside the mask
    assert np.flatnonzero(mask_interior(edge, 1).any(axis=0)).tolist() == [1, 2]


def test_edge_margin_removes_flow_mixed_across_the_edge():
    """A rigid object moving by an exact affine field over a still background; the flow is then
    averaged over a 9 x 9 box, as a patch-based flow mixes both sides of an occluding edge. The
    rim reads as deformation; 4 px in (the box's reach), the averaged field is the affine one
    again (a box average of an affine field is that field) and AdaDFRC is zero."""
    h = w = 64
    mask = np.zeros((h, w), bool)
    mask[12:52, 12:52] = True
    yy, xx = np.mgrid[0:h, 0:w].astype(float)
    a = np.deg2rad(3.0)
    fx = (np.cos(a) - 1) * (xx - 32) - np.sin(a) * (yy - 32) + 6.0
    fy = np.sin(a) * (xx - 32) + (np.cos(a) - 1) * (yy - 32) - 2.0
    flow = np.stack([np.where(mask, fx, 0.0), np.where(mask, fy, 0.0)], axis=-1).astype(np.float32)
    mixed = cv2.blur(flow, (9, 9), borderType=cv2.BORDER_REPLICATE)
    rim = adadfrc_pair(mixed, mask, None, grid=8)
    inner = adadfrc_pair(mixed, mask, mask_interior(mask, 4), grid=8)
    assert rim.d_t > 0.5
    assert inner.d_t == pytest.approx(0.0, abs=1e-6)
