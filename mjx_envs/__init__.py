"""Pure-functional dual-UR3 environments on MuJoCo MJX and MuJoCo's C engine.

``mjx_envs.make(task, physics="auto", **overrides)`` builds a task; see ``docs/ENVIRONMENTS.md``.
"""

from __future__ import annotations

from mjx_envs.core import DualArmEnv, State, TaskConfig, replace_config
from mjx_envs.reach import Reach
from mjx_envs.push import Push
from mjx_envs.pickup import Pickup
from mjx_envs.pot import Pot

_REGISTRY = {"reach": Reach, "push": Push, "pickup": Pickup, "pot": Pot}
TASKS = ("reach", "push", "pickup", "pot")


def register(name: str, cls) -> None:
    _REGISTRY[name] = cls


def make(task: str, physics: str = "auto", **overrides) -> DualArmEnv:
    """Build a task's env. ``physics``: 'auto' (MJX on an accelerator, C on CPU), 'mjx' or 'c'.

    Keyword overrides replace fields of the task's ``default_config()``.
    """
    if task not in _REGISTRY:
        known = sorted(_REGISTRY)
        raise ValueError(f"unknown task {task!r}; available: {known}")
    if physics not in ("auto", "mjx", "c"):
        raise ValueError(f"unknown physics {physics!r}: choose 'auto', 'mjx' or 'c'")
    cls = _REGISTRY[task]
    cfg = replace_config(cls.default_config(), **overrides)
    return cls(cfg, physics=physics)


def default_config(task: str) -> TaskConfig:
    if task not in _REGISTRY:
        raise ValueError(f"unknown task {task!r}; available: {sorted(_REGISTRY)}")
    return _REGISTRY[task].default_config()


__all__ = ["make", "default_config", "register", "State", "TaskConfig", "DualArmEnv", "TASKS"]
