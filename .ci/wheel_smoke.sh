#!/usr/bin/env bash
# Builds the wheel, installs it (not editable) into a fresh venv and, from outside the
# repository, steps an env and trains a tiny run through the console script.
set -euo pipefail
repo="$(cd "$(dirname "$0")/.." && pwd)"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
PY=${PYTHON:-python3}
"$PY" -m venv "$work/venv"
"$work/venv/bin/python" -m pip install -q --upgrade pip
"$work/venv/bin/python" -m pip wheel -q --no-deps -w "$work/dist" "$repo"
"$work/venv/bin/python" -m pip install -q "$work"/dist/daddpg_jax-*.whl
cd "$work"
export JAX_PLATFORMS=cpu
"$work/venv/bin/python" - <<'PY'
import jax, numpy as np
import mjx_envs
import daddpg_jax
assert "site-packages" in mjx_envs.__file__, mjx_envs.__file__
for task in mjx_envs.TASKS:
    env = mjx_envs.make(task, physics="c")
    s = env.step(env.reset(jax.random.PRNGKey(0)), np.zeros(8, np.float32))
    assert s.obs["observation"].shape == (2, env.obs_size), task
print("wheel smoke: env step ok for", ", ".join(mjx_envs.TASKS))
PY
"$work/venv/bin/daddpg-train" --task reach --num-envs 2 --epochs 1 --no-progress \
  --set n_cycles=1 --set n_batches=2 --set batch_size=32 --set hidden=16 \
  --set n_test_episodes=4 --out "$work/run"
test -f "$work/run/metrics.csv" && test -f "$work/run/config.json"
"$work/venv/bin/daddpg-export" --help >/dev/null
echo "wheel smoke: training ok"
