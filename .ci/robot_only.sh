#!/usr/bin/env bash
# The robot side alone: a fresh venv holding only what it needs (NumPy, h11, MuJoCo for the
# simulator), the package installed with --no-deps; from outside the repository,
# daddpg-serve serves the shipped reach policy and daddpg-robot-client runs a few episodes with
# --arms sim and --arms ur-sim (the UR path on simulated controllers). No JAX, Flax, Optax or
# Orbax is installed, so any import of them fails the run.
set -euo pipefail
repo="$(cd "$(dirname "$0")/.." && pwd)"
work="$(mktemp -d)"
PY=${PYTHON:-python3}
serve_pid=""
cleanup() { [ -n "$serve_pid" ] && kill "$serve_pid" 2>/dev/null || true; rm -rf "$work"; }
trap cleanup EXIT
"$PY" -m venv "$work/venv"
pip="$work/venv/bin/python -m pip"
$pip install -q --upgrade pip
$pip install -q "numpy>=1.26,<3" "h11>=0.14" "mujoco==4.0.0"
$pip install -q --no-deps "$repo"
cd "$work"
if "$work/venv/bin/python" -c "import jax" 2>/dev/null; then
  echo "robot-only: jax is importable in the robot venv" >&2; exit 1
fi
port=$("$work/venv/bin/python" -c "import socket; s=socket.socket(); s.bind(('127.0.0.1',0)); print(s.getsockname()[1])")
"$work/venv/bin/daddpg-serve" "$repo/tests/data/legacy_reach/policy.npz" --port "$port" \
  >"$work/serve.log" 2>&1 &
serve_pid=$!
for _ in $(seq 100); do
  "$work/venv/bin/python" -c "import urllib.request as u; u.urlopen('http://127.0.0.1:$port/health', timeout=1)" \
    2>/dev/null && break
  sleep 0.1
done
limits="$("$work/venv/bin/python" -c "import os, daddpg_jax.deploy.limits as l; print(os.path.join(l.SHIPPED, 'sim.toml'))")"
for arms in sim ur-sim; do
  "$work/venv/bin/daddpg-robot-client" --server "http://127.0.0.1:$port" --limits "$limits" \
    --arms "$arms" --fast --episodes 2 --deadline-ms 40 --json "$work/$arms.json" >/dev/null
  "$work/venv/bin/python" - "$work/$arms.json" <<'PY'
import json, sys
out = json.load(open(sys.argv[1]))
assert out["episodes_run"] == 2 and out["aborted"] is None, out
print(f"robot-only: --arms {out['arms']}: {out['episodes_run']} episodes, gate refusals "
      f"{out['gate_refusals']}")
PY
done
echo "robot-only: daddpg-serve and daddpg-robot-client ran without JAX"
