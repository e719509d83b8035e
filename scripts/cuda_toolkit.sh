#!/usr/bin/env bash
# The CUDA toolkit that `cargo build --features cuda` needs, from PyPI, in .venv-cuda/ (no GPU,
# no driver, no system CUDA needed):
#
#   eval "$(scripts/cuda_toolkit.sh)"
#   cargo build --release --features cuda
#
# Progress goes to stderr; stdout is only `export` lines. Idempotent: a second run with the same
# pins installs nothing and prints the same exports.
#
# What the build needs and where it comes from (candle 0.11.1, candle-kernels 0.11.1 built by
# cudaforge, cudarc 0.19.10 with `dynamic-linking` + `cuda-version-from-build-system`):
#   - nvcc on PATH (cudaforge finds it there; cudarc runs `nvcc --version` to pick its CUDA
#     version): nvidia-cuda-nvcc, with ptxas/cicc/crt headers from nvidia-nvvm, nvidia-cuda-crt.
#   - headers cuda.h, cuda_runtime.h, cuda_fp16/bf16/fp8.h (nvidia-cuda-runtime), cub/thrust/
#     cuda/std (nvidia-cuda-cccl, in include/cccl, which nvcc.profile adds).
#   - CUDA_COMPUTE_CAP: cudaforge asks nvidia-smi otherwise, and fails without it. Default 80
#     (PTX for compute_80 runs on every GPU from Ampere on, JIT-compiled by the driver).
#   - at link time: -lcuda (the driver: a stub made here, lib/stubs/libcuda.so, SONAME
#     libcuda.so.1, every entry point returning CUDA_ERROR_STUB_LIBRARY), -lnvrtc -lcurand
#     -lcublas -lcublasLt (cudarc) and -lcudart (candle-kernels' static MoE kernels): the wheels
#     ship only libX.so.N, so unversioned libX.so links are made beside them. cudarc searches
#     $CUDA_ROOT/lib and $CUDA_ROOT/lib/stubs once CUDA_ROOT (or CUDA_PATH/CUDA_HOME) is set.
#
# CUDA 13.0 on purpose: a binary's PTX must not be newer than the driver that JIT-compiles it,
# and the GPU machines this project borrows run driver 580 (CUDA 13.0). nvcc 13.1+ emits PTX 9.1,
# which a 580 driver rejects. A binary built here runs where libcublas.so.13, libcurand.so.10,
# libnvrtc.so.13, libcudart.so.13 and a driver >= 580 are found (`LD_LIBRARY_PATH`).
#
# Env: CUDA_VENV (default: .venv-cuda in the repo root), PYTHON (python3), CUDA_COMPUTE_CAP
# (default: nvidia-smi's, else 80), CC (cc, for the stub).
set -euo pipefail

repo=$(cd "$(dirname "$0")/.." && pwd)
venv=${CUDA_VENV:-$repo/.venv-cuda}
python=${PYTHON:-python3}

# CUDA 13.0 Update 2, pinned.
pins=(
    nvidia-cuda-nvcc==13.0.88
    nvidia-cuda-crt==13.0.88
    nvidia-nvvm==13.0.88
    nvidia-cuda-runtime==13.0.96
    nvidia-cuda-cccl==13.0.85
    nvidia-cuda-nvrtc==13.0.88
    nvidia-cublas==13.0.2.14
    nvidia-curand==10.4.0.35
)

say() { echo "cuda_toolkit: $*" >&2; }
die() { say "error: $*"; exit 1; }

if [ ! -x "$venv/bin/python" ]; then
    command -v "$python" >/dev/null 2>&1 || die "no $python: Python 3 with the venv module is needed (Debian/Ubuntu: apt-get install python3 python3-venv)"
    "$python" -c 'import venv, ensurepip' >/dev/null 2>&1 \
        || die "$python has no working venv module (Debian/Ubuntu: apt-get install python3-venv)"
    say "creating $venv"
    "$python" -m venv "$venv" >&2
