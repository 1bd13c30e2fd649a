#!/usr/bin/env bash
# The main job on the built-in default: set up, then run `geocon demo`
# (extra arguments are passed on, e.g. `bash scripts/demo.sh --out /tmp/demo`).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
bash scripts/bootstrap.sh viewer
exec .venv/bin/geocon demo "$@"
