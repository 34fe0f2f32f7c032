"""A training run on disk: config, metrics CSV, learning curve, checkpoints, resume.

``experiments/run.py`` parses flags and calls :func:`train`. Python runs only between epochs
(evaluation, logs, checkpoints); inside an epoch everything is one compiled ``train_epoch``.

RUN_DIR layout::

    config.json          TrainConfig, env overrides, package versions, device, git revision
    metrics.csv          one row per epoch (columns: metric_columns.METRIC_COLUMNS; with
                         cross_check also CROSS_COLUMNS: daddpg_jax/running/cross_check.py)
    learning_curve.png   test success vs env steps
    checkpoints/{step}   orbax checkpoints (last ``keep_checkpoints``), step = epoch number
    checkpoints_best/{step}  the checkpoint with the best test success (earliest of ties),
                         without the replay buffer
    tensorboard/         TensorBoard event files (daddpg_jax/running/tracking.py); with --wandb
                         wandb/, with --video-every videos/
    .lock                held (flock) by the process using the run directory: a second run on
                         it stops with RunLockedError

Crash safety (docs/RELIABILITY.md, "Training runs"): after each epoch metrics.csv is rewritten
whole through a temporary file and ``os.replace``, then the checkpoint is saved (orbax renames
it into place when complete), then the best checkpoint is updated. A resume restores the newest
complete checkpoint that can be read (warning about and deleting newer unreadable ones), drops
the CSV rows of later epochs and makes checkpoints_best/ agree with the CSV; a run directory
without any complete checkpoint starts again from epoch 0.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from types import SimpleNamespace
from typing import Any

import jax
import numpy as np

import mjx_envs
from daddpg_jax import variants
from daddpg_jax.algo.config import TrainConfig
from daddpg_jax.algo.train import StageClock, make_train_fns
from daddpg_jax.running import checkpoint as ckpt
from daddpg_jax.running import cross_check as xcheck
from daddpg_jax.running import distributed as dist
from daddpg_jax.running import resources, tracking
from daddpg_jax.running.levels import reaches
from daddpg_jax.running.metric_columns import metric_columns
from daddpg_jax.running.run_record import (
    RunLog,
    check_resume_layout,
    prepare_run_dir,
    resume,
    success_of,
    warn,
)
from mjx_envs import registry
from mjx_envs.physics.backends import default_chunk
from mjx_envs.schema import ConfigError

PHYSICS_FAULT_WARN = 0.01
"""an epoch whose training or test physics-fault rate is above this gets a warning on stderr"""

MJX_CPU_MAX_BATCH = 256
"""MJX on a CPU hangs at this many envs (or test episodes) or more; refused before compiling"""


class NonFiniteLoss(RuntimeError):
    """Raised when a loss became NaN/inf; the last good checkpoint is kept."""


RunDirError = ckpt.RunDirError
CheckpointError = ckpt.CheckpointError
CheckpointSaveError = ckpt.CheckpointSaveError

STOP_REASONS = {
    "epochs": "all {n_epochs} epochs done",
    "time_budget": "time budget of {time_budget_s:g} s used",
    "stop_at_success": "test success reached {stop_at_success:g} (--stop-at-success)",
}
"""why a run stopped (RunResult.stopped) -> the closing line's words"""


