"""Gate windows (``tau_t_window``): a camera that translates and comes back to where it started
reads a first-last ``t_inf`` of about zero, while every pair a few frames apart sees parallax. The
first-last gate alone calls it H and the homography fails on a rigid scene; with the gate windows
(``audit``) the clip is in the gray zone, both families are fitted and the rigid scene passes.
Re-gating from the record reproduces either verdict."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from geocon_core.config import preset
from geocon_core.media import Mp4Writer
from geocon_core.record import write_record
from geocon_core.scoring import Thresholds, gate_decision, load_residuals, regate_clip, score_clip, window_t_inf
from geocon_core.synth import build_scene, render_frame

W, H, OUT = 320, 180, 17  # 17 frames out, 16 back: 33 frames, the last one where the first was


@pytest.fixture(scope="module")
def there_and_back(tmp_path_factory) -> Path:
    """The C3 truck (a rigid scene with strong parallax) driven out and back along its path."""
    scene = build_scene("C3", seed=3, width=W, height=H, num_frames=OUT)
    path = np.concatenate([scene.T_cam_world, scene.T_cam_world[-2::-1]])
    scene = replace(scene, T_cam_world=path)
    out = tmp_path_factory.mktemp("windows") / "there_and_back.mp4"
    rng = np.random.default_rng(0)
    with Mp4Writer(out, W, H, 24) as writer:
        for t in range(scene.num_frames):
            rgb = render_frame(scene, t).rgb.astype(np.float32) + rng.normal(0.0, 2.0, (H, W, 3))
            writer.write(np.clip(rgb, 0, 255).astype(np.uint8))
    return out


@pytest.fixture(scope="module")
def records(there_and_back):
    audit = preset("audit").with_(working_size=(W, H))
    assert audit.tau_t_window > 0
    return {
        "windows": score_clip(there_and_back, audit),
        "first-last": score_clip(there_and_back, audit.with_(tau_t_window=0.0)),
    }


def test_the_windows_see_the_translation_the_first_last_pose_misses(records):
    rec = records["windows"]
    cfg = rec.config
    assert rec.gate.t_inf is not None and rec.gate.t_inf <= cfg.tau_t_low  # out and back: first ~ last
    rows = [(w.start, w.end, w.t_inf, w.pose_present) for w in rec.gate.timeline]
    t_window = window_t_inf(rows, (0, rec.video.num_frames - 1))
    assert t_window is not None and t_window > cfg.tau_t_high  # a window holds the whole way out
    # the rigid scene: in the gray zone, the family that fits (F) is kept and passes
    assert (rec.gate.label, rec.background.model, rec.background.consistent) == ("U", "F", True)
    assert rec.gate.margin is not None and rec.gate.margin < 0
    assert "gate window" in (rec.background.choice_note or "")
    # the first-last gate alone calls it a homography, which the parallax breaks
    alone = records["first-last"]
    assert (alone.gate.label, alone.background.model, alone.background.consistent) == ("H", "H", False)


def test_regating_honours_the_gate_windows(records, tmp_path):
    rec = records["windows"]
    th = Thresholds.of(rec.config)
    v = regate_clip(rec, th)
    assert (v.label, v.model, v.consistent) == (rec.gate.label, rec.background.model, rec.background.consistent)
    off = regate_clip(rec, replace(th, tau_t_window=0.0))
    assert (off.label, off.consistent) == ("H", False)
    write_record(rec, tmp_path / "rec")
    assert regate_clip(load_residuals(tmp_path / "rec"), th).label == "U"


def test_gate_windows_rule():
    rows = [(0, 16, 0.08, True), (8, 24, 0.01, True), (16, 32, None, False), (0, 32, 0.001, True)]
    assert window_t_inf(rows, (0, 32)) == 0.08  # the whole span itself is not a window of it
    assert window_t_inf(rows, (8, 32)) == 0.01 and window_t_inf(rows, (16, 32)) is None
    assert gate_decision(0.001, pose_present=True, t_window=0.08, window=0.03)[0] == "U"
    assert gate_decision(0.001, pose_present=True, t_window=0.02, window=0.03)[0] == "H"
    assert gate_decision(0.001, pose_present=True, t_window=0.08, window=0.0)[0] == "H"  # off
    assert gate_decision(0.2, pose_present=True, t_window=0.0, window=0.03)[0] == "F"  # only H is moved
    with pytest.raises(ValueError, match="gate window"):
        Thresholds(1.0, 0.1, 0.97, 0.6, 0.03, 0.05, -0.1)
