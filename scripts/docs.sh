#!/usr/bin/env bash
# Build the documentation site into site/ (open site/index.html): set up the `docs` extra
# (MkDocs, Material for MkDocs, mkdocstrings) in .venv, then `mkdocs build --strict`, which
# fails on any warning (a broken link or anchor, a page missing from the nav, a docstring the
# API reference cannot read); then scripts/api_coverage.py checks that every public name of every
# package of geocon_core has its entry in the reference. Extra arguments go to mkdocs build. A live preview:
# .venv/bin/mkdocs serve (127.0.0.1:8000).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
# scripts/test.sh installs the docs extra with its own; otherwise set it up here
if ! .venv/bin/python -c 'import mkdocs, material, mkdocstrings' 2>/dev/null; then
    bash scripts/bootstrap.sh docs
fi

# Material for MkDocs prints a notice about its successor on every build; it is no warning.
export NO_MKDOCS_2_WARNING=1
echo "geocon: mkdocs build --strict" >&2
if ! .venv/bin/mkdocs build --strict --site-dir site "$@"; then
    echo "geocon: the documentation build failed; fix the warnings above (configuration in mkdocs.yml)" >&2
    exit 1
fi
# every public name of every package of geocon_core has its entry in the reference
.venv/bin/python scripts/api_coverage.py site
echo "geocon: documentation built; open site/index.html" >&2