@dataclass
class RunResult:
    run_dir: str
    epochs: int
    env_steps: int
    wall_time: float
    test_success_rate: float
    rows: list = field(default_factory=list)
    stopped: str = "epochs"
    """why the run stopped: a key of STOP_REASONS"""
    why: str = ""
    """STOP_REASONS[stopped] with the run's values"""
    cross: dict = field(default_factory=dict)
    """with cross_check: physics, engine, and the last row's test_success_best,
    cross_success_best and cross_best_epoch; {} without"""

    def summary(self) -> str:
        why = f"; stopped: {self.why}" if self.why else ""
        cross = ""
        if self.cross:
            c = self.cross
            epoch = "" if self._best_epoch() is None else f" (epoch {self._best_epoch()})"
            cross = (f"; best checkpoint{epoch}: test success {c['test_success_best']:.3f} on "
                     f"{c['physics']}, {c['cross_success_best']:.3f} on {c['engine']} "
                     "(--cross-check)")
        return (f"run {self.run_dir}: {self.epochs} epochs, {self.env_steps:,} env steps, "
                f"{self.wall_time:.0f} s, test success {self.test_success_rate:.3f}{why}{cross}")

    def cross_warning(self) -> str | None:
        """With cross_check: the warning line (without 'warning: ') when the two engines'
        success at the best checkpoint part by more than cross_check.PART_TOLERANCE; else
        None."""
        if not self.cross:
            return None
        c = self.cross
        return xcheck.parting_warning(c["test_success_best"], c["cross_success_best"],
                                      c["physics"], c["engine"], self._best_epoch())

    def _best_epoch(self) -> int | None:
        epoch = self.cross.get("cross_best_epoch", math.nan)
        return None if math.isnan(epoch) else int(epoch)








def _scalar(x) -> float:
    return float(np.mean(np.asarray(x)))




def make_env(cfg: TrainConfig, env_overrides: dict | None = None):
    """The training env: ``mjx_envs.make`` of cfg.task with cfg.physics and the overrides."""
    return mjx_envs.make(cfg.task, physics=cfg.physics, **(env_overrides or {}))


def make_test_env(cfg: TrainConfig, env_overrides: dict | None = None):
    """A run's test env on its own: the task of cfg on cfg.physics with the run's env overrides
    and the training-only task options off (``mjx_envs.registry.test_overrides``), what
    ``daddpg-evaluate RUN --physics E`` builds from a run's config.json
    (``evaluation.load_policy``) and what ``--cross-check`` plays the best checkpoint on."""
    return make_env(cfg, {**(env_overrides or {}), **registry.test_overrides(cfg.task)})


def make_eval_env(cfg: TrainConfig, env_overrides: dict | None = None):
    """The env of test episodes: the task without its training-only options
    (mjx_envs.registry.test_overrides: goals at rest height, grasped-state starts), so that
    test success always measures the standard task. None when the overrides switch none of
    them on (the training env then serves both)."""
    env_overrides = dict(env_overrides or {})
    test = registry.test_overrides(cfg.task)
    train_cfg = registry.task_config(cfg.task, **env_overrides)
    if all(getattr(train_cfg, k) == v for k, v in test.items()):
        return None
    return make_test_env(cfg, env_overrides)


def check_physics_backend(physics: str | None, num_envs: int,
                          backend: str | None = None) -> None:
    """Raises ConfigError for MJX physics on a CPU at MJX_CPU_MAX_BATCH envs or more: such a
    run hangs inside XLA's batched Cholesky factorization (docs/RELIABILITY.md), so it is
    refused before anything compiles. Test episodes are played in batches of
    `mjx_envs.settings.MJX_CPU_CHUNK` there, whatever n_test_episodes is."""
    backend = backend or jax.default_backend()
    if physics != "mjx" or backend != "cpu":
        return
    if num_envs >= MJX_CPU_MAX_BATCH:
        raise ConfigError(
            f"physics 'mjx' on a CPU with num_envs={num_envs}: MJX at {MJX_CPU_MAX_BATCH} or "
            "more envs per batch hangs on a CPU (a deadlock inside XLA's batched Cholesky "
            "factorization; docs/RELIABILITY.md); use --physics c (the MuJoCo C engine, the "
            f"CPU default) or fewer than {MJX_CPU_MAX_BATCH} envs")




