"""`geocon synth` and `geocon demo` as a user runs them."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from geocon_core.synth import FAMILIES, load_ground_truth
from geocon_viewer.cli import app

runner = CliRunner()


def digest(folder: Path) -> dict[str, str]:
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def test_synth_all_writes_every_family_and_failure_variant(tmp_path):
    res = runner.invoke(app, ["synth", "all", "--out", str(tmp_path), "--frames", "4", "--size", "160x96", "--json"])
    assert res.exit_code == 0, res.output
    rows = json.loads(res.stdout)
    families = {r["family"] for r in rows if r["failure"] is None}
    kinds = {r["failure"]["kind"] for r in rows if r["failure"]}
    assert families == set(FAMILIES)
    assert kinds == {
        "breathing",
        "slide",
        "slide_along",
        "slide_across",
        "missing_parallax",
        "elastic",
        "boiling",
        "letterbox",
    }
    for row in rows:
        cid = row["clip_id"]
        gt = load_ground_truth(tmp_path / f"{cid}.gt.json")
        assert (tmp_path / f"{cid}.mp4").stat().st_size > 0
        assert (tmp_path / f"{cid}.meta.json").is_file()
        assert len(list((tmp_path / gt.masks_path).glob("*.png"))) == 4
        assert gt.expected_gate == ("F" if gt.family in ("C3", "C5", "C6") else "H")
    assert not list(tmp_path.glob(".*part")), "no temporary files are left behind"


def test_same_seed_gives_identical_bytes(tmp_path):
    """16 frames, so that the encoder's look-ahead is in play (with x264's macroblock tree on, two
    renders out of three differed here)."""
    args = ["synth", "C3", "--frames", "16", "--size", "320x180", "--failure", "breathing", "--severity", "3"]
    for name, seed in (("a", "7"), ("b", "7"), ("d", "7"), ("c", "8")):
        res = runner.invoke(app, [*args, "--out", str(tmp_path / name), "--seed", seed])
        assert res.exit_code == 0, res.output
    a, b, d, c = (digest(tmp_path / n) for n in "abdc")
    assert a == b == d and len(a) == 3 + 16
    assert a["c3_translation__breathing-s3.mp4"] != c["c3_translation__breathing-s3.mp4"]


def test_bad_input_gives_clear_errors(tmp_path):
    res = runner.invoke(app, ["synth", "C9", "--out", str(tmp_path)])
    assert res.exit_code == 2 and "unknown family 'C9'" in res.output and "c3_translation" in res.output
    res = runner.invoke(app, ["synth", "C1", "--out", str(tmp_path), "--failure", "melt"])
    assert res.exit_code == 2 and "valid: breathing, slide" in res.output
    res = runner.invoke(app, ["synth", "C1", "--out", str(tmp_path), "--size", "641x360"])
    assert res.exit_code == 2 and "even width" in res.output
    res = runner.invoke(app, ["synth", "C1", "--out", str(tmp_path), "--severity", "2"])
    assert res.exit_code == 2 and "--severity needs --failure" in res.output
    assert not any(tmp_path.iterdir())


def test_failure_listing():
    res = runner.invoke(app, ["synth-failures"])
    assert res.exit_code == 0 and "missing_parallax" in res.output


@pytest.mark.slow
def test_demo(tmp_path):
    res = runner.invoke(app, ["demo", "--out", str(tmp_path)])
    assert res.exit_code == 0, res.output
    gt = load_ground_truth(tmp_path / "c4_objects__elastic-s4.gt.json")
    assert [o.rigid for o in gt.objects] == [False, True]
    assert "NON-RIGID" in res.output and "t_inf = 0.000" in res.output
    record = json.loads((tmp_path / "record" / "record.json").read_text())
    scores = {o["object_id"]: o["adadfrc"] for o in record["objects"]}
    assert scores[1] > 2 * scores[2], scores  # the elastic disc is the less rigid one
    assert record["category"]["label"] == "C4" and record["summary"]["background"]["consistent"]
