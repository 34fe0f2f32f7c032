"""The task registry: every task, built-in or added, declared by one `Task` record.

A task is one module (``mjx_envs/tasks/<name>.py`` for the built-in ones) that builds a `Task`
and calls `register` (public as ``mjx_envs.register``). Everything that lists or looks up tasks
reads it from here: the tables derived from the tasks (``TASKS``, ``TASK_SETTINGS``,
``OBJECTS``), a task's settings (`default_config`, `task_config`, `saved_config`,
`test_overrides`), the training presets (`daddpg_jax.algo.config`), the Gymnasium ids
(`mjx_envs.gym_env`), the scripted controllers and the commands' ``--task`` choices.
docs/TASKS.md, "Adding a task", walks through a new one.

A task that lives outside this package is found through its module: `import_task_module`
imports it (a training run records the module as ``task_module`` in its config.json, so
evaluation and export in another process find the task again).

Standard library only at import (no JAX, NumPy or MuJoCo; of this package only
`mjx_envs.schema`): the robot side and the command-line parsers read the registry without JAX.
A task module must keep to that too (the scripted controller imports JAX inside its body).
"""

from __future__ import annotations

import dataclasses
import importlib
from collections.abc import Callable
from typing import Any

from mjx_envs.schema import fields, replace_config

BUILTIN_MODULES = ("mjx_envs.tasks.reach", "mjx_envs.tasks.push", "mjx_envs.tasks.pickup",
                   "mjx_envs.tasks.pot")
"""The modules of the built-in tasks, in the order the task list shows them."""


@dataclasses.dataclass(frozen=True)
class Task:
    """Everything that is one task's.

    name: the task name (``mjx_envs.make(name)``, ``--task name``).
    config: its settings defaults, a `mjx_envs.settings.TaskConfig` (or subclass) instance.
    rules: its rule hooks, a subclass of `mjx_envs.rules.TaskRules`, built as
      ``rules(config, mj_model, object)`` by the JAX env and the NumPy simulator.
    object: (free joint, body, (left point site, right point site)) of its object, or None
      (an env without an object, as reach).
    scripted: its scripted controller ``(obs, max_delta) -> action [..., 8]`` (a pure JAX
      function of the observation dict), or None.
    cpu_preset / accelerator_preset: training preset values (`daddpg_jax.algo.config.preset`):
      on a CPU ``n_cycles``, ``n_epochs`` and any other TrainConfig field; on an accelerator
      ``epoch_env_steps`` and ``n_epochs``.
    env_preset: env overrides a new run trains with unless ``--env`` says otherwise (e.g.
      grasped starts).
    for_c_engine: whether ``daddpg-train --for-c-engine`` (MJX training for the C engine,
      `daddpg_jax.algo.config.FOR_C_ENGINE_ENV`) is measured for it (docs/MJX_VS_C.md);
      the flag refuses the other tasks.
    gym_id / dense_gym_id: its Gymnasium ids (sparse reward; dense reward); by default
      derived from the name (`gym_ids`: 'pot' -> DualUR3Pot-v0, DualUR3PotDense-v0); '' = none.
    module: the module that declares it (recorded by training runs as ``task_module``).
    """

    name: str
    config: Any
    rules: type
    object: tuple | None = None
    scripted: Callable | None = None
    cpu_preset: dict = dataclasses.field(default_factory=lambda: dict(n_cycles=50,
                                                                       n_epochs=100))
    accelerator_preset: dict = dataclasses.field(
        default_factory=lambda: dict(epoch_env_steps=1_000_000, n_epochs=40))
    env_preset: dict = dataclasses.field(default_factory=dict)
    for_c_engine: bool = False
    gym_id: str | None = None
    dense_gym_id: str | None = None
    module: str = ""

    def __post_init__(self):
        derived = gym_ids(self.name)
        for field, default in zip(("gym_id", "dense_gym_id"), derived):
            if getattr(self, field) is None:
                object.__setattr__(self, field, default)   # frozen: set once, here


_TASKS: dict[str, Task] = {}
_LISTENERS: list[Callable[[Task], None]] = []
_builtins_loaded = False


def _load_builtins() -> None:
    global _builtins_loaded
    if not _builtins_loaded:
        _builtins_loaded = True
        for mod in BUILTIN_MODULES:
            importlib.import_module(mod)


def register(task: Task) -> Task:
    """Adds `task` to the registry (the public way to add a task: ``mjx_envs.register``).
    A module may register its task again (a reload replaces it); a task of another module under
    a taken name is an error. Returns the task."""
    if not isinstance(task, Task):
        raise TypeError(f"register takes a mjx_envs.registry.Task, got {type(task).__name__}")
    old = _TASKS.get(task.name)
    if old is not None and old.module != task.module:
        raise ValueError(f"task {task.name!r} is already registered (by {old.module or '?'})")
    _TASKS[task.name] = task
    for listener in _LISTENERS:
        listener(task)
    return task