@dataclass
class RunOptions:
    """How `train` runs a config: where, and what it reports. Every field but run_dir has a
    default that a plain run uses."""

    run_dir: str
    """the run directory (layout in the module docstring)"""
    env_overrides: dict = field(default_factory=dict)
    """env fields over the task's defaults (keywords of ``mjx_envs.make``); recorded in
    config.json"""
    resume: bool = False
    """continue the run in run_dir (see the module docstring); else run_dir must hold no
    checkpoint (RunDirError) unless force"""
    force: bool = False
    """delete the run in run_dir first"""
    hooks: Any = None
    """what the run reports while it trains (e.g. ``daddpg_jax.running.progress.Progress``), an
    object with any of: ``start(epoch)`` (once, with the epoch the run starts from, before the
    first epoch compiles), ``cycle(metrics)`` (once per cycle, from inside the compiled epoch:
    ``algo.train.EpochHooks``), ``epoch(row)`` (each epoch's metrics.csv row after it is
    written). start and epoch run on process 0 only; cycle is compiled into every process's
    epoch"""
    loggers: list | None = None
    """experiment trackers (``daddpg_jax.running.tracking``) fed the config and every CSV row;
    None = TensorBoard event files in RUN_DIR/tensorboard; [] = none"""
    plot: Callable | None = None
    """``plot(rows, path, title)``: draws learning_curve.png from the CSV rows after every epoch
    (e.g. ``daddpg_jax.analysis.plotting.plot_learning_curve``); None = no plot"""
    video: Callable | None = None
    """``video(env, fns, state, path) -> (path written, frames, fps)``: a video of test episodes
    of the current policy (e.g. ``daddpg_jax.analysis.evaluation.train_video``), every
    video_every epochs"""
    video_every: int = 0
    """every this many epochs, a video into RUN_DIR/videos and the loggers (0 = never; when it
    fails, e.g. without a renderer, one warning and training goes on)"""
    time_budget_s: float | None = None
    """stop after the epoch during which this much wall time (this call) elapsed"""
    stop_at_success: float | None = None
    """stop after the first epoch whose test success rate is at least this (within float32
    rounding: 90 of 100 episodes reach 0.9)"""
    command: str | None = None
    """the command line, recorded in config.json"""
    demo_policy: Callable | None = None
    """the demonstrations' controller when cfg.n_demos > 0 (default: the task's scripted
    controller; see ``algo.train.make_train_fns``)"""
    make_env: Callable | None = None
    """``make_env(cfg, env_overrides) -> env``: the training env, for an env that
    ``mjx_envs.make`` does not build (e.g. a small test env or a wrapped task); it then serves
    the test episodes too. None = `make_env` and `make_eval_env` of this module"""


def train(cfg: TrainConfig, options: RunOptions) -> RunResult:
    """Trains until ``cfg.n_epochs`` epochs are done (counting epochs of a resumed run), with
    `options` (RunOptions: run directory, resume, hooks, loggers, stop rules, ...).

    In a multi-process job (daddpg_jax/running/distributed.py) every process calls this with
    the same config and options (checked: DistributedError otherwise); process 0 alone
    prepares run_dir, writes config.json, metrics.csv and the plot, and calls the hooks'
    ``start`` and ``epoch``.
    """
    opts = replace(options, env_overrides=dict(options.env_overrides or {}))
    dist.check_same_config(dict(config=cfg.to_dict(), env_overrides=opts.env_overrides,
                                run_dir=os.fspath(opts.run_dir), resume=opts.resume,
                                force=opts.force, time_budget_s=opts.time_budget_s,
                                stop_at_success=opts.stop_at_success))
    if opts.make_env is None:
        check_physics_backend(cfg.physics, cfg.num_envs)
    xcheck.check(cfg.physics, cfg.cross_check)
    dist.on_primary(prepare_run_dir, opts.run_dir, opts.resume, opts.force,
                    errors=(RunDirError, ValueError, OSError))
    try:
        return _train(cfg, opts)
    finally:
        if dist.is_primary():
            ckpt.unlock_run_dir(opts.run_dir)


