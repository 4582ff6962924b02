#!/usr/bin/env bash
# Prepare the GPU check for this workplace's offline device machine (see README.md beside this).
# Run here, in the repository root, after `make env`:
#   bash scripts/gpu_check/prepare.sh [CAPTURE [BENCH_SCENE]]    (default CAPTURE: ../shared/data/fox)
# Writes two ignored folders that the device call carries: .whl/ (Python 3.12 wheels of what the
# device image lacks, and stealth-ns itself) and .gpu/ (the open3d stand-in, a self-contained
# copy of CAPTURE with triangulated seed points and, given BENCH_SCENE, a nerfstudio-data scene with
# seed points such as `stealth-ns make-scene --preset facing --resolution 1008x756`, copied without
# its depth maps for `bench train`). Nothing there is committed.
set -euo pipefail
cd "$(dirname "$0")/../.."
CAPTURE="${1:-../shared/data/fox}"
BENCH_SCENE="${2:-}"
PY=.venv/bin/python
[ -x "$PY" ] || { echo "prepare: run 'make env' first" >&2; exit 1; }
[ -d "$CAPTURE" ] || { echo "prepare: no capture at $CAPTURE" >&2; exit 1; }
if [ -n "$BENCH_SCENE" ] && ! grep -q ply_file_path "$BENCH_SCENE/transforms.json" 2>/dev/null; then
    echo "prepare: $BENCH_SCENE is not a nerfstudio-data scene with seed points (ply_file_path)" >&2
    exit 1
fi

# What a training, its attack, a scan and test_cuda.py import that the device image (KINDS.md's
# package list) lacks; open3d is replaced by the stand-in.
NEEDED="nerfstudio gsplat tyro docstring_parser typeguard nerfacc viser msgspec websockets appdirs rawpy
pyquaternion fpsample pathos ppft dill multiprocess pytorch-msssim tensorly splines torch_fidelity plyfile"
PLATFORMS=(--platform manylinux2014_x86_64 --platform manylinux1_x86_64)
for n in $(seq 5 39); do PLATFORMS+=(--platform "manylinux_2_${n}_x86_64"); done
# only what this script makes: a .gpu/gsplat_cuda.so from an earlier call stays
rm -rf .whl .gpu/shim .gpu/capture .gpu/bench
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
if [ -n "$BENCH_SCENE" ]; then  # the depth maps are most of a generated scene's bytes; training reads none
    mkdir .gpu/bench
    cp -r "$BENCH_SCENE/images" .gpu/bench/
    "$PY" - "$BENCH_SCENE" .gpu/bench <<'PY'
import json, shutil, sys
from pathlib import Path
source, target = Path(sys.argv[1]), Path(sys.argv[2])
meta = json.loads((source / "transforms.json").read_text())
for frame in meta["frames"]:
    frame.pop("depth_file_path", None)
shutil.copy(source / meta["ply_file_path"], target / meta["ply_file_path"])
(target / "transforms.json").write_text(json.dumps(meta, indent=2))
PY
fi
du -sh .whl .gpu
echo "prepare: now call the device tool's run with command 'LIMIT=575 bash scripts/gpu_check/check.sh'," \
    "carry ['.whl', '.gpu'] and timeout_s 595 (gsplat's first build takes 3 of its minutes)"
