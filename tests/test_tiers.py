"""The quick tier (``bash scripts/test.sh --quick``: tests not marked ``full`` or ``slow``) keeps
every test file: each keeps tests of its own in the loop, so no module drops out of it."""

from __future__ import annotations

import ast
from pathlib import Path

TESTS = Path(__file__).resolve().parent


def _marks(node: ast.FunctionDef) -> set[str]:
    out = set()
    for dec in node.decorator_list:
        target = dec.func if isinstance(dec, ast.Call) else dec
        if isinstance(target, ast.Attribute) and isinstance(target.value, ast.Attribute):
            if isinstance(target.value.value, ast.Name) and target.value.value.id == "pytest":
                out.add(target.attr)
    return out


def _module_marks(tree: ast.Module) -> str:
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == "pytestmark" for t in node.targets):
            return ast.unparse(node.value)
    return ""


def quick_tests(path: Path) -> list[str]:
    """The test functions of ``path`` that the quick tier runs."""
    tree = ast.parse(path.read_text())
    module = _module_marks(tree)
    if "mark.full" in module or "mark.slow" in module:
        return []
    return [
        node.name
        for node in tree.body
        if isinstance(node, ast.FunctionDef) and node.name.startswith("test") and not _marks(node) & {"full", "slow"}
    ]


def test_every_test_file_keeps_tests_in_the_quick_tier():
    files = sorted(TESTS.glob("test_*.py"))
    assert len(files) > 50
    empty = [p.name for p in files if not quick_tests(p)]
    assert not empty, f"test files with no test in the quick tier: {empty}"


def test_the_reader_sees_both_markers(tmp_path):
    sample = tmp_path / "test_sample.py"
    sample.write_text(
        "import pytest\n\n@pytest.mark.full\ndef test_a():\n    pass\n\n"
        "@pytest.mark.slow\n@pytest.mark.parametrize('x', [1])\ndef test_b(x):\n    pass\n\ndef test_c():\n    pass\n"
    )
    assert quick_tests(sample) == ["test_c"]
    sample.write_text("import pytest\n\npytestmark = pytest.mark.full\n\ndef test_a():\n    pass\n")
    assert quick_tests(sample) == []
