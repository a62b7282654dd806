#!/usr/bin/env bash
# Build pednav's CUDA binaries on any x86-64 Linux machine — no GPU needed to build.
#
#   ./deploy/build_cuda.sh            # release binaries + bench into target-cuda/, stripped,
#                                     # and target-cuda/pednav-cuda.tar.xz to carry to a GPU machine
#   ./deploy/build_cuda.sh --bins     # only the process binaries (target-cuda/release; what
#                                     # `run_local.sh --device cuda` runs)
#   ./deploy/build_cuda.sh --check    # only `cargo check` pednav-nets with CUDA (what CI runs;
#                                     # candle's kernels preprocessed, not compiled:
#                                     # deploy/nvcc_preprocess_only.sh)
#
# What it does:
# - installs NVIDIA's CUDA compiler from PyPI (nvidia-cuda-nvcc, -cccl, -runtime, -crt)
#   into a virtualenv outside the repository ($PEDNAV_CUDA_VENV, default
#   ~/.venvs/pednav-cuda, ≈ 370 MB) on first use;
# - builds with `--features pednav-nets/cuda` into its own target directory
#   ($PEDNAV_CUDA_TARGET, default target-cuda), so the CPU build stays as it is.
#
# Environment: CUDA_COMPUTE_CAP (default 90: H100/H200; 80 for A100, 89 for L4/4090)
# picks the GPU generation candle's kernels are compiled for; CUDARC_CUDA_VERSION
# (default 13000) the CUDA API level cudarc binds (13.0 runs on any CUDA 13 driver;
# cudarc 0.19 rejects nvcc 13.5's own version string).
#
# Linking: candle links the CUDA libraries dynamically (libcuda, libcublas,
# libcublasLt, libcurand, libnvrtc, libcudart). A machine without a GPU has none of
# them but libcudart (from PyPI), so the build links against stubs generated from the
# symbols cudarc imports, under the real libraries' sonames (what NVIDIA's own stub
# libraries are for). At run time the binaries need the real ones: the GPU driver's
# libcuda.so.1 and CUDA 13's libcublas/libcurand/libnvrtc/libcudart. PyTorch's CUDA 13
# wheels carry all but libcurand (candle creates a cuRAND generator with every CUDA
# device), so the tarball carries libcurand.so.10 from PyPI's nvidia-curand, and
# deploy/gpu_check.sh puts both on LD_LIBRARY_PATH. The tarball is packed with a
# dictionary larger than one binary, so their shared code and CUDA kernels are
# stored once (≈ 13 MB for the seven binaries instead of ≈ 48).
set -euo pipefail
cd "$(dirname "$0")/.."
mode=build
case "${1:-}" in
    --check) mode=check ;;
    --bins) mode=bins ;;
    "") ;;
    -h|--help) sed -n '2,/^set -euo/p' "$0" | sed '$d' | sed 's/^# \{0,1\}//'; exit 0 ;;
    *) echo "build_cuda.sh: unknown argument '$1' (try --help)" >&2; exit 2 ;;
esac

venv="${PEDNAV_CUDA_VENV:-$HOME/.venvs/pednav-cuda}"
target="${PEDNAV_CUDA_TARGET:-target-cuda}"
packages=(nvidia-cuda-nvcc nvidia-cuda-cccl nvidia-cuda-runtime nvidia-cuda-crt)
cuda_root() {
    "$venv/bin/python" - <<'PY'
import os, nvidia
for base in nvidia.__path__:
    for sub in sorted(os.listdir(base), reverse=True):
        if os.path.isfile(os.path.join(base, sub, "bin", "nvcc")):
            print(os.path.join(base, sub)); raise SystemExit
PY
}
if [ ! -x "$venv/bin/python" ] || [ -z "$(cuda_root 2>/dev/null)" ]; then
    echo "build_cuda.sh: installing the CUDA compiler into $venv (PyPI: ${packages[*]})" >&2
    command -v python3 >/dev/null || { echo "error: python3 is needed to install nvcc from PyPI" >&2; exit 1; }
    python3 -m venv "$venv" || { echo "error: cannot create $venv (on Debian/Ubuntu: apt-get install -y python3-venv)" >&2; exit 1; }
    "$venv/bin/pip" install -q --upgrade pip
    "$venv/bin/pip" install -q "${packages[@]}"
fi
root="$(cuda_root)"
[ -n "$root" ] || { echo "error: no nvcc found under $venv after installing ${packages[*]}" >&2; exit 1; }
export PATH="$root/bin:$PATH" CUDA_ROOT="$root" CUDA_PATH="$root" CUDA_TOOLKIT_ROOT_DIR="$root"
export CUDA_COMPUTE_CAP="${CUDA_COMPUTE_CAP:-90}" CUDARC_CUDA_VERSION="${CUDARC_CUDA_VERSION:-13000}"
export CARGO_BUILD_JOBS="${CARGO_BUILD_JOBS:-$(nproc)}"
echo "build_cuda.sh: $(nvcc --version | tail -1), compute capability $CUDA_COMPUTE_CAP, target dir $target" >&2
features=(--features pednav-nets/cuda)
start=$(date +%s)

