#!/usr/bin/env bash
# The Python package's tests (python/tests, pytest): a virtual environment inside the
# clone (target/python-venv, nothing cached outside it), the extension built in
# release from this workspace by maturin (`pip install ./python`, which reuses the
# workspace's target/ for the Rust dependencies), then pytest with numpy and Gymnasium
# — no PyTorch — and the `report` extra (rliable, scipy, matplotlib) for pednav_report's
# tests (tests/test_report.py). Called by deploy/test.sh; runs alone as well.
set -euo pipefail
cd "$(dirname "$0")/.."
venv=target/python-venv
if [[ ! -x "$venv/bin/python" ]]; then
    python3 -m venv "$venv"
fi
"$venv/bin/python" -m pip install --quiet --upgrade pip
"$venv/bin/python" -m pip install --quiet "./python[test,report]"
"$venv/bin/python" -m pytest python/tests -q "$@"
