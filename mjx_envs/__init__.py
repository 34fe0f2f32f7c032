"""Pure-functional dual-UR3 environments on MuJoCo MJX and MuJoCo's C engine.

``mjx_envs.make(task, physics="auto", **overrides)`` builds a task; see ``docs/ENVIRONMENTS.md``.

Imports are lazy (PEP 562): ``import mjx_envs.observation`` (or ``daddpg_jax.deploy.ur3``,
``mjx_envs.numpy_env``) does not import JAX, so the robot side can reuse the observation code
with NumPy only. ``make``, ``State``, ``TaskConfig``, ``DualArmEnv`` and the task classes load
the JAX environments on first use. Tasks: `mjx_envs.registry` (``register`` adds one).

Gymnasium: when Gymnasium is installed, importing ``mjx_envs`` registers the adapter's ids
(``ENV_IDS``, ``DENSE_ENV_IDS``, from the task registry; entry point
``mjx_envs.gym_env:DualUR3GoalEnv``, loaded on the first ``make``), so both Gymnasium
conventions work, as for ``gymnasium_robotics``:

    gymnasium.make("mjx_envs:DualUR3Push-v0")      # imports mjx_envs, then makes the env
    gymnasium.register_envs(mjx_envs)                # after `import mjx_envs`
    gymnasium.make("DualUR3PushDense-v0")
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

from mjx_envs import registry
from mjx_envs.registry import (
    Task,  # noqa: F401  (public: the record `register` takes)
    default_config,  # noqa: F401  (public)
)
from mjx_envs.schema import replace_config
from mjx_envs.settings import PHYSICS

if TYPE_CHECKING:
    from mjx_envs.core import DualArmEnv

_LAZY = {
    "DualArmEnv": ("mjx_envs.core", "DualArmEnv"),
    "State": ("mjx_envs.core", "State"),
    "TaskConfig": ("mjx_envs.settings", "TaskConfig"),
}

MAX_EPISODE_STEPS = 50
"""``max_episode_steps`` of every Gymnasium id (the tasks' ``episode_length``)"""


def __getattr__(name: str):
    """The lazy names (`_LAZY`), the tables derived from the registry (``TASKS``, ``ENV_IDS``:
    task -> Gymnasium id, ``DENSE_ENV_IDS``: task -> id of the dense-reward variant,
    ``reward_type="dense"``, docs/TOOLS.md) and each task's env class by its capitalized name
    (``mjx_envs.Push``)."""
    if name in _LAZY:
        mod, attr = _LAZY[name]
        value = getattr(importlib.import_module(mod), attr)
        globals()[name] = value
        return value
    if name == "TASKS":
        return registry.task_names()
    if name == "ENV_IDS":
        return {t.name: t.gym_id for t in registry.tasks() if t.gym_id}
    if name == "DENSE_ENV_IDS":
        return {t.name: t.dense_gym_id for t in registry.tasks() if t.dense_gym_id}
    by_class = {registry.class_name(n): n for n in registry.task_names()}
    if name in by_class:
        return env_class(by_class[name])
    raise AttributeError(f"module 'mjx_envs' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_LAZY) | {"TASKS", "ENV_IDS", "DENSE_ENV_IDS"})


_ENV_CLASSES: dict[str, type] = {}


def env_class(task: str) -> type:
    """The JAX env class of `task` (imports JAX): `mjx_envs.core.DualArmEnv`, or the object-task
    base when the task has an object, with ``task_name`` set."""
    if task not in _ENV_CLASSES:
        t = registry.get(task)
        if t.object is None:
            from mjx_envs.core import DualArmEnv as base  # lazy: `import mjx_envs` is JAX-free
        else:
            from mjx_envs.tasks.object_task import ObjectPoseTask as base  # lazy: as above
        _ENV_CLASSES[task] = type(registry.class_name(task), (base,),
                                  {"task_name": task, "__module__": t.module or __name__})
    return _ENV_CLASSES[task]


def _gym_ids(task) -> list:
    return [(t, reward_type) for t, reward_type in ((task.gym_id, "sparse"),
                                                    (task.dense_gym_id, "dense")) if t]


def _register_gym_task(task) -> list[str]:
    import gymnasium  # lazy: the [gym] extra; its callers checked it is installed

    for env_id, reward_type in _gym_ids(task):
        if env_id not in gymnasium.registry:
            gymnasium.register(id=env_id, entry_point="mjx_envs.gym_env:DualUR3GoalEnv",
                               kwargs={"task": task.name, "reward_type": reward_type},
                               max_episode_steps=MAX_EPISODE_STEPS)
    return [env_id for env_id, _ in _gym_ids(task)]


def register_gymnasium_envs() -> list[str]:
    """Registers every task's Gymnasium ids (``ENV_IDS``, ``DENSE_ENV_IDS``) with Gymnasium
    (idempotent; needs gymnasium). Returns the ids, sparse ones first."""
    tasks = registry.tasks()
    ids = {task.name: _register_gym_task(task) for task in tasks}
    return [ids[t.name][i] for i in (0, 1) for t in tasks if len(ids[t.name]) > i]


def _register_if_gymnasium() -> None:
    """Gymnasium 1.x loads no plugins: a package registers its ids when it is imported (and a
    task registered later registers its own)."""
    try:
        import gymnasium  # noqa: F401  (optional: the [gym] extra)
    except ImportError:
        return
    register_gymnasium_envs()
    registry.on_register(_register_gym_task)


def register(task: Task) -> Task:
    """Adds a task (a `mjx_envs.registry.Task`: its settings, rules, scripted controller,
    presets and Gymnasium ids) to every place that lists tasks; see docs/TASKS.md, "Adding a
    task"."""
    return registry.register(task)


def make(task: str, physics: str = "auto", **overrides) -> DualArmEnv:
    """Build a task's env. ``physics``: 'auto' (MJX on an accelerator, C on CPU), 'mjx' or 'c'.

    Keyword overrides replace fields of the task's ``default_config()``.
    """
    registry.get(task)   # ValueError naming the registered tasks
    if physics not in PHYSICS:
        raise ValueError(f"unknown physics {physics!r}: choose 'auto', 'mjx' or 'c'")
    cls = env_class(task)
    cfg = replace_config(cls.default_config(), **overrides)
    return importlib.import_module("mjx_envs.wrappers").wrap(cls(cfg, physics=physics))


__all__ = ["make", "default_config", "register", "Task", "State", "TaskConfig", "DualArmEnv",
           "TASKS", "ENV_IDS", "DENSE_ENV_IDS", "register_gymnasium_envs"]

_register_if_gymnasium()
