"""``scripts/test.sh`` reads ``--quick`` wherever it stands and hands every other argument to
pytest as it was given. The script runs here in its plan mode (``GEOCON_TEST_PLAN=1``: it prints
the tier and the pytest arguments and stops before any set-up), from a copy beside a stand-in
``bootstrap.sh`` that fails at once: a script that ignored the plan mode would fail there, and never
set anything up or run the suite."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "test.sh"
RUN_LIMIT_S = 20
"""The plan mode prints its plan at once; a run still going after this long fails."""


def plan(tmp_path: Path, *args: str) -> tuple[str, list[str]]:
    """(tier, pytest arguments) that ``bash scripts/test.sh ARGS`` plans."""
    scripts = tmp_path / "scripts"
    scripts.mkdir(exist_ok=True)
    shutil.copyfile(SCRIPT, scripts / "test.sh")
    (scripts / "bootstrap.sh").write_text("echo 'bootstrap ran' >&2\nexit 3\n")
    env = {k: v for k, v in os.environ.items() if k != "GEOCON_WHEEL_CHECK"} | {"GEOCON_TEST_PLAN": "1"}
    res = subprocess.run(
        ["bash", str(scripts / "test.sh"), *args],
        capture_output=True,
        text=True,
        env=env,
        timeout=RUN_LIMIT_S,
        stdin=subprocess.DEVNULL,
    )
    assert res.returncode == 0 and "bootstrap ran" not in res.stderr, res.stderr
    lines = res.stdout.splitlines()
    assert lines and lines[0].startswith("tier: "), res.stdout
    passed = [line.removeprefix("pytest arg: ") for line in lines[1:]]
    assert all(line.startswith("pytest arg: ") for line in lines[1:]), res.stdout
    return lines[0].removeprefix("tier: "), passed


@pytest.mark.parametrize(
    ("args", "tier", "passed"),
    [
        ((), "full", []),
        (("--quick",), "quick", []),
        (("-x", "--quick"), "quick", ["-x"]),
        (("--quick", "-x"), "quick", ["-x"]),
        (("tests/test_x.py", "-x", "--quick", "-k", "fit"), "quick", ["tests/test_x.py", "-x", "-k", "fit"]),
        (("-k", "synth and not slow", "--quick"), "quick", ["-k", "synth and not slow"]),
        (("--quick", "--quick"), "quick", []),
        (("-m", "slow"), "full", ["-m", "slow"]),
        (("--quickly",), "full", ["--quickly"]),
        (("-k", ""), "full", ["-k", ""]),
    ],
    ids=["none", "quick-alone", "quick-last", "quick-first", "quick-in-the-middle", "an-argument-with-spaces",
         "quick-twice", "a-marker", "another-word", "an-empty-argument"],
)  # fmt: skip
def test_quick_is_read_anywhere_and_the_rest_goes_to_pytest(tmp_path, args, tier, passed):
    assert plan(tmp_path, *args) == (tier, passed)
