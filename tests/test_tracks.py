"""KLT tracks kept alive across frames (``klt_tracks``): against a known sub-pixel motion, pairs
match exactly the tracks alive in both frames, lost tracks are replaced only away from the live
ones, and the tracks do not depend on which thread extracts which frame."""

from __future__ import annotations

import random
import threading

import cv2
import numpy as np
import pytest

from geocon_core.geometry import KltTrackMatcher, make_matcher

STEP = np.array([1.3, -0.7])
"""The scene's motion per frame (px): frame k is the texture shifted by k * STEP."""


def _frames(n: int, size: tuple[int, int] = (320, 240)) -> list[np.ndarray]:
    w, h = size
    rng = np.random.default_rng(5)
    big = cv2.GaussianBlur(rng.uniform(0, 255, (h + 80, w + 80)).astype(np.float32), (0, 0), 2.0)
    big = cv2.normalize(big, None, 0, 255, cv2.NORM_MINMAX)
    out = []
    for k in range(n):
        dx, dy = k * STEP
        M = np.float32([[1, 0, dx - 40], [0, 1, dy - 40]])
        out.append(cv2.warpAffine(big, M, (w, h), flags=cv2.INTER_CUBIC).clip(0, 255).astype(np.uint8))
    return out


def _assert_moved(xa: np.ndarray, xb: np.ndarray, frames: int) -> None:
    """The matches moved by the scene's motion over ``frames`` frames: frame-to-frame tracking
    drifts by a few hundredths of a pixel per frame, the odd track by more."""
    err = np.linalg.norm(xb - xa - frames * STEP, axis=1)
    assert np.median(err) < 0.1 and np.percentile(err, 95) < 0.2 and err.max() < 1.0


def _extract_all(matcher, frames, masks=None):
    full = np.ones(frames[0].shape, bool)
    return [matcher.extract(g, full if masks is None else masks[k], k, 1.0) for k, g in enumerate(frames)]


def test_tracks_follow_a_known_motion_and_pairs_match_the_tracks_alive_in_both():
    frames = _frames(10)
    matcher = make_matcher("klt_tracks", max_features=400)
    fs = _extract_all(matcher, frames)
    x0, x9 = matcher.match(fs[0], fs[9])
    assert len(x0) >= 0.8 * len(fs[0]), "a smooth shift of 13 px keeps most tracks"
    _assert_moved(x0, x9, 9)
    # a pair matches the tracks alive in both frames, whatever the frames between
    for a, b in ((0, 1), (3, 7), (2, 9)):
        xa, xb = matcher.match(fs[a], fs[b])
        common = np.intersect1d(fs[a].desc, fs[b].desc)
        assert len(xa) == len(common)
        _assert_moved(xa, xb, b - a)
    # a track alive at frame 0 and at frame 9 is alive at every frame between
    assert all(np.isin(np.intersect1d(fs[0].desc, fs[9].desc), f.desc).all() for f in fs)


def test_lost_tracks_are_replaced_only_away_from_the_live_ones():
    frames = _frames(8)
    h, w = frames[0].shape
    masks = [np.ones((h, w), bool) for _ in frames]
    masks[5][:, : w // 2] = False  # the left half is masked out (an object) at frame 5
    matcher = KltTrackMatcher(max_features=300, redetect_share=0.9, min_distance=5)
    fs = _extract_all(matcher, frames, masks)
    before, at = fs[4], fs[5]
    survivors = np.isin(at.desc, before.desc)
    assert (at.xy[:, 0] >= w // 2 - 1).all(), "no feature inside the masked region"
    lost = len(before) - int(survivors.sum())
    assert lost > 0.3 * len(before)
    new = at.xy[~survivors]
    assert len(new) > 0 and (at.desc[~survivors] > before.desc.max()).all(), "new tracks get new ids"
    d = np.linalg.norm(new[:, None] - at.xy[survivors][None], axis=2)
    assert d.min() >= 5 - 0.5, "new corners keep min_distance from every live track"
    # while enough tracks live, nothing is detected again
    quiet = KltTrackMatcher(max_features=300, redetect_share=0.0)
    qs = _extract_all(quiet, frames[:4])
    assert all(np.isin(q.desc, qs[0].desc).all() for q in qs)


def test_frames_extracted_on_threads_in_any_order_give_the_sequential_tracks():
    frames = _frames(10)
    reference = _extract_all(make_matcher("klt_tracks", max_features=300), frames)
    matcher = make_matcher("klt_tracks", max_features=300)
    full = np.ones(frames[0].shape, bool)
    got: dict[int, object] = {}

    def run(k: int) -> None:
        got[k] = matcher.extract(frames[k], full, k, 1.0)

    order = list(range(10))
    random.Random(1).shuffle(order)
    threads = [threading.Thread(target=run, args=(k,)) for k in order]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=60)
    for k, ref in enumerate(reference):
        assert np.array_equal(got[k].desc, ref.desc) and np.array_equal(got[k].xy, ref.xy)


def test_a_failed_frame_restarts_the_tracks_instead_of_blocking_the_next():
    frames = _frames(4)
    matcher = KltTrackMatcher(max_features=200, wait_s=5.0)
    full = np.ones(frames[0].shape, bool)
    a = matcher.extract(frames[0], full, 0, 1.0)
    with pytest.raises(ValueError, match="non-empty"):
        matcher.extract(np.zeros((0, 0), np.uint8), np.zeros((0, 0), bool), 1, 1.0)
    b = matcher.extract(frames[2], full, 2, 1.0)
    assert len(b) > 0 and not np.isin(b.desc, a.desc).any(), "frame 2 starts new tracks"
    assert len(matcher.match(a, b)[0]) == 0


def test_the_first_and_last_frame_are_matched_by_sift():
    frames = _frames(10)
    matcher = make_matcher("klt_tracks", max_features=400, anchors=(0, 9))
    fs = _extract_all(matcher, frames)
    assert fs[0].anchor is not None and fs[9].anchor is not None and fs[5].anchor is None
    x0, x9 = matcher.match(fs[0], fs[9])
    s0, s9 = make_matcher("sift", max_features=400).match(fs[0].anchor, fs[9].anchor)
    assert np.array_equal(x0, s0) and np.array_equal(x9, s9) and len(x0) > 100
    assert np.median(np.linalg.norm(x9 - x0 - 9 * STEP, axis=1)) < 0.1
    # any other pair, one anchor included, matches tracks
    xa, _ = matcher.match(fs[0], fs[5])
    assert len(xa) == len(np.intersect1d(fs[0].desc, fs[5].desc))
