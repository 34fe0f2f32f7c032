"""The task registry (mjx_envs/registry.py): every task declared in one module, the tables
derived from it, and a task added from outside the package (tests/tasks_extra/slide.py) that
trains, evaluates and exports through the console scripts.

The slide task is only ever imported in subprocesses, so the registry of this test process
keeps the built-in tasks alone.
"""

from __future__ import annotations

import csv
import json
import os
import re
import subprocess
import sys

import numpy as np
import pytest

import mjx_envs
from daddpg_jax.algo import config as config_lib
from daddpg_jax.deploy import NumpyPolicy
from mjx_envs import registry
from mjx_envs.numpy_env import NumpyDualArmEnv

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SLIDE_MODULE = "tests.tasks_extra.slide"
BUILTIN = ("reach", "push", "pickup", "pot")


def _python(code_or_args, cwd=None, timeout=300) -> subprocess.CompletedProcess:
    """A fresh interpreter with the repository on PYTHONPATH (so that the slide task's module
    is importable) and nothing else."""
    args = ["-c", code_or_args] if isinstance(code_or_args, str) else list(code_or_args)
    env = {**os.environ, "PYTHONPATH": ROOT, "JAX_PLATFORMS": "cpu"}
    return subprocess.run([sys.executable, *args], cwd=cwd or ROOT, env=env, timeout=timeout,
                          capture_output=True, text=True)


def test_builtin_tasks_come_from_their_modules():
    """~0.1 s. The tables are the registered tasks' records, in the built-in order."""
    assert registry.TASKS == BUILTIN == registry.task_names()
    for name in BUILTIN:
        task = registry.get(name)
        assert task.module == f"mjx_envs.tasks.{name}"
        assert registry.default_config(name) is task.config is registry.TASK_SETTINGS[name]
        assert mjx_envs.ENV_IDS[name] == task.gym_id
        assert mjx_envs.DENSE_ENV_IDS[name] == task.dense_gym_id
        assert config_lib.task_presets(name)["cpu"] == task.cpu_preset
        assert config_lib.preset_env(name) == task.env_preset
    assert set(registry.OBJECTS) == {"push", "pickup", "pot"}
    assert registry.scripted_task_names() == ("push", "pickup", "pot")
    assert config_lib.preset("pickup", device="cpu")["n_step"] == 3
    assert config_lib.preset_env("pot") == {"grasp_start_fraction": 0.5}


def test_gym_ids_default_from_the_task_name():
    """~0.1 s. A task that names no Gymnasium ids gets DualUR3<Name>-v0 and
    DualUR3<Name>Dense-v0 (the built-in ids, unchanged); '' means none; given ids stay."""
    assert mjx_envs.ENV_IDS == {"reach": "DualUR3Reach-v0", "push": "DualUR3Push-v0",
                                "pickup": "DualUR3Pickup-v0", "pot": "DualUR3Pot-v0"}
    assert mjx_envs.DENSE_ENV_IDS == {t: i.replace("-v0", "Dense-v0")
                                      for t, i in mjx_envs.ENV_IDS.items()}
    base = registry.get("reach")
    task = registry.Task(name="lift_bar", config=base.config, rules=base.rules)  # unregistered
    assert (task.gym_id, task.dense_gym_id) == ("DualUR3LiftBar-v0", "DualUR3LiftBarDense-v0")
    task = registry.Task(name="lift_bar", config=base.config, rules=base.rules, gym_id="Mine-v1",
                         dense_gym_id="")
    assert (task.gym_id, task.dense_gym_id) == ("Mine-v1", "")


def test_unknown_task_is_one_clear_error():
    """~0.1 s."""
    with pytest.raises(ValueError, match="unknown task 'nope'; available"):
        mjx_envs.make("nope")
    with pytest.raises(config_lib.ConfigError, match="unknown task 'nope'"):
        config_lib.TrainConfig(task="nope")
    with pytest.raises(config_lib.ConfigError, match="cannot be imported"):
        config_lib.TrainConfig(task="reach", task_module="no_such_module_here")
    with pytest.raises(TypeError, match="registry.Task"):
        mjx_envs.register("slide")


def test_a_task_name_appears_in_at_most_two_other_package_modules():
    """~0.2 s. One definition per task: its module; besides it, at most two Python modules of
    the packages spell its name (e.g. a default)."""
    for name in BUILTIN:
        pattern = re.compile(rf"[\"']{name}[\"']")
        files = []
        for pkg in ("daddpg_jax", "mjx_envs"):
            for d, _, names in os.walk(os.path.join(ROOT, pkg)):
                for n in names:
                    path = os.path.join(d, n)
                    if n.endswith(".py") and pattern.search(open(path).read()):
                        files.append(os.path.relpath(path, ROOT))
        own = os.path.join("mjx_envs", "tasks", f"{name}.py")
        assert own in files, name
        assert len(files) - 1 <= 2, (name, files)


