"""The engine check where the policy is made: ``daddpg-train --cross-check ENGINE``
(TrainConfig.cross_check).

At every evaluation (between epochs) the run's best checkpoint so far, the one it keeps in
``checkpoints_best/``, is also played on the other physics engine over the run's own test
episodes: the same ``n_test_episodes`` reset keys from ``eval_seed``, deterministic actors, each
engine closing its own loop, so the two success rates are paired. Its row of metrics.csv gets
``metric_columns.CROSS_COLUMNS`` (test_success_best, cross_success_best, cross_best_epoch,
cross_eval_time), which the trackers log like every column (tags ``test/success_best``,
``cross/success_best``, ...), and the run's closing lines warn when the two engines' success at
the best checkpoint part by more than `PART_TOLERANCE` (`parting_warning`).

The other engine's env is the run's test env with only the physics changed, built once per run
by the runner's own builder (the path ``daddpg-evaluate RUN --physics E`` takes: the run's config
with ``physics=E``, its env overrides with the training-only task options off, then
``runner.make_env``), and its evaluation program compiles once. The best checkpoint is played
there only when it changes (the same parameters over the same episodes give the same number),
so the check costs one evaluation on the other engine per new best. After ``--resume`` the best
checkpoint is read back from ``checkpoints_best/`` when first needed.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import jax
import numpy as np

from daddpg_jax.algo.config import TrainConfig
from daddpg_jax.algo.train import make_train_fns
from daddpg_jax.running import checkpoint as ckpt
from daddpg_jax.running import distributed as dist
from daddpg_jax.running.run_record import restore_readable, warn
from mjx_envs.physics.backends import default_chunk
from mjx_envs.schema import ConfigError
from mjx_envs.settings import ENGINES

PART_TOLERANCE = 0.10
"""the success difference between the engines at the best checkpoint above which the run's
closing lines warn (the ±0.10 agreement of docs/MJX_VS_C.md)"""

_ACCELERATORS = ("gpu", "cuda", "rocm", "tpu")


def resolved_physics(physics: str, backend: str | None = None) -> str:
    """The engine a run's physics setting names: ``auto`` is MJX on an accelerator, the C engine
    on a CPU (as `mjx_envs.physics.backends.default_physics`)."""
    if physics != "auto":
        return physics
    backend = backend or jax.default_backend()
    return "mjx" if backend in _ACCELERATORS else "c"


def check(physics: str, cross_check: str, backend: str | None = None,
          multiprocess: bool | None = None) -> None:
    """ConfigError (one line naming the flag) unless `cross_check` is off ('') or the engine
    other than the run's `physics` (``auto`` resolved on `backend`), in a one-process job."""
    if not cross_check:
        return
    if cross_check not in ENGINES:
        raise ConfigError(f"--cross-check: unknown engine {cross_check!r} (choose from "
                          f"{', '.join(ENGINES)}: the engine other than --physics)")
    backend = backend or jax.default_backend()
    engine = resolved_physics(physics, backend)
    if cross_check == engine:
        other = next(e for e in ENGINES if e != engine)
        via = "" if physics == engine else f" (--physics {physics} on this {backend})"
        raise ConfigError(
            f"--cross-check {cross_check}: the run already trains on the engine "
            f"'{engine}'{via}; --cross-check names the other engine, on which the best "
            f"checkpoint is also evaluated: --cross-check {other}, or leave it out")
    if dist.is_multiprocess() if multiprocess is None else multiprocess:
        raise ConfigError("--cross-check runs in a one-process job only; evaluate the run "
                          "afterwards with daddpg-evaluate RUN --best --physics c,mjx")


def apply_flag(cfg: TrainConfig, flag: str | None, resumed: bool = False) -> TrainConfig:
    """cfg with daddpg-train's ``--cross-check`` (None: not given, cfg's own value: a resumed
    or recorded run keeps its config.json's), then `check`ed. A resumed run keeps the engine it
    was started with: a different flag is ConfigError."""
    if flag is not None:
        if resumed and flag != cfg.cross_check:
            raise ConfigError(f"--resume: --cross-check {flag} differs from the run's config "
                              f"(cross_check {cfg.cross_check or 'off'}); start a new run "
                              "instead")
        cfg = cfg.replace(cross_check=flag)
    check(cfg.physics, cfg.cross_check)
    return cfg


