"""Untrusted files are never unpickled: every ``np.load`` in the package passes
``allow_pickle=False``, nothing imports ``pickle``, and a ``torch.load`` passes
``weights_only=True`` (checked on the source, so a new call cannot slip in)."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("geocon_core", "geocon_viewer")


def _calls(name: str):
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
            for node in ast.walk(tree):
                if isinstance(node, ast.Call) and ast.unparse(node.func).endswith(name):
                    yield path.relative_to(ROOT), node


def _keyword(node: ast.Call, key: str):
    for kw in node.keywords:
        if kw.arg == key and isinstance(kw.value, ast.Constant):
            return kw.value.value
    return None


def test_every_np_load_refuses_pickles():
    found = list(_calls("np.load"))
    assert found, "the check must see the package's np.load calls"
    unsafe = [f"{p}:{n.lineno}" for p, n in found if _keyword(n, "allow_pickle") is not False]
    assert not unsafe, f"np.load without allow_pickle=False: {unsafe}"


def test_no_pickle_and_no_unsafe_torch_load():
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            tree = ast.parse(path.read_text(encoding="utf-8"))
            for node in ast.walk(tree):
                if isinstance(node, ast.Import):
                    assert all(a.name not in ("pickle", "dill", "cloudpickle") for a in node.names), path
                if isinstance(node, ast.ImportFrom):
                    assert node.module not in ("pickle", "dill", "cloudpickle"), path
    unsafe = [f"{p}:{n.lineno}" for p, n in _calls("torch.load") if _keyword(n, "weights_only") is not True]
    assert not unsafe, f"torch.load without weights_only=True: {unsafe}"