def test_a_task_added_in_one_file_is_everywhere():
    """~5 s (one fresh interpreter, no JAX). Importing tests/tasks_extra/slide.py registers
    the task: settings tables, presets, Gymnasium id, scripted controller; its own goal rule
    acts in the NumPy simulator; a config naming only the module finds the task; reading all
    of it imports no JAX."""
    code = f"""
import json, sys
import gymnasium, numpy as np
from daddpg_jax.algo.config import TrainConfig, preset
cfg = TrainConfig(task="slide", task_module="{SLIDE_MODULE}")   # imports the module
from mjx_envs import registry, settings
from mjx_envs.numpy_env import NumpyDualArmEnv
env = NumpyDualArmEnv(task="slide")
goals = np.stack([env.reset(np.random.default_rng(s)).desired_goal for s in range(20)])
g = gymnasium.make("DualUR3Slide-v0")
obs, _ = g.reset(seed=0)
try:
    registry.register(registry.Task(name="push", config=None, rules=object, module="elsewhere"))
    clash = None
except ValueError as e:
    clash = str(e)
print(json.dumps(dict(
    tasks=list(registry.TASKS), scene=registry.TASK_SETTINGS["slide"].scene,
    object=registry.OBJECTS["slide"][0], cpu=preset("slide", device="cpu")["n_cycles"],
    scripted=list(registry.scripted_task_names()), centre=goals.mean(axis=1).tolist(),
    gym_goal=obs["desired_goal"].reshape(2, 3).mean(axis=0).tolist(), clash=clash,
    jax="jax" in sys.modules)))
"""
    out = _python(code, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    r = json.loads(out.stdout.strip().splitlines()[-1])
    assert r["tasks"] == [*BUILTIN, "slide"]
    assert (r["scene"], r["object"], r["cpu"]) == ("scene_push.xml", "bar", 10)
    assert r["scripted"] == ["push", "pickup", "pot", "slide"]
    centre = np.asarray(r["centre"])             # the bar centre of each goal: slid along +x
    assert np.all(centre[:, 0] >= 0.25 + 0.04 - 1e-6) and np.all(centre[:, 0] <= 0.25 + 0.08)
    np.testing.assert_allclose(centre[:, 1], 0.0, atol=1e-6)
    assert np.ptp(centre[:, 0]) > 0.01           # drawn, not fixed
    assert 0.25 + 0.04 - 1e-6 <= r["gym_goal"][0] <= 0.25 + 0.08   # the Gymnasium id: slide too
    assert "already registered" in r["clash"]
    assert r["jax"] is False


@pytest.mark.e2e
def test_added_task_trains_evaluates_and_exports(tmp_path):
    """~3 min on the loaded 2-core CPU (three fresh interpreters: a one-epoch training of 2 envs
    on the C engine, 2 cycles of 2 updates, 4 test episodes; evaluation; export). The task is
    named on the command line by its module alone; evaluation and export in fresh processes
    are given only the run directory and find the task through config.json's task_module.
    The exported policy then acts through the NumPy policy."""
    run = tmp_path / "run"
    out = _python(["-m", "daddpg_jax.cli.train", "--task", "slide", "--task-module",
                   SLIDE_MODULE, "--epochs", "1", "--num-envs", "2", "--physics", "c",
                   "--set", "n_cycles=2", "--set", "n_batches=2", "--set", "n_test_episodes=4",
                   "--out", str(run)], cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-3000:]
    recorded = json.loads((run / "config.json").read_text())["config"]
    assert (recorded["task"], recorded["task_module"]) == ("slide", SLIDE_MODULE)
    with open(run / "metrics.csv") as f:
        row = list(csv.DictReader(f))[-1]

    out = _python(["-m", "daddpg_jax.cli.evaluate", str(run), "--episodes", "4", "--json"],
                  cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-3000:]
    ev = json.loads(out.stdout[out.stdout.index("{"):])
    assert ev["task"] == "slide" and ev["episodes"] == 4
    # the run's eval seed and episode count: the same episodes as its test episodes
    assert ev["success_rate"] == pytest.approx(float(row["test_success_rate"]), abs=1e-9)
    assert ev["final_distance_mean"]["left"] == pytest.approx(
        float(row["test_final_distance_left"]), rel=1e-6)

    policy_file = tmp_path / "slide.npz"
    out = _python(["-m", "daddpg_jax.cli.export", str(run), "--out", str(policy_file)],
                  cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-3000:]
    assert "task slide" in out.stdout

    pol = NumpyPolicy.load(policy_file)   # NumPy only; the slide task is not imported here
    assert pol.task == "slide"
    env = NumpyDualArmEnv(task="push")    # the same scene, observation and goal layout
    step = env.reset(np.random.default_rng(0))
    a = pol.act(step.observation, step.desired_goal)
    assert a.shape == (8,) and a.dtype == np.float32 and np.all(np.abs(a) <= 1.0)
    np.testing.assert_array_equal(a, pol.act(step.observation, step.desired_goal))
    assert "slide" not in registry.task_names()


def test_docs_task_table_is_the_registry():
    """~0.1 s. docs/TASKS.md's task table is `registry.task_table()`."""
    text = open(os.path.join(ROOT, "docs", "TASKS.md")).read()
    table = text.split("<!-- task table: begin -->\n")[1].split("\n<!-- task table: end -->")[0]
    assert table == registry.task_table()
