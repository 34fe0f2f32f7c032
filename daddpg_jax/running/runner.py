"""A training run on disk: config, metrics CSV, learning curve, checkpoints, resume.

``experiments/run.py`` parses flags and calls :func:`train`. Python runs only between epochs
(evaluation, logs, checkpoints); inside an epoch everything is one compiled ``train_epoch``.

RUN_DIR layout::

    config.json          TrainConfig, env overrides, package versions, device, git revision
    metrics.csv          one row per epoch (columns: METRIC_COLUMNS)
    learning_curve.png   test success vs env steps
    checkpoints/{step}   orbax checkpoints (last ``keep_checkpoints``), step = epoch number
"""

from __future__ import annotations

import csv
import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import jax
import numpy as np

from daddpg_jax.algo import variants
from daddpg_jax.algo.config import TrainConfig
from daddpg_jax.running import checkpoint as ckpt

METRIC_COLUMNS = (
    "epoch", "env_steps", "updates", "wall_time", "test_success_rate", "test_arm_contact_rate",
    "test_final_distance_left", "test_final_distance_right", "train_success_rate",
    "train_arm_contact_rate", "critic_loss", "actor_loss", "mean_q", "env_steps_per_s",
    "updates_per_s", "bc_loss", "q_filter_pass", "rollout_time", "update_time", "eval_time",
)
"""Columns of metrics.csv. bc_loss and q_filter_pass (behaviour-cloning term and Q-filter pass
rate, mean over the epoch's updates and the agents) are NaN without demonstrations.
rollout_time, update_time and eval_time split the epoch's seconds: the rollouts, the updates
(with buffer insert and normalizer update), and the evaluation after the epoch (rollout and
update times are NaN on several devices). CSVs written before a column existed lack it and are
rewritten with it (blank) on --resume."""


class NonFiniteLoss(RuntimeError):
    """Raised when a loss became NaN/inf; the last good checkpoint is kept."""


@dataclass
class RunResult:
    run_dir: str
    epochs: int
    env_steps: int
    wall_time: float
    test_success_rate: float
    rows: list = field(default_factory=list)

    def summary(self) -> str:
        return (f"run {self.run_dir}: {self.epochs} epochs, {self.env_steps:,} env steps, "
                f"{self.wall_time:.0f} s, test success {self.test_success_rate:.3f}")


def _read_rows(path) -> list[dict]:
    if not os.path.exists(path):
        return []
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def _append_row(path, row: dict) -> None:
    new = not os.path.exists(path)
    with open(path, "a", newline="") as f:
        w = csv.DictWriter(f, fieldnames=METRIC_COLUMNS)
        if new:
            w.writeheader()
        w.writerow({k: row.get(k, "") for k in METRIC_COLUMNS})


def _scalar(x) -> float:
    return float(np.mean(np.asarray(x)))


def make_env(cfg: TrainConfig, env_overrides: dict | None = None):
    import mjx_envs

    return mjx_envs.make(cfg.task, physics=cfg.physics, **(env_overrides or {}))


