"""Independent motion in the background fits, the still-camera test of the gate and chains of hops
of several lengths, each against planted truth."""

from __future__ import annotations

import numpy as np
import pytest

from geocon_core.geometry import (
    fit_homography,
    independent_motion,
    inlier_stats,
    segment_inlier_stats,
    with_independent,
)
from geocon_core.pose import PoseEstimate, chain_hops, chain_lengths, compose_chain, failure, select_hops, still_share

W, H = 640, 360


def _grid(rng: np.random.Generator, n: int = 900) -> np.ndarray:
    return np.column_stack([rng.uniform(10, W - 10, n), rng.uniform(10, H - 10, n)])


def test_a_mover_the_masks_missed_is_independent_and_only_it():
    rng = np.random.default_rng(0)
    x1 = _grid(rng)
    x2 = x1 + rng.normal(0, 0.2, x1.shape)  # a still background, matcher noise
    mover = np.hypot(x1[:, 0] - 200, x1[:, 1] - 180) < 60  # a compact region moving on its own
    x2[mover] += (7.0, -3.0)
    fit = fit_homography(x1, x2, tau=2.0, seed=0)
    assert not fit.inliers[mover].any() and fit.inliers[~mover].all()
    ind = independent_motion(x1, fit.residuals_px, fit.inliers, neighbours=8, jump=4.0)
    assert np.array_equal(ind, mover)
    judged = with_independent(fit, ind, min_inliers=30, max_share=0.5)
    assert fit.ir == pytest.approx(1 - mover.mean())
    assert judged.ir == 1.0 and judged.valid and judged.n_independent == int(mover.sum())
    # a pair whose matches mostly move on their own cannot be judged
    most = with_independent(fit, np.arange(len(x1)) < 600, min_inliers=30, max_share=0.5)
    assert not most.valid and most.reason == "independent_motion"


def test_a_bending_background_is_not_independent_motion():
    """A smooth non-projective warp (breathing, rubber sheet): outliers lie just past the
    threshold beside inliers almost as far off; none jumps away from its neighbourhood."""
    rng = np.random.default_rng(1)
    x1 = _grid(rng)
    u, v = x1[:, 0] / W, x1[:, 1] / H
    bend = 4.0 * np.sin(2 * np.pi * u) * np.sin(np.pi * v)  # up to 4 px, smooth
    x2 = x1 + np.column_stack([bend, 0.5 * bend]) + rng.normal(0, 0.2, x1.shape)
    fit = fit_homography(x1, x2, tau=2.0, seed=0)
    assert (~fit.inliers).sum() > 50  # it does fail the inlier rule
    ind = independent_motion(x1, fit.residuals_px, fit.inliers, neighbours=8, jump=4.0)
    assert ind.sum() <= 0.02 * (~fit.inliers).sum()
    assert with_independent(fit, ind, min_inliers=30, max_share=0.5).ir == pytest.approx(fit.ir, abs=0.01)


def test_excluded_matches_leave_both_counts_alike_per_pair_and_in_segments():
    rng = np.random.default_rng(2)
    sizes = [40, 0, 75, 33]
    offsets = np.concatenate([[0], np.cumsum(sizes)])
    res = rng.exponential(1.5, offsets[-1]).astype(np.float32)
    exclude = (rng.random(offsets[-1]) < 0.2) & (res > 2.0)
    k, n, ge = segment_inlier_stats(res, res, offsets, 2.0, exclude=exclude)
    for i in range(len(sizes)):
        sl = slice(offsets[i], offsets[i + 1])
        inl, ir, g = inlier_stats(res[sl], res[sl], 2.0, exclude=exclude[sl])
        assert k[i] == inl.sum() and n[i] == sizes[i] - exclude[sl].sum()
        assert (ir is None and n[i] == 0) or ir == k[i] / n[i]
        assert (g is None and np.isnan(ge[i])) or g == ge[i]


# --- the still-camera test ---------------------------------------------------------------------


