#!/usr/bin/env bash
# Set-up and everyday tasks, from a fresh Debian machine: `./dev.sh run` and `./dev.sh test`.
# Installs the system libraries Open3D needs (apt, with sudo when not root), a virtual environment in
# .venv and the project with its development tools; then runs the task. Re-running skips what is done.
set -euo pipefail
cd "$(dirname "$0")"

VENV=${CANOPY_VENV:-.venv}
APT_PACKAGES=(libusb-1.0-0 libgl1 libgomp1)
PYTHON=${PYTHON:-python3}

as_root() { if [ "$(id -u)" -eq 0 ]; then "$@"; else sudo "$@"; fi; }

system_libraries() {
    local missing=()
    for package in "${APT_PACKAGES[@]}"; do
        dpkg -s "$package" >/dev/null 2>&1 || missing+=("$package")
    done
    command -v "$PYTHON" >/dev/null 2>&1 || missing+=(python3)
    "$PYTHON" -c 'import ensurepip, venv' >/dev/null 2>&1 || missing+=(python3-venv)
    if [ ${#missing[@]} -gt 0 ]; then
        echo "installing system packages: ${missing[*]}"
        as_root apt-get update -qq
        as_root env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${missing[@]}" >/dev/null
    fi
}

python_environment() {
    local stamp="$VENV/.canopy-installed"
    if [ -f "$stamp" ] && [ "$stamp" -nt pyproject.toml ]; then return; fi
    [ -x "$VENV/bin/python" ] || "$PYTHON" -m venv "$VENV"
    "$VENV/bin/python" -m pip install --quiet --upgrade pip
    "$VENV/bin/python" -m pip install --quiet -e ".[dev]"
    touch "$stamp"
}

setup() { system_libraries; python_environment; }

case "${1:-}" in
    run)
        setup
        # The main job on the embedded default: simulate one two-view capture, then measure it.
        out=${CANOPY_DATA_DIR:-./canopy-data}/demo
        rm -rf "$out"
        "$VENV/bin/canopy" simulate "$out" --seed 7 --count 1 >/dev/null
        "$VENV/bin/canopy" measure "$out/tree_000" --cloud "$out/tree_000.ply"
        echo "ground truth: $(cat "$out/tree_000/ground_truth.json" | "$VENV/bin/python" -c \
            'import json,sys; g=json.load(sys.stdin); print("H %.3f  W %.3f  D %.3f m" % (g["height_m"], g["width_m"], g["thickness_m"]))')"
        echo "fused cloud: $out/tree_000.ply"
        ;;
    test)
        setup
        shift
        "$VENV/bin/python" -m pytest -q "$@"
        ;;
    *)
        echo "usage: ./dev.sh run | ./dev.sh test [pytest args]" >&2
        exit 64
        ;;
esac