def train(cfg: TrainConfig, run_dir: str, env_overrides: dict | None = None,
          resume: bool = False, progress: Callable[[dict], None] | None = None,
          on_epoch: Callable[[dict], None] | None = None, plot: bool = True,
          command: str | None = None, time_budget_s: float | None = None,
          env: Any = None, update_progress: Callable[[int], None] | None = None,
          update_tick: int = 0, demo_policy: Callable | None = None) -> RunResult:
    """Trains until ``cfg.n_epochs`` epochs are done (counting epochs of a resumed run).

    progress: host callback called once per cycle with that cycle's metrics (progress bar).
    on_epoch: called with each epoch's CSV row after it is written.
    time_budget_s: stop after the epoch during which this much wall time (this call) elapsed.
    env: an env object to use instead of ``mjx_envs.make(cfg.task, ...)`` (tests).
    update_progress / update_tick: host callback every ``update_tick`` updates within a cycle.
    demo_policy: the demonstrations' controller when cfg.n_demos > 0 (default: the task's
    scripted controller; see ``make_train_fns``).
    """
    env_overrides = dict(env_overrides or {})
    os.makedirs(run_dir, exist_ok=True)
    metrics_path = os.path.join(run_dir, "metrics.csv")
    env = env if env is not None else make_env(cfg, env_overrides)

    from daddpg_jax.algo.train import StageClock, make_train_fns

    clock = StageClock()
    fns = make_train_fns(env, cfg, progress=progress, update_progress=update_progress,
                         update_tick=update_tick, demo_policy=demo_policy, clock=clock)
    if fns.num_devices > 1:
        clock = None
    state = fns.init(jax.random.PRNGKey(cfg.seed))
    rows, start_epoch, wall_offset = [], 0, 0.0
    if resume:
        state, start_epoch, rows, wall_offset = _resume(run_dir, state)
    else:
        if os.path.exists(metrics_path):
            os.remove(metrics_path)
        ckpt.save_config(run_dir, cfg, env_overrides=env_overrides,
                         env_config=_jsonable(dict(getattr(env.config, "__dict__", {}))),
                         command=command, num_agents=variants.get(cfg.algo).num_agents,
                         physics_resolved=getattr(env, "physics", None))

    t_start = time.perf_counter()
    last = rows[-1] if rows else None
    epoch = start_epoch
    while epoch < cfg.n_epochs:
        t0 = time.perf_counter()
        if clock is not None:
            clock.start()
        state, m = fns.train_epoch(state)
        m = jax.device_get(m)
        dt = time.perf_counter() - t0
        if bool(np.any(m["nonfinite"])):
            raise NonFiniteLoss(
                f"non-finite loss in epoch {epoch + 1}; stopping. The last good checkpoint "
                f"(epoch {ckpt.latest_step(run_dir)}) is kept in {ckpt.checkpoint_dir(run_dir)}.")
        epoch += 1
        t_ev = time.perf_counter()
        ev = jax.device_get(fns.evaluate(state))
        row = _epoch_row(cfg, env, epoch, fns.env_steps(state), int(state.updates),
                         round(wall_offset + time.perf_counter() - t_start, 3), ev, m, dt)
        row.update(rollout_time=clock.rollout_s if clock else math.nan,
                   update_time=clock.update_s if clock else math.nan,
                   eval_time=time.perf_counter() - t_ev)
        _append_row(metrics_path, row)
        ckpt.save(run_dir, state, epoch, save_buffer=cfg.save_buffer, keep=cfg.keep_checkpoints)
        rows.append(row)
        last = row
        if plot:
            from daddpg_jax.analysis.plotting import plot_learning_curve

            plot_learning_curve(rows, os.path.join(run_dir, "learning_curve.png"),
                                title=f"{cfg.task} / {cfg.algo} / {cfg.num_envs} envs")
        if on_epoch is not None:
            on_epoch(row)
        if time_budget_s is not None and time.perf_counter() - t_start >= time_budget_s:
            break
    if last is None:
        return RunResult(run_dir, epoch, fns.env_steps(state), wall_offset, math.nan, rows)
    return RunResult(run_dir, int(last["epoch"]), int(last["env_steps"]),
                     float(last["wall_time"]), float(last["test_success_rate"]), rows)


def _resume(run_dir: str, state):
    """(state restored from the latest checkpoint, its epoch, the CSV rows up to it, their
    wall time); metrics.csv is rewritten without rows of epochs after the checkpoint (a crash
    between the CSV write and the checkpoint)."""
    metrics_path = os.path.join(run_dir, "metrics.csv")
    rows = _read_rows(metrics_path)
    step = ckpt.latest_step(run_dir)
    if step is None:
        raise FileNotFoundError(f"--resume: no checkpoint in {ckpt.checkpoint_dir(run_dir)}")
    state, start_epoch = ckpt.restore(run_dir, state, step)
    rows = [r for r in rows if int(r["epoch"]) <= start_epoch]
    if os.path.exists(metrics_path):
        os.remove(metrics_path)
    for r in rows:
        _append_row(metrics_path, r)
    wall_offset = float(rows[-1]["wall_time"]) if rows else 0.0
    return state, start_epoch, rows, wall_offset


def _epoch_row(cfg: TrainConfig, env, epoch: int, env_steps: int, updates: int, wall: float,
               ev: dict, m: dict, dt: float) -> dict:
    """The metrics.csv row of an epoch: ev = evaluation, m = the epoch's per-cycle metrics,
    dt = the epoch's seconds."""
    fd = np.asarray(ev["final_distance"]).reshape(-1)
    return {
        "epoch": epoch, "env_steps": env_steps, "updates": updates, "wall_time": wall,
        "test_success_rate": _scalar(ev["success"]),
        "test_arm_contact_rate": _scalar(ev["arm_contact"]),
        "test_final_distance_left": float(fd[0]), "test_final_distance_right": float(fd[-1]),
        "train_success_rate": _scalar(m["success"]),
        "train_arm_contact_rate": _scalar(m["arm_contact"]),
        "critic_loss": _scalar(m["critic_loss"]), "actor_loss": _scalar(m["actor_loss"]),
        "mean_q": _scalar(m["mean_q"]) if "mean_q" in m else math.nan,
        "env_steps_per_s": cfg.n_cycles * cfg.num_envs * env.episode_length / dt,
        "updates_per_s": cfg.n_cycles * cfg.n_batches / dt,
        "bc_loss": _scalar(m["bc_loss"]) if "bc_loss" in m else math.nan,
        "q_filter_pass": _scalar(m["q_filter_pass"]) if "q_filter_pass" in m else math.nan,
    }


def _jsonable(d: dict) -> dict:
    out = {}
    for k, v in d.items():
        if isinstance(v, tuple):
            v = [list(x) if isinstance(x, tuple) else x for x in v]
        out[k] = v
    return out
