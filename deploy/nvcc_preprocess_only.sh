#!/usr/bin/env bash
# nvcc for `cargo check` (deploy/build_cuda.sh --check puts it in the toolkit's bin/
# and names it in $NVCC): the CUDA counterpart of what `cargo check` does to Rust —
# everything up to code generation, no code.
#
# candle-kernels' build script compiles candle's CUDA kernels (PTX, and a static
# library of its quantised and MoE kernels) whenever the `cuda` feature is on, also
# under `cargo check`, which then never links or loads them, and on 2 cores that
# compile was most of the check's time (docs/testing.md). This wrapper runs NVIDIA's nvcc
# ($PEDNAV_REAL_NVCC) for real on every query (--version, --list-gpu-code) and runs
# its preprocessor on every kernel with the build's own flags, so a toolkit whose
# headers or options no longer fit candle's kernels still fails here; then it writes
# the outputs the build script names (the .ptx files, objects, the archive) empty.
# Nothing built through it can run: `build_cuda.sh` without --check (and with
# PEDNAV_CUDA_CHECK_KERNELS=1, the check too) compiles the kernels with nvcc itself.
set -euo pipefail
real="${PEDNAV_REAL_NVCC:?nvcc_preprocess_only.sh: set PEDNAV_REAL_NVCC to the real nvcc}"
mode=query
flags=() outputs=() sources=() outdir=""
for ((i = 1; i <= $#; i++)); do
    a="${!i}"
    case "$a" in
        --ptx) mode=ptx ;;
        -c) mode=object ;;
        --lib) mode=archive ;;
        -o) i=$((i + 1)); outputs+=("${!i}") ;;
        --output-directory) i=$((i + 1)); outdir="${!i}" ;;
        *.cu) sources+=("$a") ;;
        *) flags+=("$a") ;;
    esac
done
case "$mode" in
    query) exec "$real" "$@" ;;
    ptx | object)
        for src in "${sources[@]}"; do
            "$real" -E "${flags[@]}" "$src" -o /dev/null
            if [[ "$mode" == ptx ]]; then
                out="${outdir:-.}/$(basename "${src%.cu}").ptx"
                : > "$out"
            fi
        done ;;
    archive) ;;
esac
for out in "${outputs[@]}"; do
    : > "$out"
done
