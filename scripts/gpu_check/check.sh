#!/usr/bin/env bash
# The GPU check, run ON the device machine from the repository root (see README.md beside this):
# installs the carried wheels, builds gsplat's CUDA kernels, then, in this order and each only while
# LIMIT seconds (from the start of this script) leave it time enough: make test-gpu's tests; the view
# noise's timing at 1 MP (its launches eagerly, and replayed as a CUDA graph); given
# .gpu/bench, `bench train` of a whole stealth-splat-lite run on it with the attack and without;
# ITERS steps of the carried capture for each of RUNS (stealth-splat with its attack, without it, stock
# splatfacto) and ns-eval of the stealth-splat runs. Everything is logged to $OUT/check.log as it happens.
exec > >(tee "$OUT/check.log") 2>&1
export PYTHONUNBUFFERED=1 TORCH_CUDA_ARCH_LIST="${TORCH_CUDA_ARCH_LIST:-9.0}" MAX_JOBS="${MAX_JOBS:-24}"
ITERS="${ITERS:-2000}"
LIMIT="${LIMIT:-560}"  # keep under the device call's timeout_s
BENCH_STEPS="${BENCH_STEPS:-2999}"  # bench train's timed steps (2999 after step 0: a whole lite run)
TESTS="${TESTS:-1}"  # 0: no tests (a second call on the warm machine, for the stages skipped)
BENCH="${BENCH:-1}"  # 0: no bench train (likewise)
RUNS="${RUNS:-attack clean splatfacto}"  # the trainings on the capture, in this order
# a training's expected seconds (~15 ms a step and the set-up, as on an H100/H200) and its time-out
RUN_S=$((40 + ITERS / 66))
RUN_TIMEOUT=$((2 * RUN_S + 60))
T0=$(date +%s)
t() { echo "=== [$(($(date +%s) - T0)) s] $*"; }
# fits SECONDS: is there time for a stage expected to take SECONDS? Says so when not.
fits() {
    local left=$((LIMIT - $(date +%s) + T0))
    [ "$left" -ge "$1" ] && return 0
    echo "=== skipped (needs ~$1 s, $left s left of LIMIT=$LIMIT): $2"
    return 1
}

