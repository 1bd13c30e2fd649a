"""The command line's allocator settings (:func:`geocon_core.files.tune_allocator`): applied to the
process and handed to its children, a value the user chose kept."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

CHILD = """
import json, os
from geocon_core.files import tune_allocator
applied = tune_allocator()
child = {k: os.environ.get(k) for k in ("MALLOC_ARENA_MAX", "MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_")}
print(json.dumps({"applied": applied, "env": child}))
"""


def _run(env: dict[str, str]) -> dict:
    base = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_")}
    done = subprocess.run(
        [sys.executable, "-c", CHILD], env={**base, **env}, capture_output=True, text=True, check=True, timeout=60
    )
    return json.loads(done.stdout)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_the_allocator_is_tuned_and_children_inherit_it():
    from geocon_core.files import ARENAS, MMAP_THRESHOLD

    out = _run({})
    assert out["applied"] == {
        "MALLOC_ARENA_MAX": ARENAS,
        "MALLOC_MMAP_THRESHOLD_": MMAP_THRESHOLD,
        "MALLOC_TRIM_THRESHOLD_": MMAP_THRESHOLD,
    }
    assert out["env"] == {k: str(v) for k, v in out["applied"].items()}


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_a_value_the_user_set_is_kept():
    out = _run({"MALLOC_ARENA_MAX": "7"})
    assert "MALLOC_ARENA_MAX" not in out["applied"] and out["env"]["MALLOC_ARENA_MAX"] == "7"
    assert "MALLOC_MMAP_THRESHOLD_" in out["applied"]
