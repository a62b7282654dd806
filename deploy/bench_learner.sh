#!/usr/bin/env bash
# Learner and actor compute side by side with PyTorch, on every instruction-set path
# of this CPU: PyTorch's reference, then pednav's dsac_update bench once per path
# (PEDNAV_ISA=avx2, avx512, … as the CPU allows), then PyTorch again; the ratios use
# PyTorch's faster run. These machines are shared and noisy: only figures measured
# together count (docs/design.md §8).
#
# Usage: deploy/bench_learner.sh [OUT_DIR] [-- extra dsac_update flags, e.g. --quick --only c,d]
# Writes OUT_DIR/pytorch-{1,2}.txt, OUT_DIR/<isa>.json and OUT_DIR/<isa>.txt
# (default OUT_DIR: target/bench-learner). The PyTorch virtualenv is created outside
# the repository on first use (see ../shared/bench/torch_ref/bench.sh).
set -euo pipefail
cd "$(dirname "$0")/.."
# OUT_DIR is optional: a first argument that is "--" or a flag starts the bench's flags.
out=target/bench-learner
if [ $# -gt 0 ] && [ "${1#-}" = "$1" ]; then
  out=$1
  shift
fi
[ "${1:-}" = "--" ] && shift
mkdir -p "$out"
torch=../shared/bench/torch_ref/bench.sh
[ -x "$torch" ] || [ -f "$torch" ] || { echo "error: $torch not found (../shared must sit beside the repository)" >&2; exit 1; }
export CARGO_BUILD_JOBS="${CARGO_BUILD_JOBS:-2}"
cargo bench --locked -p pednav-learner --bench dsac_update --no-run 2>&1 | tail -1
bin=$(cargo bench --locked -p pednav-learner --bench dsac_update --no-run --message-format=json 2>/dev/null \
  | sed -n 's/.*"executable":"\([^"]*\)".*/\1/p' | grep "/dsac_update-[^/]*$" | tail -1)
[ -x "$bin" ] || { echo "error: could not locate the dsac_update bench binary" >&2; exit 1; }
paths=()
grep -qw fma /proc/cpuinfo && grep -qw avx2 /proc/cpuinfo && paths+=(avx2)
grep -qw avx512f /proc/cpuinfo && paths+=(avx512)
[ ${#paths[@]} -gt 0 ] || paths=(baseline)
echo "# $(date -Is) $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs) · commit $(git rev-parse --short HEAD) · paths: ${paths[*]}"
bash "$torch" > "$out/pytorch-1.txt" 2> "$out/pytorch-1.log"
for isa in "${paths[@]}"; do
  echo "## PEDNAV_ISA=$isa"
  PEDNAV_ISA=$isa "$bin" --json "$out/$isa.json" --pytorch "$out/pytorch-1.txt" "$@" | tee "$out/$isa.txt"
done
bash "$torch" > "$out/pytorch-2.txt" 2> "$out/pytorch-2.log"
python3 - "$out" "${paths[@]}" <<'PY'
import json, sys
out, paths = sys.argv[1], sys.argv[2:]
torch = {}
for f in ("pytorch-1.txt", "pytorch-2.txt"):
    for line in open(f"{out}/{f}"):
        parts = line.split()
        if len(parts) != 2:
            continue
        name, ms = parts
        key = {"A": "a", "B": "b", "C": "c", "D": "d"}.get(name.split("_")[0])
        if name.startswith("act_nograd_b1_"):
            key = "act_full_1"
        elif name.startswith("act_nograd_b16_"):
            key = "act_full_16"
        if key:
            torch[key] = min(torch.get(key, float("inf")), float(ms))
runs = {isa: json.load(open(f"{out}/{isa}.json")) for isa in paths}
print("## ours / PyTorch: best repetition of ours over PyTorch's faster run of two")
print("| config | PyTorch ms | " + " | ".join(f"{i} ms | {i} ratio" for i in paths) + " |")
print("|---|---|" + "---|---|" * len(paths))
for key in ("a", "b", "c", "d", "act_full_1", "act_full_16"):
    if key not in torch or not all(key in r for r in runs.values()):
        continue
    cells = " | ".join(f"{r[key]['best_ms']:.2f} | {r[key]['best_ms'] / torch[key]:.2f}" for r in runs.values())
    print(f"| {key} | {torch[key]:.2f} | {cells} |")
for n in (1, 16):
    if all(f"act_cache_{n}" in r for r in runs.values()):
        cells = ", ".join(f"{i} {r[f'act_cache_{n}']['best_ms'] / r[f'act_full_{n}']['best_ms']:.3f}" for i, r in runs.items())
        print(f"streaming cache / full recompute, {n} obs: {cells}")
PY
