#!/usr/bin/env bash
# Set up and run the test suite (extra arguments go to pytest, e.g. `-m slow`).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
bash scripts/bootstrap.sh viewer bench test
exec .venv/bin/python -m pytest "$@"
