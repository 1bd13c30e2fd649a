#!/usr/bin/env bash
# Set up, check lint and types, then run the test suite. Extra arguments go to pytest:
#   bash scripts/test.sh                      # the default run (slow checks deselected): what CI runs
#   bash scripts/test.sh --quick              # the quick tier: lint, types and the tests not marked
#                                             # full or slow (every module, under 5 min on 2 cores);
#                                             # no docs build, no wheel check
#   bash scripts/test.sh -m slow              # only the slow end-to-end checks
#   bash scripts/test.sh -m "slow or not slow"  # everything
#   bash scripts/test.sh tests/test_geometry.py -x
# The lint and type checks run first and stop the run on the first finding; then the documentation
# site is built (scripts/docs.sh, mkdocs --strict: a broken link fails it); then the wheel check
# (scripts/wheel_check.sh: the built wheel alone in a fresh environment runs doctor and demo,
# about two minutes; GEOCON_WHEEL_CHECK=0 skips it for a quick local run).
# --quick may stand anywhere among the arguments (`-x --quick` is the quick tier too); every other
# argument goes to pytest as it is. GEOCON_TEST_PLAN=1 prints the tier and the pytest arguments (one
# a line) and stops there, before any set-up: what tests/test_test_script.py checks.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
quick=0
args=()
for arg in "$@"; do
    if [ "$arg" = --quick ]; then
        quick=1
    else
        args+=("$arg")
    fi
done
set -- ${args[@]+"${args[@]}"}
if [ "${GEOCON_TEST_PLAN:-0}" = 1 ]; then
    if [ "$quick" = 1 ]; then echo "tier: quick"; else echo "tier: full"; fi
    for arg in "$@"; do printf 'pytest arg: %s\n' "$arg"; done
    exit 0
fi
bash scripts/bootstrap.sh viewer bench test neural distributed docs

step() {
    local what="$1" hint="$2"
    shift 2
    echo "geocon: $what" >&2
    if ! "$@"; then
        echo "geocon: $what failed; $hint" >&2
        exit 1
    fi
}
step "ruff check" "fix the findings above (many fix themselves with .venv/bin/ruff check --fix .)" \
    .venv/bin/ruff check --quiet .
step "ruff format --check" "run .venv/bin/ruff format . and commit the result" \
    .venv/bin/ruff format --check --quiet .
step "mypy" "fix the type errors above (configuration in pyproject.toml)" \
    .venv/bin/mypy --no-error-summary
if [ "$quick" = 1 ]; then
    echo "geocon: pytest, the quick tier (-m 'not slow and not full')" >&2
    exec .venv/bin/python -m pytest -n 2 --dist loadfile --durations=10 -m "not slow and not full" "$@"
fi
step "docs build" "fix the warnings above (pages in docs/, configuration in mkdocs.yml)" \
    bash scripts/docs.sh --quiet
if [ "${GEOCON_WHEEL_CHECK:-1}" != 0 ]; then
    step "wheel check" "the wheel misses a file or a dependency; rerun alone with bash scripts/wheel_check.sh" \
        bash scripts/wheel_check.sh
fi
echo "geocon: pytest" >&2
# two worker processes (pytest-xdist), one test file each at a time, so module fixtures are made
# once: about 1.45x faster on two cores; -n 0 runs everything in this process
exec .venv/bin/python -m pytest -n 2 --dist loadfile --durations=20 "$@"
