PYTHON ?= python3
.PHONY: install test test-all train bench lint render wheel-smoke

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

render:
	MUJOCO_GL=egl $(PYTHON) experiments/render_scene.py --task reach --out docs/scene_reach.png

lint:
	$(PYTHON) -m ruff check daddpg_jax mjx_envs experiments tests

# the wheel, installed non-editable into a fresh venv, used from outside the repository
wheel-smoke:
	PYTHON=$(PYTHON) bash .ci/wheel_smoke.sh
