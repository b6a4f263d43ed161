#!/usr/bin/env bash
# Install the reference SPH codes that `sph bench` runs side by side with ours:
#   - PySPH 1.0b2 (built from source; compiles Cython + OpenMP at run time)
#   - SPlisHSPlasH 2.19.0 Python bindings (pysplishsplash, binary wheel)
# into a SEPARATE venv, <repo>/.venv-bench, so that nothing they pull in
# (Cython, mako, pytools, ...) touches the project's own .venv.
# Idempotent: re-running only checks and skips what is already there.
#
# Usage: bash scripts/setup_bench.sh        (as root, or with sudo for apt)
# Env:   PYTHON=/path/to/python3.11  to choose the base interpreter
#        SKIP_APT=1                   to skip the apt step
set -euo pipefail

REPO_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="$REPO_ROOT/.venv-bench"

NUMPY_VERSION="2.4.6"          # same as the project's .venv
PYSPH_VERSION="1.0b2"
PYSPLISHSPLASH_VERSION="2.19.0"
# PySPH's dependencies, pinned to the versions tested together.
PYSPH_DEPS=(
  "compyle==0.9.1" "cyarray==1.2" "Cython==3.3.1" "mako==1.4.3"
  "MarkupSafe==3.0.4" "pytools==2026.1.1" "Beaker==1.14.1"
  "siphash24==1.9" "platformdirs==4.14.7" "typing_extensions==4.16.0"
)

log() { printf '[setup_bench] %s\n' "$*" >&2; }

# --- 1. system packages --------------------------------------------------------
# gcc/g++ + libgomp: PySPH compiles its generated Cython code with OpenMP at
# run time.  libgl1/libglvnd0/libx11-6/libxext6/libbsd0: shared libraries the
# pysplishsplash wheel links (it is built with its GUI); libGLdispatch.so.0
# (from libglvnd0) must be LD_PRELOADed to import it (runner.py does that).
APT_PKGS=(build-essential libgomp1 libgl1 libglvnd0 libglx0 libx11-6 libxext6 libbsd0)
if [[ "${SKIP_APT:-0}" != "1" ]] && command -v apt-get >/dev/null 2>&1; then
  missing=()
  for p in "${APT_PKGS[@]}"; do
    dpkg -s "$p" >/dev/null 2>&1 || missing+=("$p")
  done
  if ((${#missing[@]})); then
    SUDO=""
    [[ "$(id -u)" != "0" ]] && SUDO="sudo"
    log "apt-get install ${missing[*]}"
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
  else
    log "system packages present"
  fi
fi

# --- 2. venv -------------------------------------------------------------------
if [[ ! -x "$VENV/bin/python" ]]; then
  BASE_PY="${PYTHON:-}"
  if [[ -z "$BASE_PY" ]]; then
    # Prefer the interpreter behind the project's .venv (same Python 3.11).
    if [[ -f "$REPO_ROOT/.venv/pyvenv.cfg" ]]; then
      home="$(sed -n 's/^home *= *//p' "$REPO_ROOT/.venv/pyvenv.cfg")"
      for c in "$home/python3.11" "$home/python3"; do
        [[ -x "$c" ]] && { BASE_PY="$c"; break; }
      done
    fi
    [[ -z "$BASE_PY" ]] && BASE_PY="$(command -v python3.11 || command -v python3)"
  fi
  log "creating $VENV with $BASE_PY"
  "$BASE_PY" -m venv "$VENV"
fi
PY="$VENV/bin/python"
"$PY" -c 'import sys; assert sys.version_info[:2] == (3, 11), sys.version' \
  || log "warning: pysplishsplash 2.19.0 wheels used here are for CPython 3.11"

have() {  # have DIST VERSION
  "$PY" - "$1" "$2" <<'EOF' >/dev/null 2>&1
import sys
from importlib.metadata import version
sys.exit(0 if version(sys.argv[1]) == sys.argv[2] else 1)
EOF
}

# --- 3. pip packages ----------------------------------------------------------
if ! have numpy "$NUMPY_VERSION" || ! have pysplishsplash "$PYSPLISHSPLASH_VERSION"; then
  log "pip install numpy==$NUMPY_VERSION pysplishsplash==$PYSPLISHSPLASH_VERSION"
  "$PY" -m pip install -q "numpy==$NUMPY_VERSION" "pysplishsplash==$PYSPLISHSPLASH_VERSION"
else
  log "pysplishsplash $PYSPLISHSPLASH_VERSION present"
fi
if ! have pysph "$PYSPH_VERSION"; then
  log "pip install pysph==$PYSPH_VERSION (builds from source, ~3 min on 2 cores)"
  "$PY" -m pip install -q --pre "numpy==$NUMPY_VERSION" "${PYSPH_DEPS[@]}" "pysph==$PYSPH_VERSION"
else
  log "pysph $PYSPH_VERSION present"
fi

# --- 4. smoke check -------------------------------------------------------------
GLD=/lib/x86_64-linux-gnu/libGLdispatch.so.0
[[ -e "$GLD" ]] || GLD=/usr/lib/x86_64-linux-gnu/libGLdispatch.so.0
LD_PRELOAD="$GLD" "$PY" -c 'import pysplishsplash' \
  || { log "pysplishsplash does not import"; exit 1; }
"$PY" -c 'import pysph, compyle, cyarray; from pysph.sph.scheme import WCSPHScheme' \
  || { log "pysph does not import"; exit 1; }
log "ok: reference codes installed in $VENV"
