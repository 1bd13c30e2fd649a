"""Optical flow backends (geocon_core.flow): accuracy on known warps, forward-backward
reliability, box crops, errors."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import cv2
import numpy as np
import pytest

from geocon_core.flow import FLOW_BACKENDS, DisFlow, FlowField, chained_flow, make_flow_backend
from geocon_core.synth.textures import procedural_texture

from .conftest import SHARED_DATA, read_video

H, W = 240, 360
BORDER = 24  # px left out of accuracy checks at the image edges


def _texture(seed: int = 0, h: int = H, w: int = W) -> np.ndarray:
    rgb = procedural_texture(np.random.default_rng(seed), h, w)
    return cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)


def _warp(img: np.ndarray, M: np.ndarray) -> np.ndarray:
    """I1 with I1(M x) = I0(x): the forward flow of pixel x is M x - x."""
    return cv2.warpAffine(
        img, M, (img.shape[1], img.shape[0]), flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT_101
    )


def _true_flow(M: np.ndarray, h: int, w: int) -> np.ndarray:
    gx, gy = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    fx = M[0, 0] * gx + M[0, 1] * gy + M[0, 2] - gx
    fy = M[1, 0] * gx + M[1, 1] * gy + M[1, 2] - gy
    return np.dstack([fx, fy])


def _inner(a: np.ndarray, b: int = BORDER) -> np.ndarray:
    return a[b:-b, b:-b]


@pytest.mark.parametrize("preset, tol", [("medium", 0.1), ("fast", 0.2)])
def test_translation_is_recovered(preset: str, tol: float) -> None:
    g0 = _texture(1)
    M = np.array([[1.0, 0.0, 2.3], [0.0, 1.0, -1.7]])
    g1 = _warp(g0, M)
    field = DisFlow(preset=preset).compute(g0, g1)
    assert isinstance(field, FlowField)
    assert field.box == (0, 0, W, H)
    assert field.flow.shape == (H, W, 2) and field.flow.dtype == np.float32
    assert field.reliable.shape == (H, W) and field.reliable.dtype == bool
    assert field.fb_error.shape == (H, W) and field.fb_error.dtype == np.float32
    err = np.linalg.norm(_inner(field.flow) - _inner(_true_flow(M, H, W)), axis=2)
    print(f"{preset}: translation median error {np.median(err):.3f} px, reliable {_inner(field.reliable).mean():.1%}")
    assert np.median(err) < tol
    assert _inner(field.reliable).mean() > 0.9


def test_affine_warp_is_recovered() -> None:
    g0 = _texture(2)
    c = np.array([W / 2, H / 2])
    a, s = np.radians(1.5), 1.02
    A = s * np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    M = np.hstack([A, (c - A @ c + np.array([1.2, 0.8]))[:, None]])
    g1 = _warp(g0, M)
    field = make_flow_backend("dis").compute(g0, g1)
    truth = _true_flow(M, H, W)
    assert np.abs(truth).max() > 4.0  # the warp moves pixels by several px
    err = np.linalg.norm(_inner(field.flow) - _inner(truth), axis=2)
    rel = _inner(field.reliable)
    print(
        f"affine: median error {np.median(err):.3f} px (reliable: {np.median(err[rel]):.3f}), reliable {rel.mean():.1%}"
    )
    assert np.median(err) < 0.15
    assert np.median(err[rel]) < 0.15
    assert rel.mean() > 0.85


def test_chained_flow_composes_consecutive_hops() -> None:
    """A patch rotating and drifting 7 px per frame: over four frames the composed flow is the
    composed affine motion (28 px and more), inside an object-sized box; a pixel whose path leaves
    the box before the last hop is unreliable."""
    g0 = _texture(3)
    c = np.array([W / 2, H / 2])
    a = np.radians(2.0)
    A = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    step = np.vstack([np.hstack([A, (c - A @ c + np.array([7.0, 2.0]))[:, None]]), [0, 0, 1]])
    grays, total = [g0], np.eye(3)
    for _ in range(4):
        total = step @ total
        grays.append(_warp(g0, total[:2]))
    box = (120, 80, 220, 150)
    field = chained_flow(DisFlow(), grays, box)
    x0, y0, x1, y1 = box
    assert field.box == box and field.flow.shape == (y1 - y0, x1 - x0, 2)
    truth = _true_flow(total[:2], H, W)[y0:y1, x0:x1]
    assert np.abs(truth).max() > 28.0
    err = np.linalg.norm(field.flow - truth, axis=2)
    print(f"chained: median error {np.median(err[field.reliable]):.3f} px, reliable {field.reliable.mean():.1%}")
    gy, gx = np.mgrid[0 : y1 - y0, 0 : x1 - x0]
    dx, dy = gx + truth[..., 0], gy + truth[..., 1]
    stays = (dx >= 2) & (dx <= x1 - x0 - 3) & (dy >= 2) & (dy <= y1 - y0 - 3)
    assert field.reliable[stays].mean() > 0.9
    before_last = _true_flow((np.linalg.inv(step) @ total)[:2], H, W)[y0:y1, x0:x1]  # three hops in
    bx, by = gx + before_last[..., 0], gy + before_last[..., 1]
    left = (bx < -1) | (bx > x1 - x0) | (by < -1) | (by > y1 - y0)
    assert left.any() and not field.reliable[left].any()  # no hop's flow is known outside the box
    assert np.median(err[field.reliable]) < 0.1 * 4  # each hop's error adds up (about 0.06 px a hop)
    direct = DisFlow().compute(grays[0], grays[-1], box)  # one jump: beyond DIS's search in a crop
    assert np.median(np.linalg.norm(direct.flow - truth, axis=2)) > 5.0
    assert np.all(np.isfinite(field.fb_error[field.reliable]))
    one = chained_flow(DisFlow(), grays[:2], box)  # one hop is the backend's own field
    hop = DisFlow().compute(grays[0], grays[1], box)
    assert np.array_equal(one.flow, hop.flow) and np.array_equal(one.reliable, hop.reliable)
    with pytest.raises(ValueError, match="at least two"):
        chained_flow(DisFlow(), grays[:1], box)


def test_occluded_region_is_unreliable() -> None:
    """A patch of another texture moves 10 px right over a static background: the background
    strip it covers in frame 1 has no partner and must be unreliable."""
    bg, patch = _texture(3), _texture(4, 80, 80)
    x, y, d = 120, 80, 10
    g0, g1 = bg.copy(), bg.copy()
    g0[y : y + 80, x : x + 80] = patch
    g1[y : y + 80, x + d : x + d + 80] = patch
    field = DisFlow().compute(g0, g1)
    covered = field.reliable[y + 6 : y + 74, x + 80 + 2 : x + 80 + d - 2]  # background hidden at t+1
    far_bg = np.zeros((H, W), bool)
    far_bg[BORDER:-BORDER, BORDER:-BORDER] = True
    far_bg[y - 30 : y + 110, x - 30 : x + 80 + d + 30] = False
    inside = field.reliable[y + 12 : y + 68, x + 12 : x + 68]
    print(
        f"reliable: covered strip {covered.mean():.1%}, far background {field.reliable[far_bg].mean():.1%}, "
        f"patch {inside.mean():.1%}"
    )
    assert covered.mean() < 0.2
    assert field.reliable[far_bg].mean() > 0.95
    assert inside.mean() > 0.9
    patch_flow = np.median(field.flow[y + 12 : y + 68, x + 12 : x + 68].reshape(-1, 2), axis=0)
    assert np.allclose(patch_flow, [d, 0], atol=0.2)
    assert np.median(field.fb_error[y + 6 : y + 74, x + 80 + 2 : x + 80 + d - 2]) > 1.0


def test_pixels_leaving_the_view_are_unreliable_with_infinite_error() -> None:
    g0 = _texture(5)
    M = np.array([[1.0, 0.0, 6.0], [0.0, 1.0, 0.0]])
    field = DisFlow().compute(g0, _warp(g0, M))
    leaving = field.fb_error[BORDER:-BORDER, W - 4 :]
    assert np.isinf(leaving).all()
    assert not field.reliable[BORDER:-BORDER, W - 4 :].any()
    assert np.isfinite(field.fb_error[BORDER:-BORDER, : W - 12]).all()


def test_box_crop_matches_the_full_computation() -> None:
    g0 = _texture(6)
    M = np.array([[1.0, 0.01, 1.5], [-0.01, 1.0, 0.7]])
    g1 = _warp(g0, M)
    backend = DisFlow()
    full = backend.compute(g0, g1)
    box = (100, 60, 220, 150)
    part = backend.compute(g0, g1, box)
    x0, y0, x1, y1 = box
    assert part.box == box
    assert part.flow.shape == (y1 - y0, x1 - x0, 2)
    diff = np.linalg.norm(part.flow - full.flow[y0:y1, x0:x1], axis=2)
    err = np.linalg.norm(part.flow - _true_flow(M, H, W)[y0:y1, x0:x1], axis=2)
    print(
        f"box vs full: median {np.median(diff):.3f} px, p95 {np.percentile(diff, 95):.3f} px; "
        f"box vs truth {np.median(err):.3f} px"
    )
    assert np.median(diff) < 0.1
    assert np.percentile(diff, 95) < 0.5
    assert np.median(err) < 0.15
    agree = np.mean(part.reliable == full.reliable[y0:y1, x0:x1])
    assert agree > 0.9


def test_box_at_the_frame_edge_and_tiny_inputs() -> None:
    g0 = _texture(7)
    g1 = _warp(g0, np.array([[1.0, 0.0, 1.0], [0.0, 1.0, 0.0]]))
    field = DisFlow().compute(g0, g1, (W - 5, H - 3, W, H))  # margin clipped to the frame
    assert field.flow.shape == (3, 5, 2)
    tiny = DisFlow().compute(g0[:6, :9].copy(), g1[:6, :9].copy())  # smaller than one DIS patch
    assert tiny.flow.shape == (6, 9, 2)


def test_compute_both_gives_consistent_directions() -> None:
    g0 = _texture(8)
    M = np.array([[1.0, 0.0, -2.0], [0.0, 1.0, 1.0]])
    fwd, bwd = DisFlow().compute_both(g0, _warp(g0, M))
    assert np.allclose(np.median(_inner(fwd.flow).reshape(-1, 2), axis=0), [-2.0, 1.0], atol=0.05)
    assert np.allclose(np.median(_inner(bwd.flow).reshape(-1, 2), axis=0), [2.0, -1.0], atol=0.05)


def test_compute_is_the_forward_field_of_compute_both() -> None:
    """``compute`` checks only the forward field; it is exactly ``compute_both``'s, box or not."""
    g0 = _texture(8)
    g1 = _warp(g0, np.array([[1.0, 0.01, -2.0], [-0.01, 1.0, 1.0]]))
    for box in (None, (40, 30, 200, 170)):
        one = DisFlow().compute(g0, g1, box)
        fwd, bwd = DisFlow().compute_both(g0, g1, box)
        assert one.box == fwd.box and one.flow.dtype == np.float32
        for a, b in ((one.flow, fwd.flow), (one.reliable, fwd.reliable), (one.fb_error, fwd.fb_error)):
            assert np.array_equal(a, b)
        assert not np.array_equal(one.flow, bwd.flow)


