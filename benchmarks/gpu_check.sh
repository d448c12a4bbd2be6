#!/usr/bin/env bash
# GPU check: trials/s of MJX-JAX, MJX-Warp and MuJoCo C (reference) at B = 64 ... 16384 and
# each backend's outcome agreement with MuJoCo C, printed as JSON (also written to
# bench_out/gpu_check.json). Meant to finish in <= 5 min on a machine with an NVIDIA GPU
# (cells that would overrun a 280 s budget are recorded as skipped).
#
# UNTESTED ON A GPU: written without a GPU at hand; checked only with --quick on a 2-core
# CPU (B = 8, 16). Expect to fix things on the first GPU run (Warp's CUDA kernels, memory of
# the Warp contact buffer at B = 16384: 64 contacts per trial).
#
#   bash benchmarks/gpu_check.sh              # on the GPU machine (repo root, .venv with
#                                             # pip install -e '.[warp]' and jax[cuda])
#   bash benchmarks/gpu_check.sh --quick      # CPU smoke check
# Extra arguments go to benchmarks/gpu_check.py (see its --help); GPU_CHECK_TIMEOUT (s, default
# 300) bounds the whole run.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PY:-.venv/bin/python}
export JAXGRASP_CACHE_DIR=${JAXGRASP_CACHE_DIR:-$PWD/.cache/jax}
export XLA_PYTHON_CLIENT_PREALLOCATE=${XLA_PYTHON_CLIENT_PREALLOCATE:-false}
if command -v nvidia-smi >/dev/null 2>&1; then
  nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader >&2 || true
else
  echo "gpu_check: no nvidia-smi; running on $("$PY" -c 'import jax; print(jax.default_backend())')" >&2
fi
"$PY" -c 'import jax; print("jax devices:", jax.devices())' >&2
exec timeout "${GPU_CHECK_TIMEOUT:-300}" "$PY" benchmarks/gpu_check.py "$@"
