"""``geocon doctor`` says what is usable here and, for the rest, what to install or pass."""

from __future__ import annotations

import importlib.util
import tomllib
from pathlib import Path

from packaging.requirements import Requirement
from typer.testing import CliRunner

import geocon_core
from geocon_viewer.cli import app, commands_doctor

ROOT = Path(__file__).resolve().parents[1]


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


def test_the_shipped_constraints_are_the_repository_s():
    shipped = Path(geocon_core.__file__).resolve().parent / "constraints.txt"
    assert shipped.read_bytes() == (ROOT / "constraints.txt").read_bytes(), (
        "geocon_core/constraints.txt is out of date: cp constraints.txt geocon_core/constraints.txt"
    )


def test_pyproject_admits_the_constrained_versions_of_every_score_package():
    pins = commands_doctor.parse_constraints((ROOT / "constraints.txt").read_text())
    deps = [Requirement(d) for d in tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]]
    bounded = {commands_doctor._canonical(r.name): r.specifier for r in deps}
    for package in commands_doctor.SCORE_PACKAGES:
        name = commands_doctor._canonical(package)
        assert name in pins, f"constraints.txt does not pin {package}"
        spec = bounded[name]
        assert spec.contains(pins[name]), f"pyproject.toml's {package}{spec} excludes constraints.txt's {pins[name]}"
        assert any(s.operator in ("<", "==") for s in spec), f"{package}{spec} has no upper bound"


def test_parse_constraints_reads_pins_by_canonical_name():
    text = "# a comment\n\nPOT==0.9.7.post1\nopencv_python.headless==5.0.0.93  # trailing\ntorch==2.13.0\n"
    assert commands_doctor.parse_constraints(text) == {
        "pot": "0.9.7.post1",
        "opencv-python-headless": "5.0.0.93",
        "torch": "2.13.0",
    }


def test_each_differing_score_package_is_named_with_both_versions():
    pins = {"numpy": "2.4.6", "opencv-python-headless": "5.0.0.93", "av": "18.1.0", "pot": "0.9.7", "scipy": "1.17.1"}
    installed = {"numpy": "2.4.6+local", "opencv-python-headless": "4.10.0.84", "av": "18.1.0", "scipy": "1.17.1"}
    drift = commands_doctor.version_drift(pins, installed.get)
    # numpy's local label matches the bare pin; pycolmap is not pinned here, so not compared
    assert drift == [
        commands_doctor.VersionDrift("opencv-python-headless", "4.10.0.84", "5.0.0.93"),
        commands_doctor.VersionDrift("POT", None, "0.9.7"),
    ]
    assert drift[0].sentence() == (
        "installed opencv-python-headless 4.10.0.84, the validation report was measured with 5.0.0.93: "
        "scores may differ"
    )
    assert drift[1].sentence() == "POT is not installed, the validation report was measured with 0.9.7"
    assert commands_doctor.version_drift(pins, {**installed, "numpy": "2.4.6", "POT": "0.9.7"}.get) == drift[:1]


def test_the_command_says_which_versions_differ(monkeypatch):
    text = (ROOT / "constraints.txt").read_text().replace(f"numpy=={commands_doctor._version('numpy')}", "numpy==1.1")
    monkeypatch.setattr(commands_doctor, "constraints_source", lambda: (text, "constraints.txt"))
    res = CliRunner().invoke(app, ["doctor"])
    assert res.exit_code == 0
    expected = (
        f"installed numpy {commands_doctor._version('numpy')}, the validation report was measured with 1.1: "
        "scores may differ"
    )
    assert expected in res.stdout
    assert "opencv-python-headless" not in res.stdout.split("differ from the validation report")[1]


def test_without_a_repository_the_shipped_copy_is_compared(monkeypatch, tmp_path):
    site = tmp_path / "site-packages" / "geocon_core"
    site.mkdir(parents=True)
    monkeypatch.setattr(geocon_core, "__file__", str(site / "__init__.py"))
    text, source = commands_doctor.constraints_source()
    assert source == "constraints.txt shipped in the geocon package"
    assert text == (ROOT / "constraints.txt").read_text()
    assert commands_doctor.version_drift(commands_doctor.parse_constraints(text)) == []


def test_missing_extras_are_optional_and_a_missing_core_part_fails(monkeypatch):
    real = commands_doctor._have
    extras = ("torch", "sam2", "mini_dust3r", "open3d", "pandas", "pyarrow", "matplotlib")
    monkeypatch.setattr(commands_doctor, "_have", lambda m: m not in extras and real(m))
    res = CliRunner().invoke(app, ["doctor"])
    assert res.exit_code == 0 and "no (optional)" in res.stdout
    assert "geocon[neural]" in res.stdout and "geocon[bench]" in res.stdout  # printed, not taken as markup
    monkeypatch.setattr(commands_doctor, "_have", lambda m: m != "ot" and real(m))
    res = CliRunner().invoke(app, ["doctor"])
    assert res.exit_code == 2
    assert "the core install is incomplete (transport (AdaDFRC-W2))" in res.output
