"""``geocon doctor`` says what is usable here and, for the rest, what to install or pass."""

from __future__ import annotations

import importlib.util

from typer.testing import CliRunner

from geocon_viewer.cli import app, commands_doctor


def _rows(checks) -> dict[tuple[str, str], commands_doctor.Check]:
    return {(c.group, c.name): c for c in checks}


def test_each_backend_is_reported_as_it_is_on_this_machine():
    rows = _rows(commands_doctor.checks())
    assert rows[("flow", "dis")].usable and rows[("masks", "motion")].usable and rows[("pose", "classical")].usable
    torch_here = importlib.util.find_spec("torch") is not None
    assert rows[("flow", "raft")].usable == torch_here
    sam2_here = torch_here and all(importlib.util.find_spec(m) is not None for m in ("sam2", "hydra", "iopath"))
    assert rows[("masks", "sam2")].usable == sam2_here
    assert ("--masks sam2 --sam2-checkpoint" if sam2_here else "pip install") in rows[("masks", "sam2")].detail
    dust3r_here = torch_here and all(
        importlib.util.find_spec(m) is not None for m in ("mini_dust3r", "einops", "beartype", "huggingface_hub")
    )
    assert rows[("pose", "dust3r")].usable == dust3r_here
    assert ("--pose dust3r --dust3r-checkpoint" if dust3r_here else "--pose-log") in rows[("pose", "dust3r")].detail
    assert rows[("viewer", "rerun (geocon view, --rrd)")].usable == (importlib.util.find_spec("rerun") is not None)


def test_a_missing_package_names_what_to_install(monkeypatch):
    real = commands_doctor._have
    monkeypatch.setattr(commands_doctor, "_have", lambda m: m not in ("torch", "pandas") and real(m))
    rows = _rows(commands_doctor.checks())
    assert not rows[("flow", "raft")].usable
    assert rows[("flow", "raft")].detail == "needs torch: pip install 'geocon[neural]' (torch 2.13.0)"
    assert not rows[("masks", "sam2")].usable and rows[("masks", "sam2")].detail == rows[("flow", "raft")].detail
    monkeypatch.setattr(commands_doctor, "_have", lambda m: m != "sam2" and real(m))
    sam2 = _rows(commands_doctor.checks())[("masks", "sam2")]
    assert not sam2.usable
    assert sam2.detail.startswith("needs sam2: ") and "--no-deps sam2==1.1.0" in sam2.detail
    assert not rows[("pose", "dust3r")].usable and rows[("pose", "dust3r")].detail.startswith(
        rows[("flow", "raft")].detail
    )
    monkeypatch.setattr(commands_doctor, "_have", lambda m: m != "mini_dust3r" and real(m))
    dust3r = _rows(commands_doctor.checks())[("pose", "dust3r")]
    assert not dust3r.usable and dust3r.detail.startswith(
        "needs mini_dust3r: pip install 'geocon[neural]' && pip install --no-deps mini-dust3r"
    )
    assert "--pose-log" in dust3r.detail
    assert not rows[("bench", "tables and report")].usable
    assert "needs pandas: pip install 'geocon[bench]'" in rows[("bench", "tables and report")].detail


def test_the_command_prints_the_table():
    res = CliRunner().invoke(app, ["doctor"])
    assert res.exit_code == 0
    for name in ("dis", "raft", "motion", "sam2", "classical", "dust3r", "rerun", "viser", "open3d"):
        assert name in res.stdout
