"""`geocon score` and `geocon presets` as a user runs them."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from geocon_core.synth import ClipPlan, write_clip
from geocon_viewer.cli import app

runner = CliRunner()


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    out = tmp_path_factory.mktemp("cli")
    write_clip(ClipPlan("C3"), out, seed=2, width=320, height=180, num_frames=8)
    return out / "c3_translation.mp4"


@pytest.mark.full
def test_json_summary_has_the_documented_keys_and_is_stable(clip, tmp_path):
    args = ["score", str(clip), "--json", "--preset", "strict"]
    a = runner.invoke(app, [*args, "--out", str(tmp_path / "a")])
    b = runner.invoke(app, [*args, "--out", str(tmp_path / "b")])
    assert a.exit_code == 0, a.output
    assert a.stdout == b.stdout, "the same clip scored twice gives identical JSON"
    s = json.loads(a.stdout)
    assert s["clip"] == str(clip)
    assert s["gate"]["label"] in ("H", "F", "U") and s["gate"]["model"] in ("H", "F")
    for key in ("t_inf", "pose_present", "margin"):
        assert key in s["gate"]
    for key in ("ir", "ge", "valid_pairs", "consistent", "tau_f_px"):
        assert key in s["background"]
    assert set(s["per_gap"]) == {"1", "4", "8"} and {"ir", "ge"} <= set(s["per_gap"]["1"])
    assert s["category"] == "C3" and len(s["config_hash"]) == 16
    assert (tmp_path / "a" / "record.json").read_bytes() == (tmp_path / "b" / "record.json").read_bytes()
    assert s["gate"]["label"] == "F"
    # dense clouds only when asked (or with --rrd): they change no score, so the record holds the same summary
    assert json.loads((tmp_path / "a" / "record.json").read_text())["dense"] == []
    c = runner.invoke(app, [*args, "--out", str(tmp_path / "c"), "--dense"])
    assert c.exit_code == 0, c.output
    assert c.stdout == a.stdout
    dense = json.loads((tmp_path / "c" / "record.json").read_text())["dense"]
    assert [(d["start"], d["end"]) for d in dense] == [(0, 7)] and dense[0]["points"] > 1000


def test_readable_summary(clip, tmp_path):
    res = runner.invoke(app, ["score", str(clip), "--out", str(tmp_path)])
    assert res.exit_code == 0, res.output
    for word in ("gate", "background", "coverage", "verdict", "t_inf"):
        assert word in res.stdout


def _file(path, data: bytes):
    path.write_bytes(data)
    return path


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda d: d / "missing.mp4", "no such file"),
        (lambda d: _file(d / "notes.mp4", b"not a video"), "cannot be decoded"),
        (lambda d: _file(d / "bytes.mp4", b"\x00\x01garbage" * 100), "bytes.mp4"),
    ],
)
def test_unusable_input_exits_2_with_one_sentence(tmp_path, make, message):
    path = make(tmp_path)
    res = runner.invoke(app, ["score", str(path), "--out", str(tmp_path / "out")])
    assert res.exit_code == 2, res.output
    assert "error:" in res.output and message in res.output
    assert "Traceback" not in res.output
    assert len([line for line in res.output.strip().splitlines() if line.strip()]) <= 2


def test_one_frame_is_unusable(tmp_path):
    import cv2
    import numpy as np

    folder = tmp_path / "frames"
    folder.mkdir()
    cv2.imwrite(str(folder / "0.png"), np.full((64, 64, 3), 128, np.uint8))
    res = runner.invoke(app, ["score", str(folder)])
    assert res.exit_code == 2 and "at least 2" in res.output


def test_unknown_names_list_the_valid_ones(clip):
    res = runner.invoke(app, ["score", str(clip), "--preset", "quick"])
    assert res.exit_code == 2 and "valid: paper, strict, audit, fast" in res.output
    res = runner.invoke(app, ["score", str(clip), "--matcher", "surf"])
    assert res.exit_code == 2 and "valid: sift, sift_octaves, orb, klt" in res.output


def test_presets_are_listed():
    res = runner.invoke(app, ["presets"])
    assert res.exit_code == 0 and "paper" in res.stdout and "strict" in res.stdout and "gaps" in res.stdout


def test_pose_log_drives_the_gate(clip, tmp_path):
    gt = clip.with_suffix(".gt.json")
    res = runner.invoke(app, ["score", str(clip), "--json", "--pose-log", str(gt), "--out", str(tmp_path)])
    assert res.exit_code == 0, res.output
    s = json.loads(res.stdout)
    truth = json.loads(gt.read_text())
    assert s["gate"]["t_inf"] == pytest.approx(truth["t_inf"]) and s["gate"]["backend"] == "log"
    bad = tmp_path / "bad.json"
    bad.write_text('{"format": "nope"}')
    res = runner.invoke(app, ["score", str(clip), "--pose-log", str(bad)])
    assert res.exit_code == 2 and "error:" in res.output
