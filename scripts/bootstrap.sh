#!/usr/bin/env bash
# Prepare this checkout for use: Debian packages, a virtual environment in .venv,
# and an editable install of geocon with the extras given as arguments
# (e.g. `bash scripts/bootstrap.sh test`). Safe to run repeatedly: each step is
# skipped when it is already done.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

# Debian packages the project needs at run time (open3d loads libusb); the test extra also
# needs headless Chromium for the browser tests of the web viewers.
DEB_PACKAGES=(libusb-1.0-0)
for extra in "$@"; do
    [ "$extra" != test ] || DEB_PACKAGES+=(chromium fonts-dejavu-core)
done
missing=()
for pkg in "${DEB_PACKAGES[@]}"; do
    dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" || missing+=("$pkg")
done
if ((${#missing[@]})); then
    echo "geocon: installing Debian packages: ${missing[*]}" >&2
    SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO="sudo"
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

PYTHON="${GEOCON_PYTHON:-}"
if [ -z "$PYTHON" ]; then
    for cand in python3.11 python3; do
        if command -v "$cand" >/dev/null && "$cand" -c 'import sys; sys.exit(sys.version_info[:2] < (3, 11))'; then
            PYTHON="$cand"; break
        fi
    done
fi
[ -n "$PYTHON" ] || { echo "geocon: Python >= 3.11 is required" >&2; exit 1; }

if [ ! -x .venv/bin/python ]; then
    echo "geocon: creating virtual environment in .venv" >&2
    "$PYTHON" -m venv .venv
    .venv/bin/python -m pip install -q --upgrade pip
fi

extras="$(IFS=,; echo "$*")"
spec="."; [ -z "$extras" ] || spec=".[${extras}]"
stamp=".venv/.geocon-install-$(cat pyproject.toml | sha256sum | cut -c1-16)-${extras:-core}"
if [ ! -f "$stamp" ]; then
    echo "geocon: installing ${spec} into .venv" >&2
    log=".venv/pip-install.log"
    if ! .venv/bin/python -m pip install -e "$spec" >"$log" 2>&1; then
        tail -n 40 "$log" >&2
        echo "geocon: pip install failed; full log in $log" >&2
        exit 1
    fi
    rm -f .venv/.geocon-install-*
    touch "$stamp"
fi
