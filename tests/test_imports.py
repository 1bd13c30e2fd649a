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
    assert "geocon_core.scoring.scorer" in graph and "geocon_viewer.cli" in graph
    assert "geocon_core.bench.layout" in graph["geocon_core.bench.run"]
    assert "geocon_core.bench.layout" in graph["geocon_core.bench.tables"]
    assert "geocon_core.record" in graph["geocon_core.scoring.verdict"]


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
        "import geocon_core.bench, geocon_core.report",
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


# The layout: geocon_core is packages that follow the data (docs/layout.md), each with one public
# __init__; nothing else sits at its top level.

CORE_TOP_LEVEL = {"__init__", "_version"}
"""The modules allowed at the top of geocon_core: the lazy public API and the version string
(loaded by ``import geocon_core`` at once; docs/layout.md says why it is no package)."""


def _packages(top: str = "geocon_core") -> list[str]:
    return sorted(p.parent.name for p in (ROOT / top).glob("*/__init__.py"))


def _core_packages() -> list[str]:
    return _packages("geocon_core")


VIEWER_PACKAGES = {"cli", "rerun", "audit", "teach", "capture", "shared"}
"""The surfaces of geocon_viewer (docs/layout.md): the command line, the Rerun recording, the
audit app, the teaching app, what runs beside them (processes, Chromium, screenshots) and what
they share (style, clouds)."""


def _package_of(module: str) -> str:
    """``geocon_core.record.clip`` -> ``geocon_core.record``, ``geocon_viewer.rerun.log`` ->
    ``geocon_viewer.rerun``; a top-level module stays itself."""
    parts = module.split(".")
    return ".".join(parts[:2])


def test_the_core_top_level_holds_packages_only():
    modules = {p.stem for p in (ROOT / "geocon_core").glob("*.py")}
    assert modules == CORE_TOP_LEVEL, f"modules at the top of geocon_core: {sorted(modules - CORE_TOP_LEVEL)}"
    assert len(_core_packages()) >= 10


def test_the_viewer_top_level_holds_its_surfaces_only():
    modules = {p.stem for p in (ROOT / "geocon_viewer").glob("*.py")}
    assert modules == {"__init__"}, f"modules at the top of geocon_viewer: {sorted(modules - {'__init__'})}"
    assert set(_packages("geocon_viewer")) == VIEWER_PACKAGES


@pytest.mark.parametrize("top", PACKAGES)
def test_no_cycles_among_the_packages(top):
    graph: dict[str, set[str]] = {}
    for module, deps in _graph().items():
        if not module.startswith(top + "."):
            continue
        mine = _package_of(module)
        targets = {_package_of(d) for d in deps if d.startswith(top + ".")}
        graph.setdefault(mine, set()).update(targets - {mine, top})
    assert len(graph) >= 5
    assert _cycle(graph) is None, "package cycle: " + " -> ".join(_cycle(graph) or [])


def test_the_package_cycle_check_sees_a_cycle_through_submodules():
    graph = {"geocon_core.a": {"geocon_core.b"}, "geocon_core.b": {"geocon_core.a"}}
    assert _cycle(graph) == ["geocon_core.a", "geocon_core.b", "geocon_core.a"]


def test_other_packages_use_a_package_through_its_init():
    """Inside a package, modules import each other; from outside, only the package's public
    ``__init__`` is imported (``from ..record import ClipRecord``, never ``..record.clip``)."""
    modules = _modules()
    known = set(modules)
    bad = []
    for name, deps in _graph().items():
        for dep in deps:
            parts = dep.split(".")
            if parts[0] not in PACKAGES or len(parts) < 3 or not (ROOT / parts[0] / parts[1]).is_dir():
                continue
            if _package_of(name) != _package_of(dep) and dep in known:
                bad.append(f"{name} -> {dep}")
    assert not bad, bad


