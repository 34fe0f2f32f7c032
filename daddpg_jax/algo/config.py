"""Training configuration: one frozen dataclass whose fields are declared with the project's
field schema (`mjx_envs.schema.spec`: default, docstring, valid range), plus the per-task presets.

`TrainConfig` holds plain Python values only, so it is hashable, can be closed over by jitted
functions and written to `config.json`. Validation, ``--help`` and config files all read the
schema. Standard library only at import (the NumPy-only robot side imports this package).
"""

from __future__ import annotations

import dataclasses
import importlib.util
import math
import os

from daddpg_jax.variants import ALGOS
from daddpg_jax.variants import get as get_variant
from mjx_envs import registry
from mjx_envs.registry import default_config
from mjx_envs.schema import ConfigError, finalize, from_dict, spec, to_dict
from mjx_envs.settings import DEFAULT_TASK, ENGINES, PHYSICS  # noqa: F401  (PHYSICS re-exported)

HER_MODES = ("future", "final", "none")
OTHER_ACTIONS = ("buffer", "policy")


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """Every training setting; see each field's docstring (``run.py --help`` prints them)."""

    task: str = spec(
        DEFAULT_TASK,
        "task name passed to `mjx_envs.make`: a registered task (mjx_envs.registry; "
        "`--help` lists them)",
        nonempty=True)
    task_module: str = spec(
        "",
        "module that registers the task when it is not built in (a dotted name importable "
        "from PYTHONPATH, e.g. 'my_tasks.slide'); imported before the task is looked up, so "
        "that every command given the run's config.json finds the task; '' = built in")
    algo: str = spec(
        "daddpg",
        "'daddpg': actors see both arms, centralized critics; 'maddpg': actors see their own "
        "arm, critics see both; 'ddpg': independent arms (actor and critic see their own arm "
        "only); 'single': one agent with an 8-d action, reward = sum over arms",
        choices=ALGOS)
    her: str = spec(
        "future",
        "goal relabelling: 'future' (a strictly later achieved goal of the same episode), "
        "'final' (the episode's last achieved goal) or 'none'",
        choices=HER_MODES)
    replay_k: int = spec(
        4,
        "HER ratio k: a sampled transition is relabelled with probability 1 - 1/(1+k)",
        low=0)
    num_envs: int = spec(
        2,
        "environments stepped in parallel; each cycle collects one episode per env",
        low=1)
    n_epochs: int = spec(
        50,
        "number of epochs (an epoch is `n_cycles` cycles followed by an evaluation)",
        low=1)
    n_cycles: int = spec(
        50,
        "cycles per epoch (a cycle = one rollout of every env + `n_batches` updates)",
        low=1)
    n_batches: int = spec(
        40,
        "gradient updates of both agents per cycle",
        low=1)
    batch_size: int = spec(
        256,
        "transitions per gradient update",
        low=1)
    n_step: int = spec(
        1,
        "n-step returns: each sampled transition's reward is the discounted sum of up to "
        "n_step rewards of its episode under its (relabelled) goal, truncated at the episode "
        "end, bootstrapped from the state reached (1 = one-step TD, the HER baselines')",
        low=1)
    buffer_size: int = spec(
        1_000_000,
        "replay capacity in transitions (stored as buffer_size // T whole episodes)",
        low=1)
    gamma: float = spec(
        0.98,
        "discount factor",
        low=0.0, high=1.0, high_open=True)
    polyak: float = spec(
        0.95,
        "target update: target <- polyak * target + (1 - polyak) * online (once per cycle)",
        low=0.0, high=1.0)
    lr_actor: float = spec(
        1e-3,
        "Adam learning rate of the actors",
        low=0.0, low_open=True)
    lr_critic: float = spec(
        1e-3,
        "Adam learning rate of the critics",
        low=0.0, low_open=True)
    noise_eps: float = spec(
        0.2,
        "std of the Gaussian exploration noise added to actions in [-1, 1]",
        low=0.0)
    random_eps: float = spec(
        0.3,
        "probability that an arm takes a uniformly random action for a step",
        low=0.0, high=1.0)
    action_l2: float = spec(
        1.0,
        "weight of the L2 penalty on the actors' pre-scaled actions",
        low=0.0)
    clip_obs: float = spec(
        200.0,
        "raw observations and goals are clipped to +-clip_obs before normalization",
        low=0.0, low_open=True)
    norm_clip: float = spec(
        5.0,
        "normalized inputs are clipped to +-norm_clip",
        low=0.0, low_open=True)
    norm_eps: float = spec(
        0.01,
        "lower bound of the normalizer's std",
        low=0.0, low_open=True)
    hidden: tuple = spec(
        (256, 256, 256),
        "hidden layer widths of actors and critics (ReLU)",
        low=1, nonempty=True)
    clip_target: bool = spec(
        True,
        "clip TD targets to [r_min/(1-gamma), r_max/(1-gamma)] from `env.reward_range`")
    other_action: str = spec(
        "buffer",
        "in arm i's actor loss the other arm's action comes from the replay 'buffer', or from "
        "the current 'policy' under stop_gradient; either way arm i's actor gets gradient "
        "only from its own parameters",
        choices=OTHER_ACTIONS)
    n_test_episodes: int = spec(
        100,
        "deterministic evaluation episodes per epoch (vectorized, fixed seeds)",
        low=1)
    seed: int = spec(
        0,
        "seed of the training PRNG key")
    eval_seed: int = spec(
        12345,
        "seed of the evaluation episodes (the same episodes every epoch)")
    physics: str = spec(
        "auto",
        "physics backend passed to `mjx_envs.make` ('auto', 'mjx' or 'c')",
        choices=PHYSICS)
    cross_check: str = spec(
        "",
        "the other physics engine ('c' or 'mjx'; '' = off) on which every evaluation also "
        "plays the best checkpoint so far over the same test episodes (metrics.csv "
        "test_success_best and cross_success_best; daddpg-train --cross-check, "
        "docs/MJX_VS_C.md)",
        choices=("", *ENGINES))
    save_buffer: bool = spec(
        False,
        "store the replay buffer in checkpoints (needed for a bit-exact resume; large)")
    keep_checkpoints: int = spec(
        3,
        "number of most recent checkpoints kept",
        low=1)
    num_devices: int = spec(
        0,
        "devices to spread envs, replay and the update batch over (0 = all devices, those of "
        "every process of a multi-process job, where 0 is required; 1 = the single-device code "
        "path). num_envs and batch_size must be multiples of it",
        low=0)
    n_demos: int = spec(
        0,
        "scripted demonstration episodes (the task's controller, `scripted_policy` in "
        "mjx_envs/tasks/<task>.py) rolled out once at init and kept in a fixed demo buffer "
        "beside the replay (0 = none: the paper's setting). Not part of the paper: with "
        "n_demos > 0 every update adds `demo_batch` HER-relabelled demo transitions to the "
        "batch of critics and actors and a behaviour-cloning term on them (demonstrations as "
        "in Nair et al. 2018). Demo env steps are not counted in env_steps",
        low=0)
    demo_batch: int = spec(
        128,
        "demo transitions added to each update's batch (with n_demos > 0)",
        low=1)
    bc_weight: float = spec(
        10.0,
        "weight of the behaviour-cloning term: mean over demo transitions of ||mu_i(o, g) - "
        "a_demo,i||^2 (arm i's slot of the demo action), added to each actor's loss",
        low=0.0)
    q_filter: bool = spec(
        True,
        "apply the behaviour-cloning term only on demo transitions where agent i's critic "
        "rates the demo action above the actor's own (Q filter)")

    def __post_init__(self):
        try:
            registry.import_task_module(self.task_module)
            registry.get(self.task)
        except ValueError as e:
            raise ConfigError(f"task: {e}") from None
        finalize(self)

    @property
    def future_p(self) -> float:
        """probability that a sampled transition gets a relabelled goal"""
        return 0.0 if self.her == "none" else 1.0 - 1.0 / (1.0 + self.replay_k)

    @property
    def num_agents(self) -> int:
        """size of the stacked agent axis (the variant's number of agents)"""
        return get_variant(self.algo).num_agents

    def replace(self, **kw) -> TrainConfig:
        return dataclasses.replace(self, **kw)

    def to_dict(self) -> dict:
        return to_dict(self)

    @classmethod
    def from_dict(cls, d: dict) -> TrainConfig:
        """From a config.json dict (unknown keys ignored: files from later versions load)."""
        return from_dict(cls, d)