t start
nvidia-smi -L
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir .whl/*.whl || exit 1
export PYTHONPATH="$PWD/.gpu/shim${PYTHONPATH:+:$PYTHONPATH}"
BIN=$(dirname "$(python3 -c 'import sys; print(sys.executable)')")
python3 -c "import sys, torch, numpy; print(sys.version.split()[0], torch.__version__, numpy.__version__, torch.cuda.get_device_name())"
# the CPU side (the injection's ray search runs there): cores, those usable, torch's threads, any quota
python3 -c "import os, torch; print('cpus', os.cpu_count(), 'usable', len(os.sched_getaffinity(0)), 'torch threads', torch.get_num_threads())"
echo "cgroup cpu.max: $(cat /sys/fs/cgroup/cpu.max 2>/dev/null || echo none)"

SITE=$(python3 -c "import importlib.util, os; print(os.path.dirname(importlib.util.find_spec('gsplat').origin))")
if [ -f .gpu/gsplat_cuda.so ]; then  # a previous call's build (same image): no 200 s rebuild
    cp .gpu/gsplat_cuda.so "$SITE/"
    cat > "$SITE/csrc.py" <<'PY'
import importlib.util, os, sys
_spec = importlib.util.spec_from_file_location("gsplat_cuda", os.path.join(os.path.dirname(__file__), "gsplat_cuda.so"))
_module = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_module)
sys.modules[__name__] = _module
PY
fi
# gsplat's build in the background, ours meanwhile
python3 -c "
import time; t = time.time()
from gsplat.cuda._backend import _C
print('gsplat kernels:', _C is not None, round(time.time() - t, 1), 's')
" > /tmp/gsplat_build.log 2>&1 &
GSPLAT=$!
python3 -c "
import time; t = time.time()
from stealth_ns.raster import cpp_backend
print('stealth-ns extension:', cpp_backend.load_extension() is not None, round(time.time() - t, 1), 's')
"
wait $GSPLAT
tail -5 /tmp/gsplat_build.log
SO=$(find ~/.cache/torch_extensions -name gsplat_cuda.so 2>/dev/null | head -1)
[ -n "$SO" ] && cp "$SO" "$OUT/"  # carry it as .gpu/gsplat_cuda.so next time
t gsplat-ready

# make test-gpu's tests. pytest's own script, not python -m pytest: the source tree must not shadow
# the installed package (stealth_ns.method_configs exists only installed).
if [ "$TESTS" != 0 ] && fits 130 "make test-gpu's tests"; then
    # the whole output in tests.log; warnings off so that the summary line stays in the tail
    timeout 300 "$BIN/pytest" -m cuda tests/method/test_cuda.py -p no:cacheprovider -p no:warnings -q -rfEs \
        --durations=5 >"$OUT/tests.log" 2>&1
    echo "pytest exit status $?"
    tail -15 "$OUT/tests.log"
    t tests-done
fi

# the view noise of a 1-MP image on the GPU: its ~118 launches run eagerly, and replayed as a CUDA graph
fits 15 "the view noise's timing" && python3 - <<'PY'
import time, torch
from stealth_ns.attack import normal_draw
image = torch.randint(0, 256, (756, 1008, 3), dtype=torch.uint8, device="cuda")
def median_ms(noise):
    for key in range(5):
        noise(key)
    torch.cuda.synchronize()
    times = []
    for key in range(100, 150):
        start = time.perf_counter()
        noise(key)
        torch.cuda.synchronize()
        times.append(time.perf_counter() - start)
    return sorted(times)[25] * 1e3
eager = median_ms(lambda key: normal_draw._noisy_uint8_on(image, 20.0, key))
graphed = median_ms(lambda key: normal_draw.noisy_uint8(image, 20.0, key))
print(f"view noise at 1008x756, median of 50: eager {eager:.3f} ms, CUDA graph {graphed:.3f} ms",
      f"(graphs off: {normal_draw._noise_graphs_off or 'no'})")
PY

# bench train's whole stealth-splat-lite run (3000 steps, each timed) on the carried scene, attack on, off
if [ "$BENCH" != 0 ] && [ -d .gpu/bench ]; then
    for attack in attack no-attack; do
        fits 100 "bench train --$attack on .gpu/bench" || continue
        timeout 240 "$BIN/stealth-ns" bench train --data .gpu/bench --warmup 0 --steps "$BENCH_STEPS" \
            "--$attack" --json "$OUT/bench_$attack.json" 2>&1 | grep -v -E "step/s|^\s*$" | tail -25
        t "bench-$attack-done"
    done
fi

run() {  # NAME METHOD ARGS...: one training of ITERS steps on the carried capture
    local name=$1 method=$2
    shift 2
    local start end
    start=$(date +%s.%N)
    timeout "$RUN_TIMEOUT" "$BIN/ns-train" "$method" --vis tensorboard --output-dir /tmp/runs --experiment-name gpu \
        --timestamp "$name" --max-num-iterations "$ITERS" --steps-per-eval-all-images 100000 \
        --machine.seed 0 "$@" nerfstudio-data --data .gpu/capture >"/tmp/$name.log" 2>&1
    local rc=$?
    end=$(date +%s.%N)
    echo "RUN $name rc=$rc wall=$(python3 -c "print(round($end - $start, 1))") s"
    grep -E "train_iteration|get_train_loss_dict" "/tmp/$name.log"
    [ $rc -ne 0 ] && tail -20 "/tmp/$name.log"
}
for name in $RUNS; do
    fits "$RUN_S" "$ITERS-step $name training" || continue
    case $name in
        attack) run attack stealth-splat ;;
        clean) run clean stealth-splat --pipeline.attack.enabled False ;;
        splatfacto)
            # stock splatfacto builds LPIPS at start-up and the machine is offline: an untrained AlexNet
            # in a TORCH_HOME of its own lets it start (its LPIPS means nothing; its training is unaffected)
            python3 -c "
import os, torch, torchvision
w = torchvision.models.AlexNet_Weights.IMAGENET1K_V1
os.makedirs('/tmp/th/hub/checkpoints', exist_ok=True)
torch.save(torchvision.models.alexnet().state_dict(), '/tmp/th/hub/checkpoints/' + os.path.basename(w.url))
"
            TORCH_HOME=/tmp/th run splatfacto splatfacto ;;
        *) echo "=== unknown training in RUNS: $name (attack, clean, splatfacto)" ;;
    esac
done
t trainings-done
python3 - <<'PY'
import glob, json, torch
for ck in sorted(glob.glob("/tmp/runs/gpu/*/*/nerfstudio_models/*.ckpt")):
    state = torch.load(ck, map_location="cpu", weights_only=False)["pipeline"]
    poison = state.get("_model.gauss_params.poison")
    print(ck.split("/")[4:6], "Gaussians", state["_model.gauss_params.means"].shape[0],
          "poison", None if poison is None else int(poison.sum()))
for path in glob.glob("/tmp/runs/gpu/*/*/attack/attack.json"):
    record = json.load(open(path))
    print("injection", record["injected_at_step"], record["n_poison_gaussians"], record["timings_s"])
PY
for name in attack clean; do
    [ -f "/tmp/runs/gpu/stealth-splat/$name/config.yml" ] && fits 30 "ns-eval of the $name run" || continue
    timeout 120 "$BIN/ns-eval" --load-config "/tmp/runs/gpu/stealth-splat/$name/config.yml" \
        --output-path "$OUT/eval_$name.json" >"/tmp/eval_$name.log" 2>&1 || tail -5 "/tmp/eval_$name.log"
done
t done
