PYTHON ?= python3
.PHONY: install test test-mjx test-e2e test-slow test-ci test-all coverage train bench gpu-check \
	lint render wheel-smoke robot-only

install:
	$(PYTHON) -m pip install -e ".[dev]"

# Test tiers (markers in pyproject.toml; times in README.md, "Install and test").
# The default tier: every package module, no MJX compile, no subprocess runs; both cores.
test:
	$(PYTHON) -m pytest -q -n 2 --dist loadfile

# MJX programs (contract, parity, randomized models on MJX)
test-mjx:
	$(PYTHON) -m pytest -q -m "mjx and not slow"

# whole runs: subprocesses, console scripts, train-kill-resume, learning checks
test-e2e:
	$(PYTHON) -m pytest -q -m "e2e and not slow"

test-slow:
	$(PYTHON) -m pytest -q -m slow

# what CI runs: the default tier, then every other tier except slow
test-ci: test test-mjx test-e2e

test-all:
	$(PYTHON) -m pytest -q -m ""

# per-module coverage of the package by the default tier (one line per module; fails if a
# module is not exercised at all)
coverage:
	$(PYTHON) -m coverage erase
	$(PYTHON) -m coverage run -m pytest -q -p no:xdist
	$(PYTHON) -m coverage json -q -o coverage_modules.json
	$(PYTHON) tests/module_coverage.py coverage_modules.json

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

# the robot side alone: NumPy, h11 and MuJoCo in a fresh venv, the package with --no-deps
# (also run by the e2e tier: tests/test_robot_only_install.py)
robot-only:
	PYTHON=$(PYTHON) bash .ci/robot_only.sh
