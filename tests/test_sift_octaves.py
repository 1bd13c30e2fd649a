"""``sift_octaves``: one SIFT pass per frame at full size, the coarser scales taken from its
octaves. Against a known motion its matches move by the motion at every scale; its full-size
features are SIFT's; scales that are not halvings fall back to a SIFT pass per scale."""

from __future__ import annotations

import numpy as np

from geocon_core.geometry import SiftMatcher, make_matcher, scaled_inputs

from .test_tracks import STEP, _frames

SIZE = (640, 480)


def _inputs(gray: np.ndarray, scales: tuple[float, ...]) -> dict[float, tuple[np.ndarray, np.ndarray]]:
    full = np.ones(gray.shape, bool)
    return {s: scaled_inputs(gray, full, s) for s in scales}


def test_matches_move_by_the_known_motion_at_every_scale():
    frames = _frames(4, SIZE)
    matcher = make_matcher("sift_octaves", max_features=2000)
    scales = (0.25, 0.5, 1.0)
    a = matcher.extract_scales(_inputs(frames[0], scales), 0)  # type: ignore[attr-defined]
    b = matcher.extract_scales(_inputs(frames[3], scales), 3)  # type: ignore[attr-defined]
    for s in scales:
        assert 0 < len(a[s]) <= max(64, round(2000 * s))
        assert a[s].mask.shape == (round(SIZE[1] * s), round(SIZE[0] * s))
        xa, xb = matcher.match(a[s], b[s])
        assert len(xa) >= 0.5 * len(a[s]), (s, len(xa), len(a[s]))
        err = np.linalg.norm(xb - xa - 3 * STEP * s, axis=1)
        assert np.median(err) < 0.05 and np.percentile(err, 90) < 0.2, (s, np.median(err))


def test_full_size_features_are_sifts_and_coarse_ones_come_from_them():
    gray = _frames(1, SIZE)[0]
    scales = (0.5, 1.0)
    shared = make_matcher("sift_octaves", max_features=1500).extract_scales(_inputs(gray, scales), 0)  # type: ignore[attr-defined]
    g, m = scaled_inputs(gray, np.ones(gray.shape, bool), 1.0)
    own = SiftMatcher(max_features=1500).extract(g, m, 0, 1.0)
    mine = {tuple(p) for p in np.round(shared[1.0].xy, 3)}
    theirs = {tuple(p) for p in np.round(own.xy, 3)}
    assert len(mine & theirs) >= 0.98 * len(theirs)
    # every half-size feature is a full-size keypoint at half its coordinates, with its descriptor
    full_set = make_matcher("sift_octaves", max_features=100000).extract_scales(_inputs(gray, (1.0,)), 0)[1.0]  # type: ignore[attr-defined]
    # (SIFT gives a keypoint with two orientations twice at one place: compare as sets)
    index: dict[tuple, set[bytes]] = {}
    for p, d in zip(np.round(full_set.xy * 0.5, 3), full_set.desc, strict=True):
        index.setdefault(tuple(p), set()).add(d.tobytes())
    half = shared[0.5]
    assert len(half) > 100
    for p, d in zip(np.round(half.xy, 3), half.desc, strict=True):
        assert d.tobytes() in index.get(tuple(p), set()), p


def test_scales_that_are_not_halvings_get_a_sift_pass_each():
    gray = _frames(1, SIZE)[0]
    scales = (0.6, 1.0)
    shared = make_matcher("sift_octaves", max_features=800).extract_scales(_inputs(gray, scales), 0)  # type: ignore[attr-defined]
    g, m = _inputs(gray, (0.6,))[0.6]
    own = SiftMatcher(max_features=800).extract(g, m, 0, 0.6)
    assert np.array_equal(shared[0.6].xy, own.xy)
