PYTHON ?= python3
.PHONY: install test test-all train bench gpu-check lint render wheel-smoke

install:
	$(PYTHON) -m pip install -e ".[dev]"

test:
	$(PYTHON) -m pytest -q

test-all:
	$(PYTHON) -m pytest -q -m ""

train:
	$(PYTHON) experiments/run.py --task reach

bench:
	$(PYTHON) experiments/benchmark.py

# one short staged check of a GPU machine (<= 5 min), e.g.
#   make gpu-check ARGS="--wheels .whl --out runs/gpu_check"   or   ARGS="--smoke" on a CPU
gpu-check:
	PYTHON=$(PYTHON) bash experiments/gpu_check.sh $(ARGS)

render:
	MUJOCO_GL=egl $(PYTHON) experiments/render_scene.py --task reach --out docs/scene_reach.png

lint:
	$(PYTHON) -m ruff check daddpg_jax mjx_envs experiments tests

# the wheel, installed non-editable into a fresh venv, used from outside the repository
wheel-smoke:
	PYTHON=$(PYTHON) bash .ci/wheel_smoke.sh