def parting_warning(test_best: float, cross_best: float, physics: str, engine: str,
                    epoch: int | None = None, tolerance: float = PART_TOLERANCE) -> str | None:
    """The closing warning of a run with --cross-check (without 'warning: '), or None when the
    two engines' success at the best checkpoint part by `tolerance` or less (or either is
    unknown, NaN). Success rates are float32 means: differences within 1e-6 of `tolerance`
    count as equal to it."""
    try:
        a, b = float(test_best), float(cross_best)
    except (TypeError, ValueError):
        return None
    if math.isnan(a) or math.isnan(b) or abs(a - b) <= tolerance + 1e-6:
        return None
    at = "the best checkpoint" if epoch is None else f"the best checkpoint (epoch {epoch})"
    return (f"--cross-check: at {at} test success is {a:.3f} on the training engine "
            f"({physics}) but {b:.3f} on {engine} over the same test episodes, {abs(a - b):.3f} "
            f"apart (more than {tolerance:.2f}): the policy relies on what one engine does and "
            f"the other does not; compare them with daddpg-evaluate RUN --best --physics "
            f"{physics},{engine} --seed S (docs/MJX_VS_C.md)")


def acting_state(state):
    """A host copy of what acting needs of a TrainState (actors, normalizers): the buffer,
    critics and optimizer states dropped. A copy, so that a later train_epoch (which donates
    its state) leaves it intact."""
    agent = state.agent.replace(critic=None, target_actor=None, target_critic=None,
                                actor_opt=None, critic_opt=None)
    return jax.device_get(state.replace(agent=agent, buffer=None, demos=None, key=None,
                                        cycles=None, updates=None))


@dataclass
class CrossCheck:
    """The other engine of a run: its test env and evaluation, and the best checkpoint so far
    (epoch, acting state, success there)."""
    cfg: TrainConfig
    run_dir: str
    env: Any
    fns: Any                      # TrainFns of `env`; only `evaluate` is used
    best_epoch: int | None = None
    policy: Any = None            # acting_state of the best checkpoint
    value: float | None = None    # its success on the other engine (None: not played yet)
    restore_failed: bool = False  # after --resume, checkpoints_best/ could not be read

    @classmethod
    def build(cls, cfg: TrainConfig, run_dir: str, make_test_env: Callable) -> CrossCheck:
        """`make_test_env(cfg) -> env`: the runner's builder of a run's test env, called once,
        with the run's config on the other engine."""
        # acting needs no replay buffer nor demonstrations (as checkpoint_policy's loader); one
        # device: the acting state is a host copy, placed by the evaluation's jit
        other = cfg.replace(physics=cfg.cross_check, buffer_size=1, n_demos=0, num_devices=1)
        env = make_test_env(other)
        chunk = default_chunk(getattr(env, "physics", other.physics))
        return cls(cfg, run_dir, env, make_train_fns(env, other, eval_chunk=chunk))

    def columns(self, state, epoch: int, success: float, best: float) -> dict:
        """The CROSS_COLUMNS of epoch `epoch`'s row: `state` after it, `success` its test
        success, `best` the best test success of the earlier epochs (-inf: none). This epoch's
        checkpoint becomes the best one when its success is above `best` (RunLog.commit's
        rule)."""
        if success > best:
            self.best_epoch, self.policy, self.value = epoch, acting_state(state), None
            best = success
        elif self.policy is None and best > -math.inf and not self.restore_failed:
            self._restore_best(state)
        seconds = 0.0
        if self.value is None and self.policy is not None:
            t0 = time.perf_counter()
            ev = jax.device_get(self.fns.evaluate(self.policy))
            self.value = float(np.mean(np.asarray(ev["success"])))
            seconds = time.perf_counter() - t0
        return {"test_success_best": best if best > -math.inf else math.nan,
                "cross_success_best": math.nan if self.value is None else self.value,
                "cross_best_epoch": math.nan if self.best_epoch is None else self.best_epoch,
                "cross_eval_time": seconds}

    def _restore_best(self, template) -> None:
        """After --resume: the best checkpoint read back from checkpoints_best/ (unreadable:
        one warning, and the columns stay NaN until the next new best)."""
        try:
            state, step = restore_readable(self.run_dir, template, best=True)
        except ckpt.CheckpointError as e:
            warn(f"--cross-check: the best checkpoint cannot be read ({e}); the "
                 "cross-check columns stay NaN until the next best epoch")
            self.restore_failed = True
            return
        self.best_epoch, self.policy, self.value = int(step), acting_state(state), None
