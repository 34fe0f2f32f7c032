"""Pure-functional dual-UR3 environments on MuJoCo MJX and MuJoCo's C engine.

``mjx_envs.make(task, physics="auto", **overrides)`` builds a task; see ``docs/ENVIRONMENTS.md``.

Imports are lazy (PEP 562): ``import mjx_envs.observation`` (or ``daddpg_jax.deploy.ur3``,
``mjx_envs.numpy_env``) does not import JAX, so the robot side can reuse the observation code
with NumPy only. ``make``, ``State``, ``TaskConfig``, ``DualArmEnv`` and the task classes load
the JAX environments on first use.

Gymnasium: when Gymnasium is installed, importing ``mjx_envs`` registers the adapter's ids
(``ENV_IDS``, ``DENSE_ENV_IDS``; entry point ``mjx_envs.gym_env:DualUR3GoalEnv``, loaded on the
first ``make``), so both Gymnasium conventions work, as for ``gymnasium_robotics``:

    gymnasium.make("mjx_envs:DualUR3Push-v0")      # imports mjx_envs, then makes the env
    gymnasium.register_envs(mjx_envs)                # after `import mjx_envs`
    gymnasium.make("DualUR3PushDense-v0")
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

from mjx_envs.settings import PHYSICS, TASKS, default_config  # noqa: F401  (JAX-free)

if TYPE_CHECKING:
    from mjx_envs.core import DualArmEnv

# task name -> env class, or (module, class name) until first use
_REGISTRY: dict = {
    "reach": ("mjx_envs.tasks.reach", "Reach"),
    "push": ("mjx_envs.tasks.push", "Push"),
    "pickup": ("mjx_envs.tasks.pickup", "Pickup"),
    "pot": ("mjx_envs.tasks.pot", "Pot"),
}

_LAZY = {
    "DualArmEnv": ("mjx_envs.core", "DualArmEnv"),
    "State": ("mjx_envs.core", "State"),
    "TaskConfig": ("mjx_envs.settings", "TaskConfig"),
    "replace_config": ("mjx_envs.settings", "replace_config"),
    "Reach": ("mjx_envs.tasks.reach", "Reach"),
    "Push": ("mjx_envs.tasks.push", "Push"),
    "Pickup": ("mjx_envs.tasks.pickup", "Pickup"),
    "Pot": ("mjx_envs.tasks.pot", "Pot"),
}


def __getattr__(name: str):
    if name in _LAZY:
        mod, attr = _LAZY[name]
        value = getattr(importlib.import_module(mod), attr)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'mjx_envs' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_LAZY))


def _task_class(task: str):
    if task not in _REGISTRY:
        raise ValueError(f"unknown task {task!r}; available: {sorted(_REGISTRY)}")
    cls = _REGISTRY[task]
    if isinstance(cls, tuple):
        cls = getattr(importlib.import_module(cls[0]), cls[1])
        _REGISTRY[task] = cls
    return cls


ENV_IDS = {"reach": "DualUR3Reach-v0", "push": "DualUR3Push-v0",
           "pickup": "DualUR3Pickup-v0", "pot": "DualUR3Pot-v0"}
"""Gymnasium ids of the tasks (sparse reward, the trainer's)"""

DENSE_ENV_IDS = {"reach": "DualUR3ReachDense-v0", "push": "DualUR3PushDense-v0",
                 "pickup": "DualUR3PickupDense-v0", "pot": "DualUR3PotDense-v0"}
"""Gymnasium ids of the dense-reward variants (``reward_type="dense"``, docs/TOOLS.md)"""

MAX_EPISODE_STEPS = 50
"""``max_episode_steps`` of every Gymnasium id (the tasks' ``episode_length``)"""


def register_gymnasium_envs() -> list[str]:
    """Registers ENV_IDS and DENSE_ENV_IDS with Gymnasium (idempotent; needs gymnasium).
    Returns the ids, sparse ones first."""
    import gymnasium

    ids = []
    for reward_type, table in (("sparse", ENV_IDS), ("dense", DENSE_ENV_IDS)):
        for task, env_id in table.items():
            if env_id not in gymnasium.registry:
                gymnasium.register(id=env_id, entry_point="mjx_envs.gym_env:DualUR3GoalEnv",
                                   kwargs={"task": task, "reward_type": reward_type},
                                   max_episode_steps=MAX_EPISODE_STEPS)
            ids.append(env_id)
    return ids


def _register_if_gymnasium() -> None:
    """Gymnasium 1.x loads no plugins: a package registers its ids when it is imported."""
    try:
        import gymnasium  # noqa: F401  (optional: the [gym] extra)
    except ImportError:
        return
    register_gymnasium_envs()


def register(name: str, cls) -> None:
    _REGISTRY[name] = cls


def make(task: str, physics: str = "auto", **overrides) -> DualArmEnv:
    """Build a task's env. ``physics``: 'auto' (MJX on an accelerator, C on CPU), 'mjx' or 'c'.

    Keyword overrides replace fields of the task's ``default_config()``.
    """
    if task not in _REGISTRY:
        known = sorted(_REGISTRY)
        raise ValueError(f"unknown task {task!r}; available: {known}")
    if physics not in PHYSICS:
        raise ValueError(f"unknown physics {physics!r}: choose 'auto', 'mjx' or 'c'")
    from mjx_envs.settings import replace_config

    cls = _task_class(task)
    cfg = replace_config(cls.default_config(), **overrides)
    return importlib.import_module("mjx_envs.wrappers").wrap(cls(cfg, physics=physics))


__all__ = ["make", "default_config", "register", "State", "TaskConfig", "DualArmEnv", "TASKS",
           "ENV_IDS", "DENSE_ENV_IDS", "register_gymnasium_envs"]

_register_if_gymnasium()
