"""Each piece of the scorer's work is done once: a pair that the fits and the chain both need is
matched once, the chain's hop poses are estimated only when the first-last pose fails, objects
are scored at the scales their verdict reads, and none of it changes a number."""

from __future__ import annotations

from collections import Counter

import pytest

from geocon_core.config import preset
from geocon_core.geometry import SiftMatcher
from geocon_core.pose import ClassicalPose
from geocon_core.scoring import score_clip

from .test_pose import RE10K


def _counting(monkeypatch: pytest.MonkeyPatch) -> Counter:
    """Count the calls of SIFT matching and of the classical pose estimate."""
    calls: Counter = Counter()
    match, estimate = SiftMatcher.match, ClassicalPose.estimate

    def counted_match(self, a, b):
        calls["match", a.frame, b.frame, a.scale] += 1
        return match(self, a, b)

    def counted_estimate(self, *args, **kwargs):
        calls["estimate"] += 1
        return estimate(self, *args, **kwargs)

    monkeypatch.setattr(SiftMatcher, "match", counted_match)
    monkeypatch.setattr(ClassicalPose, "estimate", counted_estimate)
    return calls


def _summary(rec) -> dict:
    d = rec.summary()
    d.pop("timing", None)
    return d


@pytest.mark.full
def test_a_pair_is_matched_once_and_hops_wait_for_a_failed_pose(synth_dir, monkeypatch):
    """C3 (a translating camera, 24 frames): the first-last pose succeeds, so no hop pose is
    estimated; every gap-1 pair at the top scale is matched once though the chain asks for it too."""
    clip = synth_dir / "c3_translation.mp4"
    cfg = preset("audit").with_(masks="none", scales=(0.5, 1.0), gaps=(1, 4), multiview=preset("paper").multiview)
    calls = _counting(monkeypatch)
    rec = score_clip(clip, cfg)
    n = rec.video.num_frames
    assert rec.gate.pose.pose_present and rec.gate.pose.method != "chain"
    matches = {k: v for k, v in calls.items() if k[0] == "match"}
    assert max(matches.values()) == 1, [k for k, v in matches.items() if v > 1]
    assert all(("match", t, t + 1, 1.0) in matches for t in range(n - 1))
    windows = len([w for w in rec.gate.timeline])  # the gate windows, each posed once
    assert calls["estimate"] == windows + 1  # and the first-last pose; no hop


def test_a_failed_first_last_pose_estimates_its_hops(monkeypatch):
    """The RealEstate10K dolly whose first and last frames share too few matches: its hops are
    estimated after all (one each) and compose the pose that gates it."""
    clip = RE10K / "0c11dbe781b1c11c.mp4"
    if not clip.is_file():
        pytest.skip(f"{clip} is missing")
    cfg = preset("audit").with_(masks="none", scales=(1.0,), gaps=(1,), multiview=preset("paper").multiview)
    calls = _counting(monkeypatch)
    rec = score_clip(clip, cfg)
    n = rec.video.num_frames
    assert rec.gate.pose.method == "chain" and rec.gate.pose.pose_present
    hops = n - 1
    assert calls["estimate"] >= hops + 1  # every hop, the first-last pose, the gate windows
    assert max(v for k, v in calls.items() if k[0] == "match") == 1


@pytest.mark.full
def test_objects_at_the_top_scale_keep_the_headline_scores(synth_dir, scored_clip):
    """``object_scales = "top"`` scores objects at the largest scale only: the objects, their
    headline AdaDFRC, AdaP90 and every other number of the record are those of scoring all scales."""
    clip = synth_dir / "c4_objects.mp4"
    base = preset("paper").with_(scales=(0.5, 1.0))
    every = scored_clip(clip, base)
    top = score_clip(clip, base.with_(object_scales="top"))
    assert every.objects and [o.object_id for o in top.objects] == [o.object_id for o in every.objects]
    for a, b in zip(top.objects, every.objects, strict=True):
        assert (a.adadfrc, a.adadfrc_w2, a.adap90, a.frames) == (b.adadfrc, b.adadfrc_w2, b.adap90, b.frames)
        assert [p.scale for p in a.per_scale] == [1.0] and len(b.per_scale) == 2
    assert {e.scale for e in top.object_entries} == {1.0}
    a, b = _summary(top), _summary(every)
    for d in (a, b):
        d.pop("config", None)
        d.pop("config_hash", None)
        d.pop("objects", None)
    assert a == b


def test_pot_leaves_the_array_libraries_alone():
    """Scoring with objects imports POT without its optional backends (PyTorch alone would add
    about 180 MiB and two seconds to every clip)."""
    import subprocess
    import sys

    code = (
        "import sys; from geocon_core.scoring.rigidity import quiet_pot_backends; quiet_pot_backends(); import ot; "
        "print('torch' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"
