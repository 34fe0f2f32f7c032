"""Pure-functional dual-UR3 environments on MuJoCo MJX and MuJoCo's C engine.

``mjx_envs.make(task, physics="auto", **overrides)`` builds a task; see ``docs/ENVIRONMENTS.md``.

Imports are lazy (PEP 562): ``import mjx_envs.observation`` (or ``daddpg_jax.deploy.ur3``,
``mjx_envs.numpy_env``) does not import JAX, so the robot side can reuse the observation code
with NumPy only. ``make``, ``State``, ``TaskConfig``, ``DualArmEnv`` and the task classes load
the JAX environments on first use.
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
    return cls(cfg, physics=physics)


__all__ = ["make", "default_config", "register", "State", "TaskConfig", "DualArmEnv", "TASKS"]
