#!/usr/bin/env bash
# Train pednav on this machine: build (release), then start the curriculum
# service, the learner and N actors under one supervisor (pednav-run).
#
#   ./deploy/run_local.sh --actors 2                       # new run, CPU preset
#   ./deploy/run_local.sh --actors 2 --config FILE         # new run, your config
#   ./deploy/run_local.sh --actors 2 --run-dir runs/X      # new run X (CPU preset), or resume it
#   ./deploy/run_local.sh --actors 4 --config deploy/configs/paper/navacl_plus_s_16.toml --device cuda
#                                                          # the paper's setting, learner on the GPU
#   ./deploy/run_local.sh --actors 0 --listen tcp/0.0.0.0:7447 --run-dir runs/big
#                                                          # a learner host that actor hosts join:
#       target/release/pednav-run join --connect tcp/LEARNER_HOST:7447 --actors 16 --run-dir runs/big
#
# Ctrl-C (or SIGTERM) stops the actors, then the learner (final checkpoint) and
# the curriculum service (saved state); running the same --run-dir again resumes.
# Everything else (--seed, --set FIELD=VALUE, --learner-threads, --envs, --device, --actor-device,
# --listen, --tls-ca/--tls-cert/--tls-key for mutual TLS between hosts: docs/multi-host.md)
# is passed to `pednav-run launch`; see `target/release/pednav-run launch --help`.
# `--device cuda[:N]` (or --actor-device) builds and runs the CUDA binaries
# (deploy/build_cuda.sh, target-cuda/release; no GPU is needed to build them).
#
# Environment: PEDNAV_SKIP_BUILD=1 skips the build (binaries must exist);
# PEDNAV_BIN_DIR picks the folder holding the binaries (default target/release,
# or target-cuda/release with a CUDA device).
set -euo pipefail
cd "$(dirname "$0")/.."

args=("$@")
have_config=0
run_dir=""
cuda=0
prev=""
for a in "${args[@]}"; do
    case "$a" in
        --config|--config=*) have_config=1 ;;
        --run-dir=*) run_dir="${a#--run-dir=}" ;;
        --device=cuda*|--actor-device=cuda*) cuda=1 ;;
        -h|--help)
            sed -n '2,/^set -euo/p' "$0" | sed '$d' | sed 's/^# \{0,1\}//'
            exit 0 ;;
    esac
    [[ "$prev" == "--run-dir" ]] && run_dir="$a"
    [[ ( "$prev" == "--device" || "$prev" == "--actor-device" ) && "$a" == cuda* ]] && cuda=1
    prev="$a"
done
# A new run without --config uses the reduced CPU preset; a resume reads the run's own config.
if [[ $have_config -eq 0 && ( -z "$run_dir" || ! -f "$run_dir/config.toml" ) ]]; then
    args+=(--config deploy/configs/cpu_reduced.toml)
fi

default_bins=target/release
if [[ "${PEDNAV_SKIP_BUILD:-0}" != 1 ]]; then
    ./deploy/setup_system.sh
    if [[ $cuda -eq 1 ]]; then
        echo "pednav: building the CUDA binaries (the first build takes ≈ 15 minutes)…" >&2
        ./deploy/build_cuda.sh --bins >&2
    else
        echo "pednav: building (release; the first build takes several minutes)…" >&2
        CARGO_BUILD_JOBS="${CARGO_BUILD_JOBS:-$(nproc)}" cargo build --release --locked \
            -p pednav-run -p pednav-actor -p pednav-learner -p pednav-curriculum >&2
    fi
fi
[[ $cuda -eq 1 ]] && default_bins="${PEDNAV_CUDA_TARGET:-target-cuda}/release"
bin_dir="${PEDNAV_BIN_DIR:-$default_bins}"
if [[ ! -x "$bin_dir/pednav-run" ]]; then
    hint="build them: ./deploy/run_local.sh without PEDNAV_SKIP_BUILD=1"
    [[ $cuda -eq 1 ]] && hint="build them: ./deploy/build_cuda.sh --bins (no GPU needed)"
    echo "error: no pednav binaries in $bin_dir; $hint" >&2
    exit 1
fi
exec "$bin_dir/pednav-run" launch --bin-dir "$bin_dir" "${args[@]}"
