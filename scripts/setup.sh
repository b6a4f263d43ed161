#!/usr/bin/env bash
# Create (or update) the project's virtual environment in .venv with everything a run and the test
# suite need, on a fresh Debian machine with Python >= 3.11 (3.11 is what CI runs). Idempotent: a
# second run takes seconds.
#
#   bash scripts/setup.sh            # system packages (if missing) + .venv + the package with [cuda,dev]
#   SKIP_APT=1 bash scripts/setup.sh # do not touch system packages
#   PYTHON=python3.12 bash scripts/setup.sh
#
# Every package is installed at the exact version of constraints.txt (pip -c), so every machine runs
# the same numerics; pyproject.toml itself only gives ranges. The cuda extra is installed because the
# test suite compiles every CUDA kernel to PTX (numba-cuda, NVVM) even on machines without a GPU; a
# plain install for runs on the CPU is `pip install .` (README).
set -euo pipefail
cd "$(dirname "$0")/.."

PYTHON="${PYTHON:-python3.11}"
command -v "$PYTHON" >/dev/null 2>&1 || PYTHON=python3
"$PYTHON" -c 'import sys; assert sys.version_info[:2] >= (3, 11), sys.version' \
  || { echo "setup: Python 3.11 or newer is required (found $("$PYTHON" --version 2>&1))" >&2; exit 1; }

# Off-screen rendering (PyVista/VTK) goes through Mesa EGL; install its libraries if missing.
# iproute2 and nftables: the multi-host tests make their hosts from network namespaces (launch/netns.py).
APT_PACKAGES=(libegl1 libegl-mesa0 libgl1-mesa-dri libgl1 libxrender1 iproute2 nftables)
if [[ "${SKIP_APT:-0}" != 1 ]] && command -v dpkg >/dev/null 2>&1; then
  missing=()
  for p in "${APT_PACKAGES[@]}"; do dpkg -s "$p" >/dev/null 2>&1 || missing+=("$p"); done
  if ((${#missing[@]})); then
    SUDO=""; [[ $(id -u) -ne 0 ]] && SUDO="sudo"
    echo "setup: installing system packages: ${missing[*]}"
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
  fi
fi

stamp=.venv/.installed
if [[ ! -x .venv/bin/python ]]; then
  echo "setup: creating .venv"
  "$PYTHON" -m venv .venv
fi
if [[ ! -f $stamp || pyproject.toml -nt $stamp || constraints.txt -nt $stamp ]]; then
  echo "setup: installing the package and its pinned dependencies into .venv (first time: a few minutes)"
  .venv/bin/python -m pip install -q --upgrade pip
  .venv/bin/python -m pip install -q -c constraints.txt -e ".[cuda,dev]"
  touch "$stamp"
fi
# Rerun: no usage analytics from this machine (the viewer also runs with RERUN_ANALYTICS=0)
.venv/bin/rerun analytics disable >/dev/null 2>&1 || true
.venv/bin/sph --help >/dev/null
echo "setup: ready (.venv/bin/sph)"