fi

stamp="$venv/.cuda-toolkit-pins"
want=$(printf '%s\n' "${pins[@]}")
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
    say "installing CUDA 13.0 from PyPI into $venv (~700 MB download the first time)"
    "$venv/bin/python" -m pip install --quiet --disable-pip-version-check --no-compile "${pins[@]}" >&2 \
        || die "pip install failed (no network to PyPI?)"
    printf '%s\n' "$want" >"$stamp"
else
    say "CUDA 13.0 already in $venv"
fi

site=$("$venv/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')
root="$site/nvidia/cu13"
[ -x "$root/bin/nvcc" ] || die "no nvcc at $root/bin/nvcc after install"
[ -f "$root/include/cuda.h" ] || die "no cuda.h in $root/include"

# Unversioned names for the linker (-lcudart finds libcudart.so, not libcudart.so.13).
for so in libcudart.so.13 libcublas.so.13 libcublasLt.so.13 libcurand.so.10 libnvrtc.so.13; do
    [ -f "$root/lib/$so" ] || die "missing $root/lib/$so"
    ln -sfn "$so" "$root/lib/${so%.so.*}.so"
done

# The driver stub: libcuda.so for the linker, SONAME libcuda.so.1 so that the binary loads the
# real driver where it runs. Every cu* name in cuda.h (a superset of what cudarc 0.19 binds for
# CUDA 13.0) returns 34, CUDA_ERROR_STUB_LIBRARY. libcuda.so.1 beside it only for running a
# CUDA build's `--help` on a machine without a driver: never put lib/stubs on LD_LIBRARY_PATH
# where a GPU is.
stubs="$root/lib/stubs"
if [ ! -f "$stubs/libcuda.so" ] || [ "$root/include/cuda.h" -nt "$stubs/libcuda.so" ]; then
    say "making the driver stub $stubs/libcuda.so"
    mkdir -p "$stubs"
    src="$stubs/libcuda_stub.c"
    grep -ohE '\bcu[A-Z][A-Za-z0-9_]*' "$root/include/cuda.h" | sort -u \
        | awk '{ printf "int %s(void) { return 34; }\n", $1 }' >"$src"
    [ "$(wc -l <"$src")" -gt 300 ] || die "found too few driver entry points in cuda.h"
    "${CC:-cc}" -shared -fPIC -O0 -w -Wl,-soname,libcuda.so.1 -o "$stubs/libcuda.so" "$src" >&2 \
        || die "cannot compile the libcuda stub with ${CC:-cc}"
    ln -sfn libcuda.so "$stubs/libcuda.so.1"
fi

ver=$("$root/bin/nvcc" --version)
case $ver in *"release 13.0,"*) ;; *) die "$root/bin/nvcc is not CUDA 13.0: $ver" ;; esac

cap=${CUDA_COMPUTE_CAP:-}
if [ -z "$cap" ] && command -v nvidia-smi >/dev/null 2>&1; then
    cap=$(nvidia-smi --query-gpu=compute_cap --format=csv,noheader 2>/dev/null | head -n 1 | tr -d ' .') || cap=
fi
cap=${cap:-80}
say "nvcc: $(PATH="$root/bin:$PATH" nvcc --version | grep release); CUDA_COMPUTE_CAP=$cap"

q() { printf "'%s'" "${1//\'/\'\\\'\'}"; }
echo "export CUDA_ROOT=$(q "$root")"
echo "export CUDA_PATH=$(q "$root")"
echo "export CUDA_HOME=$(q "$root")"
echo "export CUDA_COMPUTE_CAP=$(q "$cap")"
# shellcheck disable=SC2016 # expanded by the caller's eval
echo "export PATH=$(q "$root/bin")"':"$PATH"'
# shellcheck disable=SC2016
echo "export LD_LIBRARY_PATH=$(q "$root/lib")"'"${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"'