# HER baselines reference point: 2 rollouts per worker, 40 batches of 256 per cycle, T = 50,
# i.e. 40 * 256 / (2 * 50) = 102.4 gradient samples per stored transition.
BASE_NUM_ENVS = 2
BASE_BATCH = 256
BASE_N_BATCHES = 40
REPLAY_RATIO = BASE_N_BATCHES * BASE_BATCH / (BASE_NUM_ENVS * 50)
MAX_BATCH = 8192
MIN_BUFFER_CYCLES = 20
# CPU, many envs: at most CPU_MAX_UPDATES updates of at most CPU_MAX_BATCH per cycle, and an
# epoch of about CPU_EPOCH_ENV_STEPS env steps up to the task's n_cycles; why these values:
# docs/TRAINING.md, "Defaults and presets".
CPU_MAX_BATCH = 1024
CPU_MAX_UPDATES = 100
CPU_EPOCH_ENV_STEPS = 300_000
ACCELERATOR_NUM_ENVS = 4096
DEVICES = ("cpu", "gpu", "tpu")


def task_presets(task: str) -> dict:
    """The task's preset values (its module's `mjx_envs.registry.Task`): ``cpu`` (n_cycles,
    n_epochs, other TrainConfig fields), ``accelerator`` (epoch_env_steps, n_epochs) and ``env``
    (env overrides a new run trains with unless --env says otherwise; test episodes always use
    the standard task, mjx_envs.registry.test_overrides). ConfigError for an unknown task."""
    try:
        t = registry.get(task)
    except ValueError as e:
        raise ConfigError(str(e)) from None
    return dict(cpu=dict(t.cpu_preset), accelerator=dict(t.accelerator_preset),
                env=dict(t.env_preset))