if [ "$mode" = check ]; then
    # Only pednav-nets's library has code under `feature = "cuda"` (its device
    # selection); its tests and benches, and the crates above it, compile the same
    # source either way, so checking them again here (with criterion and proptest, or
    # wgpu, rapier and iceoryx2 under them) would only repeat the CPU build's work.
    # candle's kernels are preprocessed, not compiled: `cargo check` never uses them
    # (deploy/nvcc_preprocess_only.sh; PEDNAV_CUDA_CHECK_KERNELS=1 compiles them too).
    # Its empty kernels get a target directory of their own: candle's build script
    # caches kernels by source and flags, not by compiler, and would take them for
    # compiled ones in any later build beside them.
    check_target="$target"
    if [[ "${PEDNAV_CUDA_CHECK_KERNELS:-0}" != 1 ]]; then
        install -m 755 deploy/nvcc_preprocess_only.sh "$root/bin/nvcc-preprocess-only"
        export PEDNAV_REAL_NVCC="$root/bin/nvcc" NVCC="$root/bin/nvcc-preprocess-only"
        check_target="$target/preprocess-only"
    fi
    cargo check --locked --target-dir "$check_target" "${features[@]}" -p pednav-nets --lib
    echo "build_cuda.sh: CUDA build checks ($(( $(date +%s) - start )) s)" >&2
    exit 0
fi

# Link-time stubs (see the header): one per library, every function cudarc imports
# from it, under the library's soname, next to libcudart in the toolkit's lib folder
# (candle's build script puts that folder on the link path).
cargo build --release --locked --target-dir "$target" "${features[@]}" -p pednav-nets
cudarc_lib=$(ls -t "$target"/release/deps/libcudarc-*.rlib | head -1)
lib="$root/lib"
stub_src="$(mktemp -d)"
make_stub() { # name soname symbol-regex [exclude-regex]
    nm --undefined-only "$cudarc_lib" 2>/dev/null | awk '$1 == "U" {print $2}' | grep -E "$3" \
        | { if [ -n "${4:-}" ]; then grep -vE "$4"; else cat; fi; } | sort -u \
        | sed 's/.*/void &(void) {}/' > "$stub_src/$1.c"
    [ -s "$stub_src/$1.c" ] || { echo "error: no $1 symbols found in $cudarc_lib" >&2; exit 1; }
    cc -shared -fPIC -Wl,-soname,"$2" -o "$lib/lib$1.so" "$stub_src/$1.c"
}
make_stub cuda libcuda.so.1 '^cu[A-Z]'
make_stub cublas libcublas.so.13 '^cublas' '^cublasLt'
make_stub cublasLt libcublasLt.so.13 '^cublasLt'
make_stub curand libcurand.so.10 '^curand'
make_stub nvrtc libnvrtc.so.13 '^nvrtc'
ln -sf libcudart.so.13 "$lib/libcudart.so"
rm -rf "$stub_src"

bins=(pednav-run pednav-learner pednav-device-check pednav-actor pednav-curriculum pednav-eval)
cargo build --release --locked --target-dir "$target" "${features[@]}" \
    -p pednav-run -p pednav-learner -p pednav-actor -p pednav-curriculum -p pednav-experiments
if [ "$mode" = bins ]; then
    echo "build_cuda.sh: binaries in $target/release ($(( $(date +%s) - start )) s)" >&2
    exit 0
fi
bench=$(cargo bench --locked --target-dir "$target" "${features[@]}" -p pednav-learner --bench dsac_update --no-run \
    --message-format=json 2>/dev/null | sed -n 's/.*"executable":"\([^"]*\)".*/\1/p' | grep "/dsac_update-[^/]*$" | tail -1)
[ -x "$bench" ] || { echo "error: the dsac_update bench did not build" >&2; exit 1; }
out="$target/bin"
mkdir -p "$out"
for b in "${bins[@]}"; do strip -o "$out/$b" "$target/release/$b"; done
strip -o "$out/dsac_update" "$bench"
# The real cuRAND library travels with them (see the header).
if [ ! -f "$lib/libcurand.so.10" ] || [ -L "$lib/libcurand.so.10" ]; then
    "$venv/bin/pip" install -q nvidia-curand
fi
mkdir -p "$out/lib"
cp -L "$lib/libcurand.so.10" "$out/lib/"
tar -C "$out" -cf - "${bins[@]}" dsac_update lib | xz -6 --lzma2=dict=192MiB -T1 > "$target/pednav-cuda.tar.xz"
# The PyTorch reference travels too (gpu_check.sh compares against it on the GPU).
if [ -f ../shared/bench/torch_ref/dsac_ref.py ]; then
    mkdir -p "$target/torch_ref" && cp ../shared/bench/torch_ref/dsac_ref.py "$target/torch_ref/"
fi
echo "build_cuda.sh: built in $(( $(date +%s) - start )) s; stripped binaries in $out:" >&2
ls -l "$out" >&2
echo "build_cuda.sh: carry $target/pednav-cuda.tar.xz ($(du -h "$target/pednav-cuda.tar.xz" | cut -f1)) to the GPU machine and run deploy/gpu_check.sh there" >&2
