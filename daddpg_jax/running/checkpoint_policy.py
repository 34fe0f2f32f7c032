"""A trained run's policy from its checkpoint, without building the training step: the one loader
behind evaluation (``daddpg_jax.analysis.evaluation.load_policy``, daddpg-evaluate) and export
(``daddpg_jax.running.export.export_run``, daddpg-export).

    from daddpg_jax.running.checkpoint_policy import load_run_policy
    pol = load_run_policy("runs/reach")                 # latest checkpoint
    pol = load_run_policy("runs/reach", best=True)      # the best test success
    pol = load_run_policy("runs/reach", step=2, physics="mjx")
    actions = pol.act(pol.params, obs, desired_goal)    # [..., 8], deterministic

Run dir -> ``config.json`` (`checkpoint.load_config`: the TrainConfig, the env overrides, the
physics version the run was trained on) -> the env of the standard task (the run's env
overrides with the training-only task options switched off: ``runner.make_test_env``, the
builder ``daddpg-train --cross-check`` uses too) -> the restore target from the networks' and
normalizers' own init functions (``algo.actors.abstract_params``: shapes only, nothing
allocated) -> the actors and normalizers alone restored from the checkpoint (orbax's partial
restore, `checkpoint.restore` with an ActorParams template; the newest readable checkpoint, as
`run_record.restore_readable`).
No replay buffer, critic, optimizer state or training step (``algo.train.make_train_fns``) is
built, and the saved critics, optimizer states and buffer are not restored (the readability
check before the restore, `checkpoint.verify`, still reads every array once, as it always did).
Nor is the run's device count needed: a run trained with ``num_devices=2`` loads in a process
with one device.

Importing this module loads no JAX (the loader imports JAX, orbax and MuJoCo when called), so
that daddpg-evaluate --help stays JAX-free.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from daddpg_jax import variants
from mjx_envs import settings


class RunPolicyError(FileNotFoundError):
    """A run's policy cannot be loaded: no run directory, config.json or such checkpoint, no
    checkpoint readable, or both a step and best asked for. The message is one line."""


@dataclass
class RunPolicy:
    """A run's deterministic policy and the env it acts in: what evaluation and export read."""

    run_dir: str
    step: int          # the checkpoint restored
    cfg: Any           # the run's TrainConfig (its physics replaced when asked)
    payload: dict      # config.json
    env: Any           # the standard task's env (``runner.make_test_env``)
    act: Callable      # act(params, obs [..., 2, obs], desired_goal [..., 2, 3]) -> [..., 8]
    params: Any        # act's parameters: an algo.actors.ActorParams (actors, normalizers)
    best: bool = False  # restored from checkpoints_best/ (the best test success)

    @property
    def variant(self) -> variants.Variant:
        """The run's row of the variants table (``cfg.algo``: agents, what each actor sees)."""
        return variants.get(self.cfg.algo)


def load_run_policy(run_dir, step: int | None = None, best: bool = False,
                    physics: str | None = None, physics_version: int | None = None,
                    robot_limits: tuple | None = None) -> RunPolicy:
    """The policy of checkpoint ``step`` of the run in ``run_dir`` (default: the newest
    readable one, a warning naming each unreadable newer one), or with ``best`` of its best
    checkpoint (``checkpoints_best/``). ``physics``: the engine to act on instead of the run's.
    The env simulates the physics version the run was trained on, or ``physics_version`` (one
    warning line when that acts unlike the run's). ``robot_limits``: the env setting of a
    robot limits file (`daddpg_jax.algo.resolve.limits_values`), applied to every action
    instead of the run's own (None: the run's; ``()``: none). RunPolicyError (one line) when
    the run or the checkpoint cannot be read."""
    # lazy: JAX, orbax and MuJoCo load only when a run is loaded (--help stays JAX-free)
    import jax

    from daddpg_jax.algo import actors
    from daddpg_jax.running import checkpoint as ckpt
    from daddpg_jax.running.run_record import restore_readable
    from daddpg_jax.running.runner import make_test_env

    run_dir = os.fspath(run_dir)
    if best and step is not None:
        raise RunPolicyError("give a checkpoint step or best, not both")
    try:
        ckpt.check_run_dir(run_dir, step, best=best)
        cfg, payload = ckpt.load_config(run_dir)
    except ckpt.RunDirError as e:   # ConfigFileError too: one line naming the file
        raise RunPolicyError(str(e)) from None
    if physics is not None:
        cfg = cfg.replace(physics=physics)
    overrides = dict(payload.get("env_overrides") or {})
    if physics_version is not None:
        ckpt.physics_note(run_dir, payload, cfg.task, simulated=physics_version,
                          engine=cfg.physics if cfg.physics in settings.ENGINES else None)
        overrides["physics_version"] = int(physics_version)
    if robot_limits is not None:
        overrides["robot_limits"] = tuple(robot_limits)
        if not overrides["robot_limits"]:  # no limits: nothing to charge
            overrides["intervention_penalty"] = 0.0
    env = make_test_env(cfg, overrides)   # the training-only task options off
    target = actors.abstract_params(cfg, env.obs_size, env.goal_size)
    try:   # the newest readable checkpoint (a warning for each unreadable newer one)
        params, used = restore_readable(run_dir, target, step, best=best)
    except ckpt.CheckpointError as e:
        raise RunPolicyError(str(e)) from None

    def act(params, obs, desired_goal):
        return actors.act(cfg, params, obs, desired_goal)

    return RunPolicy(run_dir, int(used), cfg, payload, env, jax.jit(act), params, best=bool(best))