def on_register(listener: Callable[[Task], None]) -> None:
    """Calls ``listener(task)`` for every task registered from now on (e.g. Gymnasium ids)."""
    _LISTENERS.append(listener)


def task_names() -> tuple[str, ...]:
    """The registered tasks' names, built-in ones first."""
    _load_builtins()
    return tuple(_TASKS)


def tasks() -> tuple[Task, ...]:
    _load_builtins()
    return tuple(_TASKS.values())


def is_task(name: str) -> bool:
    _load_builtins()
    return name in _TASKS


def get(name: str) -> Task:
    """The task called `name`; ValueError naming the registered ones when there is none."""
    _load_builtins()
    if name not in _TASKS:
        raise ValueError(f"unknown task {name!r}; available: {sorted(_TASKS)} (a task defined "
                         "in another module: import it first, e.g. train with --task-module)")
    return _TASKS[name]


def import_task_module(module: str | None) -> None:
    """Imports `module` (a dotted module name), whose import registers one or more tasks;
    nothing for None or ''. ValueError when it cannot be imported."""
    if not module:
        return
    _load_builtins()
    try:
        importlib.import_module(module)
    except ImportError as e:
        raise ValueError(f"task module {module!r} cannot be imported ({e}); is its directory "
                         "on PYTHONPATH?") from None


def gym_ids(name: str) -> tuple[str, str]:
    """The default Gymnasium ids of task `name` (sparse reward, dense reward):
    'pick_up' -> ('DualUR3PickUp-v0', 'DualUR3PickUpDense-v0')."""
    return f"DualUR3{class_name(name)}-v0", f"DualUR3{class_name(name)}Dense-v0"


def __getattr__(name: str):
    """The tables derived from the tasks (read when asked for, so a task registered later is in
    them): ``TASKS`` (names, `task_names`), ``TASK_SETTINGS`` (name -> settings defaults) and
    ``OBJECTS`` (name -> (free joint, body, point sites), object tasks only)."""
    if name == "TASKS":
        return task_names()
    if name == "TASK_SETTINGS":
        return {t.name: t.config for t in tasks()}
    if name == "OBJECTS":
        return {t.name: t.object for t in tasks() if t.object is not None}
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def default_config(name: str):
    """The settings defaults of task `name` (a frozen `mjx_envs.settings.TaskConfig`)."""
    return get(name).config


def task_config(name: str, **overrides):
    """Task `name`'s settings with `overrides` applied (lists from JSON become tuples)."""
    return replace_config(default_config(name), **overrides)


def saved_config(name: str, saved=None):
    """Task `name`'s settings holding the values in `saved`: a dict (e.g. a policy export's env
    settings; keys that are not fields, such as ``dt``, are ignored; fields it lacks keep the
    task's values) or a whole config of the task's class (returned as is)."""
    base = default_config(name)
    if saved is None:
        return base
    if dataclasses.is_dataclass(saved) and not isinstance(saved, type):
        if not isinstance(saved, type(base)):
            raise TypeError(f"task {name!r} needs a {type(base).__name__}, got "
                            f"{type(saved).__name__}")
        return saved
    names = fields(base)
    return replace_config(base, **{k: v for k, v in dict(saved).items() if k in names})


def test_overrides(name: str) -> dict:
    """The env overrides that give the standard task for test episodes: every training-only
    field of task `name` off (`mjx_envs.settings.TaskConfig.training_only_off`); {} for a task
    that is not registered."""
    return get(name).config.training_only_off() if is_task(name) else {}


def make_rules(name: str, config, model):
    """The rules of task `name` bound to `config` and a compiled scene `model`."""
    task = get(name)
    return task.rules(config, model, task.object)


def class_name(name: str) -> str:
    """The env class name of task `name`: 'pick_up' -> 'PickUp'."""
    return "".join(p.capitalize() for p in name.split("_"))


def scripted_task_names() -> tuple[str, ...]:
    """The registered tasks that have a scripted controller."""
    return tuple(t.name for t in tasks() if t.scripted is not None)


def task_table() -> str:
    """The registered tasks as a Markdown table (docs/TASKS.md, "Tasks", is this table)."""
    rows = ["| task | module | scene | object | scripted controller | Gymnasium ids | CPU "
            "preset | env preset |", "|---|---|---|---|---|---|---|---|"]
    for t in tasks():
        def fmt(d):
            return ", ".join(f"{k}={v}" for k, v in d.items()) or "-"
        ids = " / ".join(i for i in (t.gym_id, t.dense_gym_id) if i) or "-"
        rows.append(f"| {t.name} | `{t.module}` | {t.config.scene} | "
                    f"{t.object[1] if t.object else '-'} | "
                    f"{'yes' if t.scripted is not None else '-'} | {ids} | {fmt(t.cpu_preset)} "
                    f"| {fmt(t.env_preset)} |")
    return "\n".join(rows)
