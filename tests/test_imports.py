"""The import graph: no cycles among the project's modules, the core never imports the viewers,
and importing the core stays light (no viewer, no torch)."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("geocon_core", "geocon_viewer")
HEAVY = ("rerun", "viser", "open3d", "torch")


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for pkg in PACKAGES for p in sorted((ROOT / pkg).rglob("*.py"))}


def _resolve(module: str, is_package: bool, node: ast.ImportFrom) -> str:
    if node.level == 0:
        return node.module or ""
    base = module.split(".") if is_package else module.split(".")[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def _imports(module: str, path: Path, known: set[str]) -> set[str]:
    """Project modules that ``module`` imports, at any depth of its code (lazy imports included)."""
    is_package = path.name == "__init__.py"
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = _resolve(module, is_package, node)
            # `from pkg import sub` names a submodule when one exists, else an attribute of pkg
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in known else base for a in node.names]
        else:
            continue
        for target in targets:
            while target and target not in known:
                target = target.rpartition(".")[0]
            if target and target != module:
                found.add(target)
    return found


def _graph() -> dict[str, set[str]]:
    modules = _modules()
    known = set(modules)
    return {name: _imports(name, path, known) for name, path in modules.items()}


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle of ``graph`` (a list of modules, first == last), or None. A package's own
    ``__init__`` importing its submodules is not an edge back (Python imports the package first)."""
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph.get(node, ())):
            if node.startswith(nxt + "."):
                continue  # a submodule importing its parent package's names
            if state.get(nxt) == 1:
                return stack[stack.index(nxt) :] + [nxt]
            if state.get(nxt) is None:
                found = visit(nxt)
                if found:
                    return found
        stack.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if state.get(node) is None:
            found = visit(node)
            if found:
                return found
    return None


def test_the_graph_is_walked():
    graph = _graph()
    assert "geocon_core.scorer" in graph and "geocon_viewer.cli" in graph
    assert "geocon_core.layout" in graph["geocon_core.bench"]
    assert "geocon_core.layout" in graph["geocon_core.tables"]


def test_no_import_cycles_among_project_modules():
    cycle = _cycle(_graph())
    assert cycle is None, "import cycle: " + " -> ".join(cycle or [])


def test_cycle_finder_finds_a_planted_cycle():
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": set()}) is None


def test_core_imports_nothing_from_the_viewers():
    offenders = {m: sorted(d for d in deps if d.startswith("geocon_viewer")) for m, deps in _graph().items()}
    offenders = {m: d for m, d in offenders.items() if m.startswith("geocon_core") and d}
    assert not offenders, offenders


def test_no_private_names_cross_packages():
    """The viewers use the core's public names only."""
    bad = []
    for name, path in _modules().items():
        if not name.startswith("geocon_viewer"):
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").startswith("geocon_core"):
                private = [a.name for a in node.names if a.name.startswith("_") and not a.name.endswith("__")]
                bad += [f"{name}: {node.module}.{p}" for p in private]
    assert not bad, bad


@pytest.mark.parametrize(
    "code",
    [
        "import geocon_core",
        "import geocon_core; geocon_core.ScoreConfig; geocon_core.preset('paper')",
        "import geocon_core.bench, geocon_core.results, geocon_core.tables",
        "import geocon_viewer.cli",
    ],
)
def test_importing_the_core_loads_no_viewer_and_no_torch(code):
    probe = f"{code}\nimport sys\nprint(','.join(m for m in {HEAVY!r} if m in sys.modules))"
    res = subprocess.run(
        [sys.executable, "-c", probe], cwd=ROOT, capture_output=True, text=True, timeout=120, check=False
    )
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == "", f"{code!r} imported {res.stdout.strip()}"


def test_import_geocon_core_loads_no_opencv_stage():
    probe = "import geocon_core, sys\nprint('cv2' in sys.modules)"
    res = subprocess.run([sys.executable, "-c", probe], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert res.stdout.strip() == "False", res.stderr


def test_the_public_api_resolves():
    import geocon_core

    assert set(geocon_core.__all__) == {"__version__", *geocon_core._LAZY}
    for name in geocon_core.__all__:
        assert getattr(geocon_core, name) is not None, name
    with pytest.raises(AttributeError):
        geocon_core.not_a_name  # noqa: B018
