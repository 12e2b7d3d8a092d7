#!/usr/bin/env bash
# One-time set-up on a fresh Debian 12 machine: system libraries, then a virtual
# environment at .venv with rjfit and its test dependencies. Safe to run again.
set -euo pipefail
cd "$(dirname "$0")"

# Mitsuba's LLVM variants crash with Debian 12's default LLVM 15 ("Cannot select ...
# fminimum"); drjit picks up libllvm19 by itself once it is installed. libgomp1: the
# OpenMP runtime of Numba's threading layer, which runs a chain's large passes on threads.
PACKAGES="libllvm19 libgomp1"
if ! dpkg -s $PACKAGES >/dev/null 2>&1; then
  SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  export DEBIAN_FRONTEND=noninteractive
  $SUDO apt-get install -y -q $PACKAGES || { $SUDO apt-get update -q && $SUDO apt-get install -y -q $PACKAGES; }
fi

PYTHON="${PYTHON:-python3}"
if [ ! -x .venv/bin/python ]; then
  "$PYTHON" -m venv .venv
fi
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q -e ".[test]"
# the sampler's Numba kernels compiled once into their on-disk cache (about 50 s on 2 cores), so the
# first fit, each chain's worker process and each test worker start from it (rjfit/pipeline/precompile.py)
.venv/bin/python -m rjfit.pipeline.precompile
echo "rjfit set up in $(pwd)/.venv"