def _train(cfg: TrainConfig, opts: RunOptions) -> RunResult:
    """`train` once process 0 holds the run directory's lock."""
    run_dir = opts.run_dir
    layout = dist.current_layout() if dist.is_multiprocess() else None
    if opts.resume:
        check_resume_layout(run_dir, layout)
    if opts.make_env is None:
        env = make_env(cfg, opts.env_overrides)
        eval_env = make_eval_env(cfg, opts.env_overrides)
    else:
        env = opts.make_env(cfg, opts.env_overrides)
        check_physics_backend(getattr(env, "physics", None), cfg.num_envs)
        eval_env = None
    clock = StageClock()
    epoch_hooks = SimpleNamespace(cycle=getattr(opts.hooks, "cycle", None), stage=clock.stage)
    fns = make_train_fns(env, cfg, hooks=epoch_hooks, demo_policy=opts.demo_policy,
                         eval_env=eval_env,
                         eval_chunk=default_chunk(getattr(env, "physics", cfg.physics)))
    check_memory(fns, cfg)
    # --cross-check: the other engine's test env, built once (its evaluation compiles once)
    cross = (xcheck.CrossCheck.build(cfg, run_dir, lambda c: _test_env_of(c, opts))
             if cfg.cross_check else None)
    columns = metric_columns(cfg.cross_check)
    state = fns.init(jax.random.PRNGKey(cfg.seed))
    if opts.resume:
        state, log = resume(run_dir, state, columns)
    else:
        log = RunLog(run_dir, [], columns=columns)
        if dist.is_primary():
            extra = {"distributed": layout.to_dict()} if layout is not None else {}
            ckpt.save_config(run_dir, cfg, env_overrides=opts.env_overrides,
                             env_config=_jsonable(dict(getattr(env.config, "__dict__", {}))),
                             command=opts.command, num_agents=variants.get(cfg.algo).num_agents,
                             physics_resolved=getattr(env, "physics", None), **extra)
    epoch = log.epoch
    trackers = _open_loggers(opts.loggers, cfg, run_dir, opts.env_overrides, log)
    on_start = getattr(opts.hooks, "start", None)
    try:
        if on_start is not None and dist.is_primary():
            on_start(epoch)
        run = _Run(cfg, opts, env, eval_env or env, fns, clock, log, trackers, cross)
        state, stopped = run.epochs(state)
    finally:
        for t in trackers:
            t.close()
    why = STOP_REASONS[stopped].format(n_epochs=cfg.n_epochs,
                                       time_budget_s=opts.time_budget_s or 0,
                                       stop_at_success=opts.stop_at_success or 0)
    if not log.rows:
        return RunResult(run_dir, epoch, fns.env_steps(state), log.wall_offset, math.nan, [],
                         stopped, why)
    last = log.rows[-1]
    return RunResult(run_dir, int(last["epoch"]), int(last["env_steps"]),
                     float(last["wall_time"]), float(last["test_success_rate"]), log.rows,
                     stopped, why, _cross_result(cfg, env, cross, last))


def _test_env_of(cfg: TrainConfig, opts: RunOptions):
    """The test env of `cfg` (the --cross-check engine's): `make_test_env`, or the caller's
    ``RunOptions.make_env``."""
    if opts.make_env is not None:
        return opts.make_env(cfg, opts.env_overrides)
    return make_test_env(cfg, opts.env_overrides)


def _cross_result(cfg: TrainConfig, env, cross, last: dict) -> dict:
    """RunResult.cross: the two engines and the last row's cross-check columns as numbers
    (NaN where empty); {} when off."""
    if cross is None:
        return {}
    out = dict(physics=getattr(env, "physics", None) or xcheck.resolved_physics(cfg.physics),
               engine=cfg.cross_check)
    for k in ("test_success_best", "cross_success_best", "cross_best_epoch"):
        try:
            out[k] = float(last.get(k))
        except (TypeError, ValueError):
            out[k] = math.nan
    return out


