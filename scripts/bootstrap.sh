#!/usr/bin/env bash
# Prepare this checkout for use: Debian packages, a virtual environment in .venv,
# and an editable install of geocon with the extras given as arguments
# (e.g. `bash scripts/bootstrap.sh test`, or any extra pyproject.toml names, such as docs).
# Every pip install here takes `-c constraints.txt`: the packages listed there get exactly the
# versions the validation report was measured with; the others pip resolves as usual.
# Safe to run repeatedly: each step is skipped when it is already done.
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
stamp=".venv/.geocon-install-$(cat pyproject.toml constraints.txt | sha256sum | cut -c1-16)-${extras:-core}"
if [ ! -f "$stamp" ]; then
    echo "geocon: installing ${spec} into .venv" >&2
    log=".venv/pip-install.log"
    if ! .venv/bin/python -m pip install -c constraints.txt -e "$spec" >"$log" 2>&1; then
        tail -n 40 "$log" >&2
        if grep -q "No space left on device" "$log"; then
            echo "geocon: pip install failed: the disk is full ($(df -h --output=avail . | tail -n 1 | tr -d ' ')" \
                "free here; the full test environment needs about 4 GB, torch and Open3D most of it)" >&2
        fi
        echo "geocon: pip install failed; full log in $log" >&2
        exit 1
    fi
    rm -f .venv/.geocon-install-*
    touch "$stamp"
fi

# Neural backends that pip cannot install from the extra alone (only when the neural extra is asked for).
want_neural=0
for extra in "$@"; do [ "$extra" != neural ] || want_neural=1; done
if [ "$want_neural" = 1 ]; then
    # SAM-2 (Apache-2.0, see README, "SAM-2 masks"): PyPI has only its source, whose declared
    # dependencies pull a CUDA torch and torchvision; built without the CUDA extension, against the
    # CPU torch of the neural extra, with what the video predictor imports (hydra-core, iopath).
    if ! .venv/bin/python -c 'import importlib.metadata as m, sys; sys.exit(m.version("sam2") != "1.1.0")' \
        2>/dev/null; then
        echo "geocon: installing sam2 1.1.0 (SAM-2) into .venv" >&2
        log=".venv/pip-install-sam2.log"
        if ! { .venv/bin/python -m pip install -c constraints.txt "setuptools>=70.1" \
            && SAM2_BUILD_CUDA=0 .venv/bin/python -m pip install -c constraints.txt --no-build-isolation \
                --no-deps "sam2==1.1.0"; } \
            >"$log" 2>&1; then
            tail -n 20 "$log" >&2
            echo "geocon: pip install sam2 failed; full log in $log" >&2
            exit 1
        fi
    fi
    # DUSt3R (CC BY-NC-SA 4.0, see README, "DUSt3R pose"): the inference-only mini-dust3r package
    # without its declared dependencies (gradio, a CUDA torchvision, ...); what its model imports
    # (einops, beartype, huggingface_hub) comes pinned with the neural extra.
    if ! .venv/bin/python -c 'import importlib.metadata as m, sys; sys.exit(m.version("mini-dust3r") != "0.1.2")' \
        2>/dev/null; then
        echo "geocon: installing mini-dust3r 0.1.2 (DUSt3R) into .venv" >&2
        log=".venv/pip-install-dust3r.log"
        if ! .venv/bin/python -m pip install -c constraints.txt --no-deps "mini-dust3r==0.1.2" >"$log" 2>&1; then
            tail -n 20 "$log" >&2
            echo "geocon: pip install mini-dust3r failed; full log in $log" >&2
            exit 1
        fi
    fi
fi