@pytest.mark.parametrize(
    "package",
    [f"geocon_core.{p}" for p in _core_packages()] + [f"geocon_viewer.{p}" for p in sorted(VIEWER_PACKAGES)],
)
def test_each_package_declares_its_public_names(package):
    import importlib

    if package.startswith("geocon_viewer.") and package != "geocon_viewer.cli":
        for needed in ("rerun", "viser"):
            pytest.importorskip(needed)
    module = importlib.import_module(package)
    assert module.__doc__ and len(module.__doc__.strip()) > 40, f"{package} has no docstring"
    names = module.__all__
    assert len(names) == len(set(names)), "a name twice in __all__"
    top = package.split(".")[0]
    for name in names:
        value = getattr(module, name)
        defined_in = getattr(value, "__module__", None)
        if isinstance(defined_in, str) and defined_in.startswith(top + "."):
            # re-exported from its own package, or an alias of another package's public name
            owner = _package_of(defined_in)
            assert owner == package or name in importlib.import_module(owner).__all__, name


SCORING_FLOW = ("schedule", "rigidity", "verdict", "category", "judge", "regate", "pipeline", "assemble", "scorer")
"""The modules of ``geocon_core.scoring`` in the order a clip goes through them (docs/layout.md):
each imports only modules before it, so scoring flows one way."""


def test_scoring_flows_one_way():
    modules = {p.stem for p in (ROOT / "geocon_core" / "scoring").glob("*.py")} - {"__init__"}
    assert modules == set(SCORING_FLOW), (
        f"scoring modules and SCORING_FLOW differ: {sorted(modules ^ set(SCORING_FLOW))}"
    )
    graph = _graph()
    back = []
    for i, name in enumerate(SCORING_FLOW):
        for dep in graph[f"geocon_core.scoring.{name}"]:
            if dep.startswith("geocon_core.scoring.") and SCORING_FLOW.index(dep.rsplit(".", 1)[1]) >= i:
                back.append(f"{name} -> {dep}")
    assert not back, back
    page = (ROOT / "docs" / "layout.md").read_text()
    places = [page.find(f"`{name}.py`", page.find("How a clip goes through")) for name in SCORING_FLOW]
    assert min(places) > 0 and places == sorted(places), "docs/layout.md lists the scoring modules in another order"


def test_the_layout_page_names_every_package():
    page = (ROOT / "docs" / "layout.md").read_text()
    missing = [p for p in [*_core_packages(), *_packages("geocon_viewer")] if f"`{p}/`" not in page]
    assert not missing, f"docs/layout.md does not describe {missing}"
    assert "`_version.py`" in page


EXTRAS_ONLY = {"report": "the bench extra (pandas, matplotlib)"}
"""Packages of geocon_core that need an extra to import, and which (docs/layout.md says so)."""

OPTIONAL_MODULES = ("pandas", "pyarrow", "matplotlib", "ray", "psutil", "torch", "rerun", "viser", "open3d", "sam2")


def test_the_core_install_imports_every_package_and_the_command_line():
    """With none of the extras (an import of any optional library fails), every package of
    geocon_core but those in EXTRAS_ONLY imports, and so does ``geocon``'s command line."""
    wanted = [f"geocon_core.{p}" for p in _core_packages() if p not in EXTRAS_ONLY] + ["geocon_viewer.cli"]
    probe = f"""
import importlib, importlib.abc, sys
class Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name.split(".")[0] in {OPTIONAL_MODULES!r}:
            raise ImportError(f"No module named {{name!r}} (an extra)")
sys.meta_path.insert(0, Block())
failed = []
for name in {wanted!r}:
    try:
        importlib.import_module(name)
    except ImportError as exc:
        failed.append(f"{{name}}: {{exc}}")
print("\\n".join(failed))
"""
    res = subprocess.run([sys.executable, "-c", probe], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == "", res.stdout


def test_the_extras_only_packages_are_named_in_the_layout_page():
    entries = (ROOT / "docs" / "layout.md").read_text().split("\n  - ")
    for package in EXTRAS_ONLY:
        entry = next(e for e in entries if e.startswith(f"`{package}/`"))
        assert "extra" in entry, f"docs/layout.md does not say that {package}/ needs an extra"
