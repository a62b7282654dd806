#!/usr/bin/env bash
# Run every test of the workspace, as on a fresh machine: system packages first,
# then one release build shared by all tests (the oracle planner and the renderer
# are too slow to test unoptimised).
set -euo pipefail
cd "$(dirname "$0")/.."
export CARGO_BUILD_JOBS="${CARGO_BUILD_JOBS:-2}"
./deploy/setup_system.sh
# The process binaries first: the end-to-end tests start them as a user would.
cargo build --release --workspace --locked --bins
cargo test --release --workspace --locked "$@"
# The Gymnasium package (python/): built by maturin into a venv under target/, pytest.
./deploy/test_python.sh
# The CUDA build keeps compiling: `cargo check` with the `cuda` feature, nvcc from
# PyPI (no GPU needed; ≈ 10–15 min on 2 cores from scratch, into target-cuda/).
# PEDNAV_SKIP_CUDA_CHECK=1 skips it for a quick local run; CI always runs it.
if [[ "${PEDNAV_SKIP_CUDA_CHECK:-0}" != 1 || "${CI:-}" == true ]]; then
    ./deploy/build_cuda.sh --check
fi