def _texture(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    import cv2

    img = rng.integers(0, 256, (H // 8, W // 8), dtype=np.uint8)
    return cv2.resize(img, (W, H), interpolation=cv2.INTER_CUBIC)


def test_a_still_camera_with_a_large_mover_is_still_and_a_slow_pan_is_not():
    bg = _texture(3)
    first, last = bg.copy(), bg.copy()
    first[60:300, 100:300] = _texture(4)[60:300, 100:300]  # a large mover: 40% of the frame...
    last[60:300, 300:500] = _texture(4)[60:300, 100:300]  # ...that moved 200 px
    test = still_share(first, last, still_px=1.0)
    assert test.share > 0.4 and test.motion_px < 0.5
    mover = np.zeros((H, W), bool)
    mover[60:300, 100:500] = True
    assert still_share(first, last, still_px=1.0, ignore=mover).share > 0.9  # the rest does not move at all
    # the still map is the background: outside the mover's two places (a margin for the flow's patch)
    inner = np.zeros((H, W), bool)
    inner[80:280, 120:480] = True
    assert test.still[~mover].mean() > 0.95 and test.still[inner].mean() < 0.5
    panned = np.roll(bg, 3, axis=1)  # the camera turned by 3 px
    assert still_share(bg, panned, still_px=1.0).share < 0.05


# --- chains of hops of several lengths ---------------------------------------------------------


def _pose(t: float) -> PoseEstimate:
    T = np.eye(4)
    T[0, 3] = t
    return PoseEstimate(True, t, T, "essential", None, 100, 80, 0.0, 2.0, 500.0)


FAILED = failure("too_few_matches", 5, 500.0)


def test_the_chain_takes_the_longest_hop_with_a_pose_at_each_frame():
    assert chain_lengths(1, 8) == [8, 4, 2, 1] and chain_lengths(1, 0) == [1] and chain_lengths(2, 5) == [4, 2]
    n = 17
    hops = {w: _pose(0.01 * (w[1] - w[0])) for L in (8, 4, 1) for w in chain_hops(n, L)}
    hops[(8, 16)] = FAILED  # the second long hop has no pose: 4-frame hops there
    chosen = select_hops(hops, n)
    assert [w for w, _ in chosen] == [(0, 8), (8, 12), (12, 16)]
    est = compose_chain(chosen, n, FAILED, min_share=0.5)
    assert est is not None and est.t_inf == pytest.approx(0.16)
    # where no hop has a pose the chain is cut with the shortest hop from there
    hops = {w: (FAILED if w[0] < 4 else _pose(0.01)) for w in chain_hops(9, 1)}
    assert [w for w, _ in select_hops(hops, 9)] == [(a, a + 1) for a in range(8)]


@pytest.mark.full
def test_movers_the_masks_miss_leave_a_still_camera_consistent(synth_clips):
    """A still camera with two movers scored without masks: their matches leak into the background
    (IR below the gate); audit leaves them out (they jump away from the still background, and they
    moved between the first and last frame), and counts them."""
    from dataclasses import replace

    from geocon_core.config import IndependentConfig, preset
    from geocon_core.scoring import score_clip
    from geocon_core.synth import ClipPlan

    folder = synth_clips([ClipPlan("C4")], seed=2, width=640, height=360, num_frames=24)
    clip = folder / f"{ClipPlan('C4').clip_id}.mp4"
    audit = preset("audit").with_(masks="none")
    leaky = score_clip(clip, replace(audit, still_share=0.0, independent=IndependentConfig()))
    assert leaky.background.consistent is False and leaky.background.ir < audit.ir_gate
    rec = score_clip(clip, audit)
    assert rec.gate.label == "H" and rec.background.consistent is True and rec.background.ir == 1.0
    assert any(w.startswith("independent motion:") for w in rec.warnings)
    moved = sum(p.h.n_independent for p in rec.pairs if p.h is not None)
    assert moved > 0 and rec.matches.h_ind.sum() == moved


@pytest.mark.full
def test_a_failing_background_whose_matches_moved_on_their_own_is_not_judged(synth_clips, tmp_path):
    """The untrusted share: a background that fails while at least ``untrusted_share`` of its
    matches moved on their own is not judged; one that passes keeps its verdict. The share is the
    record's, and re-gating (the stored per-match flags, also from the saved residuals) reads the
    same share and gives the same verdict."""
    from dataclasses import replace

    from geocon_core.config import preset
    from geocon_core.record import write_record
    from geocon_core.scoring import Thresholds, load_residuals, regate_clip, regate_family, score_clip
    from geocon_core.synth import ClipPlan

    folder = synth_clips([ClipPlan("C4")], seed=2, width=640, height=360, num_frames=24)
    audit = preset("audit").with_(masks="none")  # the movers' matches are left to the independent-motion rule
    rec = score_clip(folder / f"{ClipPlan('C4').clip_id}.mp4", replace(audit, still_share=0.0))
    share = rec.background.chosen.independent_share
    assert 0.0 < share < 1.0 and rec.background.consistent is True  # passing: the share changes nothing
    th = Thresholds.of(rec.config)
    assert th.untrusted_share == 0.5
    assert regate_family(rec, rec.background.model, th.tau(rec.background.model)).independent_share == share
    # made to fail (a GE gate no fit meets): not judged from the share up, failing under it
    strict = replace(th, ge_gate=1e-6)
    at, under = replace(strict, untrusted_share=share), replace(strict, untrusted_share=min(1.0, share * 1.01))
    v = regate_clip(rec, at)
    assert (v.consistent, v.untrusted, v.report_margin) == (None, True, None)
    assert (regate_clip(rec, under).consistent, regate_clip(rec, under).untrusted) == (False, False)
    assert regate_clip(rec, replace(strict, untrusted_share=0.0)).consistent is False  # off
    write_record(rec, tmp_path / "rec")
    assert regate_clip(load_residuals(tmp_path / "rec"), at).untrusted is True
