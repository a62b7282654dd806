#!/usr/bin/env bash
# Train pednav on this machine: build (release), then start the curriculum
# service, the learner and N actors under one supervisor (pednav-run).
#
#   ./deploy/run_local.sh --actors 2                       # new run, CPU preset
#   ./deploy/run_local.sh --actors 2 --config FILE         # new run, your config
#   ./deploy/run_local.sh --actors 2 --run-dir runs/X      # new run X (CPU preset), or resume it
#
# Ctrl-C (or SIGTERM) stops the actors, then the learner (final checkpoint) and
# the curriculum service (saved state); running the same --run-dir again resumes.
# Everything else (--seed, --learner-threads) is passed to `pednav-run launch`;
# see `target/release/pednav-run launch --help`.
#
# Environment: PEDNAV_SKIP_BUILD=1 skips the build (binaries must exist);
# PEDNAV_BIN_DIR picks the folder holding the binaries (default target/release).
set -euo pipefail
cd "$(dirname "$0")/.."

args=("$@")
have_config=0
run_dir=""
prev=""
for a in "${args[@]}"; do
    case "$a" in
        --config|--config=*) have_config=1 ;;
        --run-dir=*) run_dir="${a#--run-dir=}" ;;
        -h|--help)
            sed -n '2,16p' "$0" | sed 's/^# \{0,1\}//'
            exit 0 ;;
    esac
    [[ "$prev" == "--run-dir" ]] && run_dir="$a"
    prev="$a"
done
# A new run without --config uses the reduced CPU preset; a resume reads the run's own config.
if [[ $have_config -eq 0 && ( -z "$run_dir" || ! -f "$run_dir/config.toml" ) ]]; then
    args+=(--config deploy/configs/cpu_reduced.toml)
fi

if [[ "${PEDNAV_SKIP_BUILD:-0}" != 1 ]]; then
    ./deploy/setup_system.sh
    echo "pednav: building (release; the first build takes several minutes)…" >&2
    CARGO_BUILD_JOBS="${CARGO_BUILD_JOBS:-$(nproc)}" cargo build --release --locked \
        -p pednav-runtime -p pednav-actor -p pednav-learner-process -p pednav-curriculum-service >&2
fi
bin_dir="${PEDNAV_BIN_DIR:-target/release}"
exec "$bin_dir/pednav-run" launch --bin-dir "$bin_dir" "${args[@]}"
