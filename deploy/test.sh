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