ROBUST_ENV = dict(obs_noise=0.015, obs_dropout=0.1, obs_bias=0.005, latency=1,
                  base_offset=0.005, base_yaw=2.0, finger_force=0.2, action_scale=0.1,
                  object_mass=0.3, object_size=0.002, object_friction=0.3, table_height=0.005)
"""Bounds of the `--robust` training preset (each episode draws its values up to them;
mjx_envs/perturb.py, mjx_envs/randomize.py); the object fields apply only to tasks that have an
object. Test episodes stay nominal (settings.TRAINING_ONLY_FIELDS). Why these values:
docs/TRAINING.md, "Task presets"."""

ROBUST_OBS = dict(action_history=1)
"""What the `--robust` preset's policy observes besides the task's observation: each arm's last
action (mjx_envs/observation.py), so that the action latency holds back is not hidden from it.
Part of the policy's input, so test episodes and exports keep it (docs/TRAINING.md, "Task
presets")."""


def robust_env(task: str) -> dict:
    """The `--robust` training preset's env overrides for `task`: the ROBUST_ENV bounds of the
    fields the task has, and ROBUST_OBS."""
    task_presets(task)   # ConfigError for an unknown task
    fields = default_config(task)
    return {k: v for k, v in {**ROBUST_ENV, **ROBUST_OBS}.items() if hasattr(fields, k)}


FOR_C_ENGINE_ENV = dict(physics_version=9, object_friction=0.3, object_mass=0.3,
                        finger_force=0.3, grasp_timeconst=0.3)
"""The `--for-c-engine` recipe: MJX training of a policy that is to run on the C engine (the
robot side's simulator): physics version 9's scenes, and the grasp's physics (object friction
and mass, finger force, the finger-object contacts' time constant) drawn per training episode
up to these bounds; test episodes stay nominal. Measured for the tasks that say so
(`mjx_envs.registry.Task.for_c_engine`): docs/MJX_VS_C.md, "One recipe for pick up and pot"."""


def for_c_engine_tasks() -> tuple:
    """The registered tasks whose MJX -> C agreement under FOR_C_ENGINE_ENV is measured."""
    return tuple(t for t in registry.TASKS if registry.get(t).for_c_engine)


def for_c_engine_env(task: str) -> dict:
    """The `--for-c-engine` env overrides of `task` (FOR_C_ENGINE_ENV); ConfigError for a task
    whose module does not mark it measured (`for_c_engine_tasks`)."""
    task_presets(task)   # ConfigError for an unknown task
    if not registry.get(task).for_c_engine:
        raise ConfigError(f"--for-c-engine: measured for {' and '.join(for_c_engine_tasks())} "
                          f"only, not {task!r} (docs/MJX_VS_C.md); train {task} with the task's "
                          "preset, or set single fields with --env")
    return dict(FOR_C_ENGINE_ENV)


def preset_env(task: str, robust: bool = False) -> dict:
    """The env overrides of `task`'s training preset (`task_presets`' ``env``; {} for most
    tasks), plus `robust_env(task)` when `robust`."""
    return {**task_presets(task)["env"], **(robust_env(task) if robust else {})}


def current_device() -> str:
    """The platform JAX runs on ('cpu', 'gpu' or 'tpu'; imports JAX)."""
    import jax  # lazy: this module is read without JAX (the robot side, --help)

    backend = jax.default_backend()
    return backend if backend in DEVICES else "gpu"


_ACCELERATOR_PLUGINS = {"gpu": ("jax_cuda12_plugin", "jax_cuda13_plugin", "jax_rocm60_plugin",
                                "jax_rocm7_plugin"),
                        "tpu": ("libtpu",)}
"""JAX's accelerator plugins by device (their presence, not an import, decides guess_device)"""