def test_deterministic_across_instances_calls_and_threads() -> None:
    g0 = _texture(9)
    g1 = _warp(g0, np.array([[1.0, 0.0, 3.3], [0.0, 1.0, 0.4]]))
    backend = DisFlow()
    a = backend.compute(g0, g1)
    backend.compute(g0[:100, :150].copy(), g1[:100, :150].copy())  # other sizes in between
    backend.compute(g0, g1, (10, 20, 60, 90))
    b = backend.compute(g0, g1)
    c = DisFlow().compute(g0, g1)
    for other in (b, c):
        assert np.array_equal(a.flow, other.flow) and np.array_equal(a.reliable, other.reliable)
        assert np.array_equal(a.fb_error, other.fb_error)
    boxes = [None, (0, 0, 120, 90), (200, 100, 360, 240), (50, 50, 300, 200)] * 3
    serial = [backend.compute(g0, g1, box) for box in boxes]
    with ThreadPoolExecutor(max_workers=4) as pool:  # the scorer computes object flow in threads
        parallel = list(pool.map(lambda box: backend.compute(g0, g1, box), boxes))
    assert all(
        np.array_equal(s.flow, p.flow) and np.array_equal(s.reliable, p.reliable)
        for s, p in zip(serial, parallel, strict=True)
    )


