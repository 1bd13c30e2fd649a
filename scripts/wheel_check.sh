#!/usr/bin/env bash
# Check the package as a user gets it: build the sdist and the wheel (`python -m build`, which
# builds the wheel from the sdist), install the wheel and its dependencies (versions from
# constraints.txt, no extras, so no torch) into a fresh virtual environment in a temporary folder,
# then run `geocon doctor` and `geocon demo` from there, outside the checkout: whatever they read
# must come from the installed package. Needs .venv with the test extra (`build`), which
# scripts/test.sh sets up before it runs this. pip's cache (~/.cache/pip) is the one
# scripts/bootstrap.sh filled, so nothing is downloaded twice.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
root="$PWD"
start=$SECONDS

if ! .venv/bin/python -c 'import build' 2>/dev/null; then
    echo "geocon: wheel check needs .venv with the test extra: bash scripts/bootstrap.sh test" >&2
    exit 1
fi
tmp="$(mktemp -d "${TMPDIR:-/tmp}/geocon-wheel.XXXXXX")"
trap 'rm -rf "$tmp"' EXIT
log="$tmp/build.log"

echo "geocon: building the sdist and the wheel" >&2
# the isolated build environment takes its setuptools from constraints.txt too
if ! PIP_CONSTRAINT="$root/constraints.txt" .venv/bin/python -m build --outdir "$tmp/dist" . >"$log" 2>&1; then
    tail -n 40 "$log" >&2
    echo "geocon: python -m build failed" >&2
    exit 1
fi
wheel=("$tmp"/dist/geocon-*.whl)
echo "geocon: built $(cd "$tmp/dist" && echo *)" >&2

echo "geocon: installing ${wheel[0]##*/} into a fresh environment" >&2
.venv/bin/python -m venv "$tmp/venv"
if ! "$tmp/venv/bin/python" -m pip install --no-compile -c "$root/constraints.txt" "${wheel[0]}" >"$log" 2>&1; then
    tail -n 40 "$log" >&2
    echo "geocon: pip install of the wheel failed" >&2
    exit 1
fi

# from a folder outside the checkout, with nothing of the checkout on the path
mkdir "$tmp/work"
cd "$tmp/work"
unset PYTHONPATH
"$tmp/venv/bin/python" - "$root" <<'EOF'
import sys
from pathlib import Path

import geocon_core
import geocon_viewer

root = Path(sys.argv[1]).resolve()
for pkg in (geocon_core, geocon_viewer):
    where = Path(pkg.__file__).resolve()
    if where.is_relative_to(root):
        sys.exit(f"geocon: {pkg.__name__} was imported from the checkout ({where}), not the wheel")

from geocon_core.validation import ANNOTATIONS_PATH, read_annotations

if not read_annotations(ANNOTATIONS_PATH):  # `geocon validate` reads it from the wheel
    sys.exit(f"geocon: the wheel lacks the validation's annotation file ({ANNOTATIONS_PATH})")
EOF
echo "geocon: geocon doctor (from the wheel)" >&2
"$tmp/venv/bin/geocon" doctor
echo "geocon: geocon demo (from the wheel)" >&2
"$tmp/venv/bin/geocon" demo --out "$tmp/work/geocon-demo"
echo "geocon: wheel check passed in $((SECONDS - start)) s" >&2