def guess_device() -> str:
    """The platform JAX would run on, guessed without importing JAX (for --help and argument
    errors, which stay fast): the first entry of JAX_PLATFORMS if set, 'gpu' / 'tpu' when one
    of JAX's accelerator plugins is installed, else 'cpu'. A run asks JAX (`current_device`)."""
    first = os.environ.get("JAX_PLATFORMS", "").split(",")[0].strip().lower()
    if first:
        return first if first in DEVICES else "gpu"
    for device, mods in _ACCELERATOR_PLUGINS.items():
        if any(importlib.util.find_spec(m) is not None for m in mods):
            return device
    return "cpu"


def replay_ratio(n_batches: int, batch_size: int, num_envs: int, episode_length: int = 50) -> float:
    """Gradient samples per stored transition: n_batches * batch_size / (num_envs * T)."""
    return n_batches * batch_size / (num_envs * episode_length)


def preset(task: str, num_envs: int | None = None, episode_length: int = 50,
           ratio: float = REPLAY_RATIO, max_batch: int = MAX_BATCH,
           device: str | None = None) -> dict:
    """Per-task overrides for `TrainConfig` at a given number of parallel envs and device.

    The replay ratio (gradient samples per stored transition)

        ratio = n_batches * batch_size / (num_envs * T)

    is held near the HER baselines' value (40 * 256 / (2 * 50) = 102.4) as num_envs grows:
    batch_size grows first, batch_size = min(max_batch, 256 * num_envs / 2) (rounded to a power
    of two), then n_batches = ceil(ratio * num_envs * T / batch_size). At num_envs = 2 this gives
    exactly the baselines' 40 batches of 256. The buffer keeps 1e6 transitions unless that holds
    fewer than 20 cycles of data, in which case it holds 20 cycles.

    device: 'cpu', 'gpu' or 'tpu'; None = the device JAX runs on (`current_device`).
    On a CPU, num_envs=None picks 2 (the HER baselines' rollouts per worker; right for 2 cores);
    with many envs the batch is at most CPU_MAX_BATCH and the updates per cycle at most
    CPU_MAX_UPDATES (the replay ratio then falls: the rollouts and not the updates set the pace),
    and n_cycles = round(CPU_EPOCH_ENV_STEPS / (num_envs * T)) (1 to the task's n_cycles).
    On an accelerator: physics "mjx", num_envs=None picks ACCELERATOR_NUM_ENVS (4096), the same
    batch/updates rule, and n_cycles = round(epoch_env_steps / (num_envs * T)) (at least 1) so
    that an epoch holds about the same number of env steps at any num_envs (reach 4e5, contact
    tasks 1e6); n_epochs is the task's budget (`task_presets`).
    Returns a dict to pass as `TrainConfig(**preset(...))` or `cfg.replace(**preset(...))`.
    """
    presets = task_presets(task)
    device = current_device() if device is None else device
    if device not in DEVICES:
        raise ConfigError(f"device must be one of {DEVICES}, got {device!r}")
    accel = device != "cpu"
    if num_envs is None:
        num_envs = ACCELERATOR_NUM_ENVS if accel else BASE_NUM_ENVS
    num_envs = int(num_envs)
    if num_envs < 1:
        raise ConfigError(f"num_envs must be >= 1, got {num_envs}")
    if not accel:
        max_batch = min(max_batch, CPU_MAX_BATCH)
    scale = max(1.0, num_envs / BASE_NUM_ENVS)
    batch = int(min(max_batch, 2 ** round(math.log2(BASE_BATCH * scale))))
    batch = max(batch, min(BASE_BATCH, max_batch))
    samples = ratio * num_envs * episode_length
    n_batches = max(1, int(math.ceil(samples / batch - 1e-9)))
    buffer_size = max(1_000_000, MIN_BUFFER_CYCLES * num_envs * episode_length)
    out = dict(task=task, num_envs=num_envs, batch_size=batch, n_batches=n_batches,
               buffer_size=buffer_size)
    steps_per_cycle = num_envs * episode_length
    if accel:
        a = presets["accelerator"]
        out.update(physics="mjx", n_epochs=a["n_epochs"],
                   n_cycles=max(1, int(round(a["epoch_env_steps"] / steps_per_cycle))))
    else:
        c = presets["cpu"]
        out.update(c, n_batches=min(n_batches, CPU_MAX_UPDATES),
                   n_cycles=min(c["n_cycles"],
                                max(1, int(round(CPU_EPOCH_ENV_STEPS / steps_per_cycle)))))
    return out


def build_config(task: str, num_envs: int | None = None, device: str | None = None,
                 episode_length: int = 50, **overrides) -> TrainConfig:
    """The TrainConfig that ``run.py --task TASK`` trains: the preset at (num_envs, device),
    then `overrides` (validated: ConfigError names the field)."""
    return TrainConfig(**{**preset(task, num_envs, episode_length, device=device), **overrides})