def test_flow_does_not_depend_on_earlier_calls() -> None:
    """Boxes of many sizes on a real frame pair, computed in shuffled orders by one backend, give
    exactly the flow a new backend gives on its first call (an OpenCV DIS object reused across
    calls does not: its result depended on what it computed before)."""
    clip = SHARED_DATA / "real" / "realestate10k" / "0bf152ef84195293.mp4"
    if not clip.exists():
        pytest.skip(f"{clip} is missing")
    gray = [cv2.cvtColor(f, cv2.COLOR_RGB2GRAY) for f in read_video(clip)]
    h, w = gray[0].shape
    rng = np.random.default_rng(1)
    crops = []
    for _ in range(30):
        t = int(rng.integers(0, len(gray) - 1))
        ch, cw = int(rng.integers(20, 150)), int(rng.integers(20, 150))
        y, x = int(rng.integers(0, h - ch)), int(rng.integers(0, w - cw))
        crops.append((gray[t][y : y + ch, x : x + cw].copy(), gray[t + 1][y : y + ch, x : x + cw].copy()))
    first = [DisFlow().compute(a, b).flow for a, b in crops]
    backend = DisFlow()
    for i in rng.permutation(len(crops)):
        assert np.array_equal(backend.compute(*crops[i]).flow, first[i]), crops[i][0].shape


def test_registry_and_errors() -> None:
    assert set(FLOW_BACKENDS) == {"dis", "raft"}
    backend = make_flow_backend("DIS", preset="fast", fb_abs=1.0)
    assert backend.name == "dis" and isinstance(backend, DisFlow) and backend.config.preset == "fast"
    with pytest.raises(ValueError, match=r"unknown flow backend 'farneback'; valid: dis, raft"):
        make_flow_backend("farneback")
    with pytest.raises(ValueError, match=r"needs a checkpoint: pass --raft-checkpoint PATH"):
        make_flow_backend("raft")
    with pytest.raises(ValueError, match="unknown DIS preset"):
        DisFlow(preset="slow")
    g = _texture(10)
    with pytest.raises(ValueError, match="differ in size"):
        DisFlow().compute(g, g[:-1])
    with pytest.raises(ValueError, match="uint8 grey image"):
        DisFlow().compute(g.astype(np.float32), g)
    with pytest.raises(ValueError, match="outside"):
        DisFlow().compute(g, g, (0, 0, W + 1, 10))
    with pytest.raises(ValueError, match="empty"):
        DisFlow().compute(g, g, (10, 10, 10, 20))
