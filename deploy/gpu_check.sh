#!/usr/bin/env bash
# The GPU checks of pednav, in one script for a machine with an NVIDIA GPU, the CUDA
# driver and the binaries of deploy/build_cuda.sh — no Rust toolchain needed.
#
#   ./deploy/gpu_check.sh [BINS] [OUT_DIR]
#
# BINS: target-cuda/pednav-cuda.tar.xz (default) or a folder holding its binaries.
# OUT_DIR: where figures and logs go (default: $OUT if set, else gpu-check-out).
# Steps (each prints its figures; a failing step is reported and the others still run):
#   1. the GPU (nvidia-smi);
#   2. correctness: one DSAC update on the CPU and on the GPU from the same weights and
#      batch, CPU preset and paper networks (pednav-device-check: losses within 1e-3,
#      weights within two Adam steps);
#   3. PyTorch's reference of the same update on the same GPU, when a Python with
#      torch is available (dsac_ref.py --device cuda);
#   4. the learner bench on CUDA, configs (a)–(d) and the actor's step, with the
#      ratios against step 3 (dsac_update --device cuda --json OUT_DIR/cuda.json);
#   5. a 5-minute paper-config training run (NavACL⁺ (S), 84², N_h 16, batch 64;
#      warm-up cut to 5,000 steps so updates start): learner on the GPU, one actor
#      rendering on the CPU; prints ms per update and env steps/s.
# Exit status: non-zero if the correctness check failed.
set -uo pipefail
cd "$(dirname "$0")/.."
bins_in="${1:-target-cuda/pednav-cuda.tar.xz}"
out="${2:-${OUT:-gpu-check-out}}"
mkdir -p "$out"
out="$(cd "$out" && pwd)"
log() { echo "== $*" | tee -a "$out/summary.txt"; }
status=0

if [ -d "$bins_in" ]; then
    bins="$(cd "$bins_in" && pwd)"
elif [ -f "$bins_in" ]; then
    bins="$(mktemp -d)"
    tar -C "$bins" -xJf "$bins_in" || { echo "error: cannot unpack $bins_in" >&2; exit 1; }
else
    echo "error: $bins_in not found: build it with deploy/build_cuda.sh and carry it here" >&2
    exit 1
fi
for b in pednav-device-check dsac_update pednav-run pednav-learner pednav-actor pednav-curriculum; do
    [ -x "$bins/$b" ] || { echo "error: $bins/$b missing (rebuild with deploy/build_cuda.sh)" >&2; exit 1; }
done

# The CUDA libraries the binaries link (libcublas, libcublasLt, libcurand, libnvrtc,
# libcudart; libcuda.so.1 comes with the driver): from PyTorch's CUDA wheels when the
# system's library path has none.
if ! ldconfig -p 2>/dev/null | grep -q 'libcublas\.so\.13'; then
    wheel_libs=$(python3 - 2>/dev/null <<'PY'
import glob, os
try:
    import nvidia
except ImportError:
    raise SystemExit
print(":".join(sorted({os.path.dirname(p) for base in nvidia.__path__
                       for p in glob.glob(os.path.join(base, "**", "lib*.so*"), recursive=True)})))
PY
)
    [ -n "$wheel_libs" ] && export LD_LIBRARY_PATH="$wheel_libs${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
fi
# cuRAND travels in the tarball (PyTorch's wheels do not carry it); a system copy wins.
[ -d "$bins/lib" ] && export LD_LIBRARY_PATH="${LD_LIBRARY_PATH:+$LD_LIBRARY_PATH:}$bins/lib"
missing=$(ldd "$bins/pednav-device-check" 2>/dev/null | grep 'not found' || true)
if [ -n "$missing" ]; then
    echo "error: the CUDA binaries cannot find these libraries (install the CUDA 13 runtime, or a PyTorch with CUDA 13 wheels):" >&2
    echo "$missing" >&2
    exit 1
fi

log "1. GPU"
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv 2>&1 | tee -a "$out/summary.txt"
grep -m1 'model name' /proc/cpuinfo | tee -a "$out/summary.txt"

log "2. correctness: one update on cpu and cuda"
for cfg in deploy/configs/cpu_reduced.toml deploy/configs/paper/navacl_plus_s_16.toml; do
    if ! "$bins/pednav-device-check" --device cuda --config "$cfg" 2>>"$out/device-check.log" | tee -a "$out/summary.txt"; then
        log "FAILED: device check with $cfg (see $out/device-check.log)"
        status=1
    fi
done

log "3. PyTorch's reference of the same update on the same GPU"
ref=""
for r in ../shared/bench/torch_ref/dsac_ref.py target-cuda/torch_ref/dsac_ref.py; do [ -f "$r" ] && ref="$r" && break; done
pytorch=()
if [ -n "$ref" ] && python3 -c 'import torch; assert torch.cuda.is_available()' 2>/dev/null; then
    if python3 "$ref" --device cuda --only A B C D act --warmup 3 --iters 10 > "$out/pytorch-cuda.txt" 2>"$out/pytorch-cuda.log"; then
        tee -a "$out/summary.txt" < "$out/pytorch-cuda.txt"
        pytorch=(--pytorch "$out/pytorch-cuda.txt")
    else
        log "FAILED: PyTorch reference (see $out/pytorch-cuda.log)"
    fi
else
    log "skipped: no dsac_ref.py (carry ../shared/bench/torch_ref as target-cuda/torch_ref) or no torch with CUDA"
fi

log "4. learner bench on cuda (ratios against step 3's PyTorch figures, also in cuda.json)"
"$bins/dsac_update" --device cuda --json "$out/cuda.json" "${pytorch[@]}" 2>&1 | tee "$out/bench-cuda.txt" \
    | grep -v '^$' | tee -a "$out/summary.txt" || log "FAILED: dsac_update --device cuda (see $out/bench-cuda.txt)"

log "5. 5-minute paper-config run: learner on cuda, 1 actor on the CPU"
run="$(mktemp -d)/run"
cfg="$out/paper-check.toml"
if "$bins/pednav-run" check deploy/configs/paper/navacl_plus_s_16.toml 2>/dev/null \
    | sed 's/^warmup = .*/warmup = 5000/' > "$cfg"; then
    timeout -s INT 300 "$bins/pednav-run" launch --actors 1 --config "$cfg" --run-dir "$run" --device cuda \
        --bin-dir "$bins" 2> "$out/run.log"
    cp "$run/metrics/learner.csv" "$out/learner.csv" 2>/dev/null
    tail -c 2000 "$out/run.log" | tr '\r' '\n' | tail -5 | tee -a "$out/summary.txt"
    python3 - "$out/learner.csv" <<'PY' 2>&1 | tee -a "$out/summary.txt" || log "FAILED: no learner metrics (see $out/run.log and $run/logs)"
import csv, sys
rows = list(csv.DictReader(open(sys.argv[1])))
if len(rows) < 2:
    raise SystemExit("run too short to measure")
first, last = rows[0], rows[-1]
dt = float(last["elapsed_s"]) - float(first["elapsed_s"])
steps = float(last["step"]) - float(first["step"])
ups = float(last.get("updates", 0) or 0) - float(first.get("updates", 0) or 0)
print(f"env steps/s {steps / dt:.0f}; updates {ups:.0f} in {dt:.0f} s" + (f" = {1e3 * dt / ups:.1f} ms per update (learner-side wall time)" if ups > 0 else ""))
PY
    cp -r "$run/logs" "$out/run-logs" 2>/dev/null
else
    log "FAILED: cannot resolve the paper config"
fi
log "done: figures in $out (status $status)"
exit $status