@dataclass
class _Run:
    """The loop of epochs of a run whose state is built: training env, test env, compiled
    functions, the stage clock compiled into them, what was written, the trackers."""
    cfg: TrainConfig
    opts: RunOptions
    env: Any
    eval_env: Any
    fns: Any
    clock: StageClock
    log: RunLog
    trackers: list
    cross: Any = None
    """--cross-check: the other engine (cross_check.CrossCheck), None when off"""

    def epochs(self, state):
        """Epochs until a stop rule; (the last state, why it stopped: a key of STOP_REASONS)."""
        cfg, opts, log = self.cfg, self.opts, self.log
        t_start = time.perf_counter()
        epoch = log.epoch
        on_epoch = getattr(opts.hooks, "epoch", None)
        while epoch < cfg.n_epochs:
            state, row = self.train_epoch(state, epoch, t_start - log.wall_offset)
            epoch += 1
            log.commit(cfg, state, row)
            if dist.is_primary():
                _warn_physics_faults(row)
                if opts.plot is not None:
                    _plot(opts.plot, cfg, log.run_dir, log.rows)
                for t in self.trackers:
                    t.log_row(row)
                if opts.video is not None and opts.video_every and epoch % opts.video_every == 0:
                    self.video(state, epoch, int(row["env_steps"]))
                if on_epoch is not None:
                    on_epoch(row)
            if opts.time_budget_s is not None and dist.from_primary(
                    time.perf_counter() - t_start >= opts.time_budget_s):
                return state, "time_budget"
            if opts.stop_at_success is not None and reaches(success_of(row),
                                                            opts.stop_at_success):
                return state, "stop_at_success"
        return state, "epochs"

    def train_epoch(self, state, epoch: int, t_zero: float):
        """Epoch `epoch + 1`: (state after it, its CSV row); t_zero: the run's start on the
        perf_counter clock (earlier epochs included)."""
        fns, clock = self.fns, self.clock
        t0 = time.perf_counter()
        clock.start()
        state, m = fns.train_epoch(state)
        m = jax.device_get(m)
        epoch_s = time.perf_counter() - t0
        if bool(np.any(m["nonfinite"])):
            raise NonFiniteLoss(_nonfinite_message(self.log.run_dir, epoch + 1))
        t_eval = time.perf_counter()
        ev = jax.device_get(fns.evaluate(state))
        row = _epoch_row(self.cfg, self.env, epoch + 1, fns.env_steps(state),
                         int(state.updates), round(time.perf_counter() - t_zero, 3), ev, m,
                         epoch_s)
        row.update(rollout_time=clock.rollout_s, update_time=clock.update_s,
                   eval_time=time.perf_counter() - t_eval)
        if self.cross is not None:   # before commit: the best's rule needs the earlier best
            row.update(self.cross.columns(state, epoch + 1, success_of(row), self.log.best))
        return state, row

    def video(self, state, epoch: int, env_steps: int) -> None:
        """RUN_DIR/videos/epoch_{epoch}.mp4 of test episodes, also given to the trackers; when
        it cannot be made (no renderer, no imageio, an env without a MuJoCo scene) one warning
        (once per process) and nothing else."""
        path = os.path.join(self.log.run_dir, "videos", f"epoch_{epoch:04d}.mp4")
        try:
            path, frames, fps = self.opts.video(self.eval_env, self.fns, state, path)
        except Exception as e:  # noqa: BLE001 (no EGL, an env without a scene: videos are extra)
            if not _VIDEO_WARNED:
                warn(f"--video-every: no video ({ckpt.root_cause(e)}); training goes on "
                     "without videos")
                _VIDEO_WARNED.append(True)
            return
        for t in self.trackers:
            t.log_video(frames, fps, env_steps, path)


