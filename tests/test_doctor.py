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
    assert not rows[("masks", "sam2")].usable and "--masks" in rows[("masks", "sam2")].detail
    assert not rows[("pose", "dust3r")].usable and "--pose-log" in rows[("pose", "dust3r")].detail
    assert rows[("viewer", "rerun (geocon view, --rrd)")].usable == (importlib.util.find_spec("rerun") is not None)


def test_a_missing_package_names_what_to_install(monkeypatch):
    real = commands_doctor._have
    monkeypatch.setattr(commands_doctor, "_have", lambda m: m not in ("torch", "pandas") and real(m))
    rows = _rows(commands_doctor.checks())
    assert not rows[("flow", "raft")].usable
    assert rows[("flow", "raft")].detail == "needs torch: pip install 'geocon[neural]' (torch 2.13.0)"
    assert not rows[("bench", "tables and report")].usable
    assert "needs pandas: pip install 'geocon[bench]'" in rows[("bench", "tables and report")].detail


def test_the_command_prints_the_table():
    res = CliRunner().invoke(app, ["doctor"])
    assert res.exit_code == 0
    for name in ("dis", "raft", "motion", "sam2", "classical", "dust3r", "rerun", "viser", "open3d"):
        assert name in res.stdout
