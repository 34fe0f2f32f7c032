#!/usr/bin/env bash
# One short check of a GPU machine (at most ~5 minutes on one H100/H200): MJX env throughput,
# train_epoch throughput and compile time, and reach + push trained towards 0.9 test success.
# Writes OUT/gpu_check.json and OUT/gpu_check.md after every stage (a run cut off still leaves
# figures). The logic is daddpg_jax/tools/gpu_check.py; this wrapper only sets up Python.
#
#   bash experiments/gpu_check.sh --out gpu_check                 # the current environment
#   bash experiments/gpu_check.sh --wheels .whl --out gpu_check   # bare CUDA JAX image: install
#                                       # the MuJoCo/MJX wheels in .whl/ offline into /tmp/site
#   bash experiments/gpu_check.sh --smoke --out /tmp/gpu_smoke    # tiny, on a CPU (checks the tool)
#   bash experiments/gpu_check.sh --help                          # every option
#
# Environment: PYTHON (default python3), GPU_CHECK_SITE (default /tmp/site).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
PYTHON="${PYTHON:-python3}"
wheels=""
args=()
while [ $# -gt 0 ]; do
  case "$1" in
    --wheels) [ $# -ge 2 ] || { echo "gpu_check.sh: --wheels needs a directory" >&2; exit 2; }
              wheels="$2"; shift 2 ;;
    --wheels=*) wheels="${1#--wheels=}"; shift ;;
    *) args+=("$1"); shift ;;
  esac
done
if [ -n "$wheels" ]; then
  site="${GPU_CHECK_SITE:-/tmp/site}"
  shopt -s nullglob
  whl=("$wheels"/*.whl)
  shopt -u nullglob
  [ ${#whl[@]} -gt 0 ] || { echo "gpu_check.sh: no .whl files in $wheels" >&2; exit 2; }
  "$PYTHON" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
    --target "$site" "${whl[@]}"
  export PYTHONPATH="$site:$ROOT${PYTHONPATH:+:$PYTHONPATH}"
else
  export PYTHONPATH="$ROOT${PYTHONPATH:+:$PYTHONPATH}"
fi
exec "$PYTHON" -m daddpg_jax.tools.gpu_check ${args[@]+"${args[@]}"}
