"""Every public name of every geocon_core package has an entry in the built API reference.

Run after ``mkdocs build`` (``scripts/docs.sh`` does): for each package ``geocon_core.<pkg>`` and
each name in its ``__all__``, the page ``site/api/<pkg>/index.html`` must hold the anchor
``geocon_core.<pkg>.<name>`` that mkdocstrings writes for a documented object. A name without a
docstring is left out of the reference by mkdocstrings, so this also finds public names nobody
documented. Exit status 1 lists what is missing.
"""

from __future__ import annotations

import importlib
import pkgutil
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def packages() -> list[str]:
    """The packages of geocon_core (top level), by name."""
    import geocon_core

    return sorted(m.name for m in pkgutil.iter_modules(geocon_core.__path__) if m.ispkg)


def missing(site: Path) -> list[str]:
    gaps = []
    for pkg in packages():
        page = site / "api" / pkg / "index.html"
        if not page.is_file():
            gaps.append(f"geocon_core.{pkg}: no page api/{pkg}.md in the reference")
            continue
        html = page.read_text(encoding="utf-8")
        module = importlib.import_module(f"geocon_core.{pkg}")
        gaps += [f"geocon_core.{pkg}.{name}" for name in module.__all__ if f'id="geocon_core.{pkg}.{name}"' not in html]
    return gaps


def main() -> int:
    site = Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT / "site"
    sys.path.insert(0, str(ROOT))
    gaps = missing(site)
    if gaps:
        print("geocon: public names missing from the API reference (give them a docstring):", file=sys.stderr)
        for gap in gaps:
            print(f"  {gap}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
