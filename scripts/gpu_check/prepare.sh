#!/usr/bin/env bash
# Prepare the GPU check for this workplace's offline device machine (see README.md beside this).
# Run here, in the repository root, after `make env`:
#   bash scripts/gpu_check/prepare.sh [CAPTURE]      (default CAPTURE: ../shared/data/fox)
# Writes two ignored folders that the device call carries: .whl/ (Python 3.12 wheels of what the
# device image lacks, and stealth-ns itself) and .gpu/ (the open3d stand-in and a self-contained
# copy of CAPTURE with triangulated seed points). Nothing there is committed.
set -euo pipefail
cd "$(dirname "$0")/../.."
CAPTURE="${1:-../shared/data/fox}"
PY=.venv/bin/python
[ -x "$PY" ] || { echo "prepare: run 'make env' first" >&2; exit 1; }
[ -d "$CAPTURE" ] || { echo "prepare: no capture at $CAPTURE" >&2; exit 1; }

# What a training, its attack, a scan and test_cuda.py import that the device image (KINDS.md's
# package list) lacks; open3d is replaced by the stand-in.
NEEDED="nerfstudio gsplat tyro docstring_parser typeguard nerfacc viser msgspec websockets appdirs rawpy
pyquaternion fpsample pathos ppft dill multiprocess pytorch-msssim tensorly splines torch_fidelity plyfile"
PLATFORMS=(--platform manylinux2014_x86_64 --platform manylinux1_x86_64)
for n in $(seq 5 39); do PLATFORMS+=(--platform "manylinux_2_${n}_x86_64"); done
# only what this script makes: a .gpu/gsplat_cuda.so from an earlier call stays
rm -rf .whl .gpu/shim .gpu/capture
mkdir -p .whl .gpu/shim/open3d
for name in $NEEDED; do
    version=$("$PY" -c "import importlib.metadata as m; print(m.version('$name'))")
    # this venv's version; the newest binary one where that has no Python 3.12 wheel (fpsample)
    for spec in "$name==$version" "$name"; do
        if "$PY" -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 \
            --implementation cp "${PLATFORMS[@]}" -d .whl "$spec" >/dev/null 2>&1; then
            [ "$spec" = "$name" ] && echo "prepare: $name $version has no Python 3.12 wheel; took the newest"
            break
        fi
        [ "$spec" = "$name" ] && { echo "prepare: no Python 3.12 wheel of $name" >&2; exit 1; }
    done
done
"$PY" -m pip wheel -q --no-deps --no-build-isolation -w .whl . >/dev/null
cp scripts/gpu_check/open3d_standin.py .gpu/shim/open3d/__init__.py
cp -r "$CAPTURE" .gpu/capture
if ! grep -q ply_file_path .gpu/capture/transforms.json; then
    .venv/bin/stealth-ns seed-points --data .gpu/capture --overwrite
fi
du -sh .whl .gpu
echo "prepare: now call the device tool's run with command 'bash scripts/gpu_check/check.sh' and" \
    "carry ['.whl', '.gpu'] (about 9 minutes, gsplat's first build 3 of them)"