def check_memory(fns, cfg: TrainConfig) -> None:
    """Raises ConfigError (one line) when the training state (replay buffer, networks,
    optimizer moments; sizes from shapes, nothing allocated) cannot fit in memory."""
    shapes = jax.eval_shape(fns.init, jax.random.PRNGKey(0))
    nbytes = resources.tree_bytes(shapes)
    if jax.devices()[0].platform != "cpu":
        nbytes //= fns.num_devices   # the replay is sharded over the accelerators' memories
    resources.check_fits(
        f"the training state (buffer_size={cfg.buffer_size:,} transitions, "
        f"hidden={','.join(map(str, cfg.hidden))})", nbytes,
        "lower buffer_size or hidden (--set)")


def _open_loggers(loggers, cfg, run_dir, env_overrides, log) -> list:
    """The run's experiment trackers (process 0 only), started with the config."""
    if not dist.is_primary():
        return []
    if loggers is None:
        loggers = [tracking.TensorBoardLogger(run_dir)]
    for t in loggers:
        t.start(cfg, env_overrides, resumed_rows=log.rows)
    return list(loggers)


_VIDEO_WARNED: list = []


def _plot(plot: Callable, cfg: TrainConfig, run_dir: str, rows: list) -> None:
    """learning_curve.png by `plot`, written to a temporary file and renamed (never torn by a
    kill)."""
    tmp = ckpt.temp_path(os.path.join(run_dir, "learning_curve.png"), suffix=".png")
    try:
        plot(rows, tmp, title=f"{cfg.task} / {cfg.algo} / {cfg.num_envs} envs / seed {cfg.seed}")
        os.replace(tmp, os.path.join(run_dir, "learning_curve.png"))
    finally:
        if os.path.lexists(tmp):
            os.remove(tmp)


def _nonfinite_message(run_dir: str, epoch: int) -> str:
    last = ckpt.latest_step(run_dir)
    if last is None:
        return (f"non-finite loss in epoch {epoch}; stopping. No checkpoint was written: the "
                "run had not finished an epoch.")
    return (f"non-finite loss in epoch {epoch}; stopping. The last good checkpoint "
            f"(epoch {last}) is kept in {ckpt.checkpoint_dir(run_dir)}.")


def _warn_physics_faults(row: dict) -> None:
    rates = {k: float(row[f"{k}_physics_fault_rate"]) for k in ("train", "test")}
    if any(v > PHYSICS_FAULT_WARN for v in rates.values()):   # NaN (not reported): no warning
        warn(f"epoch {row['epoch']}: physics faults in {rates['train']:.1%} of the training "
             f"and {rates['test']:.1%} of the test episodes (above {PHYSICS_FAULT_WARN:.0%}): "
             "the engine froze or diverged there (e.g. MuJoCo's 'Nan, Inf or huge value in "
             "QACC'), and those episodes are still learned from; check the env settings "
             "(timestep, n_substeps, max_delta)")


















def _epoch_row(cfg: TrainConfig, env, epoch: int, env_steps: int, updates: int, wall: float,
               ev: dict, m: dict, epoch_s: float) -> dict:
    """The metrics.csv row of an epoch: ev = evaluation, m = the epoch's per-cycle metrics,
    epoch_s = the epoch's seconds (train_epoch, without the evaluation)."""
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
        "env_steps_per_s": cfg.n_cycles * cfg.num_envs * env.episode_length / epoch_s,
        "updates_per_s": cfg.n_cycles * cfg.n_batches / epoch_s,
        "bc_loss": _scalar(m["bc_loss"]) if "bc_loss" in m else math.nan,
        "q_filter_pass": _scalar(m["q_filter_pass"]) if "q_filter_pass" in m else math.nan,
        "train_physics_fault_rate":
            _scalar(m["physics_fault"]) if "physics_fault" in m else math.nan,
        "test_physics_fault_rate":
            _scalar(ev["physics_fault"]) if "physics_fault" in ev else math.nan,
    }


def _jsonable(d: dict) -> dict:
    out = {}
    for k, v in d.items():
        if isinstance(v, tuple):
            v = [list(x) if isinstance(x, tuple) else x for x in v]
        out[k] = v
    return out
