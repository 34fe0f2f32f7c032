PYTHON ?= python3
.PHONY: install test test-all train bench lint render

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
	$(PYTHON) -m compileall -q daddpg_jax mjx_envs experiments tests
