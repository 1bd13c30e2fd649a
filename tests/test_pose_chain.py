"""The gate's chain fallback (:mod:`geocon_core.pose.chain`): hops, exact composition, broken
chains, and the decision on real footage with known camera poses."""

from __future__ import annotations

import numpy as np
import pytest

from geocon_core.config import preset
from geocon_core.geometry import invert_pose, make_pose, rotation_xyz
from geocon_core.pose import ClassicalPose, PoseEstimate, chain_hops, compose_chain
from geocon_core.scoring import score_clip

from .conftest import sift_matches
from .test_pose import RE10K, gate, read_re10k, real_clip_table


def _present(T: np.ndarray, method: str = "essential") -> PoseEstimate:
    return PoseEstimate(
        pose_present=True,
        t_inf=float(np.abs(T[:3, 3]).max()),
        T_cam0_camT=T,
        method=method,
        reason=None,
        n_matches=100,
        n_inliers=80,
        rotation_deg=None,
        parallax_px=None,
        focal_px=500.0,
    )


FAILED = PoseEstimate(False, None, None, "none", "too_few_matches", 20, 0, None, None, 500.0)


def test_hops_cover_the_clip_and_merge_a_short_tail():
    assert chain_hops(16, 4) == [(0, 4), (4, 8), (8, 12), (12, 15)]
    assert chain_hops(18, 4) == [(0, 4), (4, 8), (8, 12), (12, 17)]  # a 1-frame tail joins the last hop
    assert chain_hops(5, 4) == [] and chain_hops(2, 1) == []
    for n, hop in [(16, 4), (48, 4), (25, 8), (100, 7)]:
        hops = chain_hops(n, hop)
        assert hops[0][0] == 0 and hops[-1][1] == n - 1
        assert all(a[1] == b[0] for a, b in zip(hops, hops[1:], strict=False))
        assert all(hop // 2 <= e - s <= 2 * hop for s, e in hops)


def test_exact_hop_poses_compose_to_the_first_last_pose():
    # a camera turning and translating at constant rates, in front of a scene at unit distance
    n, hop = 16, 4
    world = [make_pose(rotation_xyz(2.0 * t, 0.5 * t), np.array([0.01 * t, -0.004 * t, 0.006 * t])) for t in range(n)]
    rel = [invert_pose(world[a]) @ world[b] for a, b in chain_hops(n, hop)]  # T_cam_a_cam_b
    hops = [(w, _present(T)) for w, T in zip(chain_hops(n, hop), rel, strict=True)]
    est = compose_chain(hops, n, FAILED, min_share=0.5)
    truth = invert_pose(world[0]) @ world[n - 1]
    assert est is not None and est.method == "chain" and est.pose_present
    np.testing.assert_allclose(est.T_cam0_camT, truth, atol=1e-12)
    assert est.t_inf == pytest.approx(np.abs(truth[:3, 3]).max())
    assert "too_few_matches" in (est.note or "") and "4 hops" in (est.note or "")
    assert PoseEstimate.from_dict(est.to_dict()).note == est.note


def test_a_broken_chain_uses_its_largest_run_and_needs_enough_span():
    step = make_pose(np.eye(3), np.array([0.02, 0.0, 0.0]))
    hops = chain_hops(17, 4)  # four hops
    ests = [_present(step), FAILED, _present(step), _present(step)]
    est = compose_chain(list(zip(hops, ests, strict=True)), 17, FAILED, min_share=0.5)
    assert est is not None and est.t_inf == pytest.approx(0.04)  # the run of two hops
    assert "3/4 hops" in (est.note or "")
    assert compose_chain(list(zip(hops, ests, strict=True)), 17, FAILED, min_share=0.8) is None
    assert compose_chain(list(zip(hops, [FAILED] * 4, strict=True)), 17, FAILED, min_share=0.1) is None


def test_rotation_hops_keep_their_parallax_bound():
    hops = chain_hops(9, 4)
    rot = _present(make_pose(rotation_xyz(1.0, 0.0), np.zeros(3)), method="rotation")
    rot = PoseEstimate(**{**rot.__dict__, "t_inf": 0.003})
    est = compose_chain([(h, rot) for h in hops], 9, FAILED, min_share=0.5)
    assert est is not None and est.t_inf == pytest.approx(0.003)


@pytest.mark.slow
def test_realestate10k_chains_decide_the_gate_where_first_last_fails():
    """Real dolly shots (384x256, 16 frames) whose first and last frames keep too few matches:
    the chained classical estimate, with the true intrinsics, gates like the true pose."""
    clips = sorted(p for p in RE10K.glob("*.mp4") if not p.stem.endswith("_svdxt_ref"))
    if not clips:
        pytest.skip(f"no RealEstate10K clips under {RE10K}")
    backend = ClassicalPose()
    decided = agree = 0
    lines = []
    for video in clips:
        pose_file = RE10K / f"{video.stem}_pose.txt"
        frames, K, _ = read_re10k(video, pose_file)
        n = len(frames)
        truth = real_clip_table(video, pose_file)[-1]["truth"]
        first_last = backend.estimate(*sift_matches(frames[0], frames[-1]), K)
        hops = [((a, b), backend.estimate(*sift_matches(frames[a], frames[b]), K)) for a, b in chain_hops(n, 4)]
        est = first_last if first_last.pose_present else compose_chain(hops, n, first_last, min_share=0.5)
        got = None if est is None else est.t_inf
        lines.append(f"{video.stem}: truth {truth:.3f} ({gate(truth)}), chain {got} ({est and est.method})")
        if gate(truth) != "U":
            decided += 1
            agree += got is not None and gate(got) == gate(truth)
    print("\n".join(lines))
    assert decided >= 4 and agree >= decided - 1, "\n".join(lines)


@pytest.mark.full
def test_the_scorer_gates_a_real_dolly_through_the_chain():
    """A RealEstate10K dolly (16 frames, 384x256; true first-last t_inf 0.61): its first and last
    frames keep too few matches for a pose; the audit preset's chain gates it F, and says so."""
    clip = RE10K / "0c11dbe781b1c11c.mp4"
    if not clip.is_file():
        pytest.skip(f"{clip} is missing")
    cfg = preset("audit").with_(masks="none", scales=(1.0,), gaps=(1,))
    rec = score_clip(clip, cfg)
    pose = rec.gate.pose
    assert pose.method == "chain" and pose.pose_present and rec.gate.label == "F"
    assert "first-last pose failed" in (pose.note or "") and any("chain" in w for w in rec.warnings)
    assert rec.summary()["gate"]["pose_present"] is True
    paper = score_clip(clip, cfg.with_(chain_hop=0))  # the paper's convention: fail->F without a pose
    assert not paper.gate.pose.pose_present and paper.gate.pose.method == "none"
