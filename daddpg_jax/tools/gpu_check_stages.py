"""The stages of the GPU check (daddpg_jax/tools/gpu_check.py), each run in its own child
process: MJX env throughput (``env``), the compiled ``train_epoch`` (``train_epoch``) and
learning towards the target success (``learn_<task>``). Every measurement is appended at once to
the stage's records file, which the parent process merges into the report.
"""

from __future__ import annotations

import importlib.metadata
import json
import os
import statistics
import time
import traceback
from types import SimpleNamespace

import jax
import jax.numpy as jnp

import mjx_envs
from daddpg_jax.algo import acting
from daddpg_jax.algo.config import build_config, current_device
from daddpg_jax.algo.train import make_train_fns
from daddpg_jax.analysis.benchmark import memory
from daddpg_jax.running.levels import reaches
from daddpg_jax.running.runner import RunOptions, check_physics_backend, train

SMOKE_TRAIN = dict(hidden=(32, 32), n_batches=4, batch_size=32, n_test_episodes=8, physics="c")
"""tiny trainer settings of --smoke (as tests/conftest.py's TINY)"""
SMOKE_EPISODE = 10
"""episode length of the envs in --smoke"""
VERSIONS = ("jax", "jaxlib", "flax", "optax", "chex", "orbax-checkpoint", "numpy", "mujoco",
            "mujoco-mjx")


class Recorder:
    """Appends JSON lines to the stage's records file (each flushed to disk at once)."""

    def __init__(self, path: str):
        self.path = path

    def __call__(self, kind: str, **fields) -> None:
        with open(self.path, "a") as f:
            f.write(json.dumps(dict(kind=kind, **fields), default=_jsonable) + "\n")
            f.flush()
            os.fsync(f.fileno())

    def row(self, key: str, row: dict) -> None:
        self("row", key=key, **row)


def _jsonable(x):
    try:
        return float(x)
    except (TypeError, ValueError):
        return str(x)


def _version(pkg: str) -> str | None:
    try:
        return importlib.metadata.version(pkg)
    except importlib.metadata.PackageNotFoundError:
        return None


def device_record() -> dict:
    devs = jax.devices()
    out = {"device_kind": devs[0].device_kind, "device_count": len(devs),
           "backend": jax.default_backend(),
           "platform_version": getattr(devs[0].client, "platform_version", None)}
    out.update({p: _version(p) for p in VERSIONS})
    return out


def _one_line(e: BaseException, width: int = 300) -> str:
    lines = str(e).strip().splitlines()
    text = f"{type(e).__name__}: {lines[0]}" if lines else type(e).__name__
    return text if len(text) <= width else text[:width - 3] + "..."


def run(args, process_start: float, min_stage_s: float) -> int:
    """Runs the stage args._child, appending its records to args._records; the exit code.
    process_start: about when the process started (before JAX was imported); min_stage_s: a
    point or epoch with less time than this left before args._deadline is not started
    (`gpu_check.MIN_STAGE_S`)."""
    rec = Recorder(args._records)
    try:
        rec("device", **device_record())
        stage = args._child
        if stage == "env":
            stage_env(args, rec, min_stage_s)
        elif stage == "train_epoch":
            stage_train(args, rec)
        else:
            stage_learn(args, rec, stage.removeprefix("learn_"), process_start, min_stage_s)
        rec("done")
        return 0
    except Exception as e:  # noqa: BLE001 (recorded in the report; the next stage goes on)
        traceback.print_exc()
        rec("error", error=_one_line(e), traceback=traceback.format_exc(limit=8))
        return 1


def _env_overrides(args) -> dict:
    return {"episode_length": SMOKE_EPISODE} if args.smoke else {}


def _accel_device() -> str:
    dev = current_device()
    return "gpu" if dev == "cpu" else dev


def stage_env(args, rec: Recorder, min_stage_s: float) -> None:
    """Stage 1: every (size, task) point; a failed point is recorded and the next one runs."""
    points = [(n, t) for n in args.env_sizes for t in args.env_tasks]
    plan = {f"{t}/{n}": dict(task=t, physics=args.env_physics, num_envs=n) for n, t in points}
    rec("plan", rows=plan)
    envs = {}
    for n, task in points:
        key, base = f"{task}/{n}", plan[f"{task}/{n}"]
        if time.time() > args._deadline - min_stage_s:
            rec.row(key, dict(base, skipped="stage time cap"))
            continue
        try:
            check_physics_backend(args.env_physics, n)
            if task not in envs:
                envs[task] = mjx_envs.make(task, physics=args.env_physics,
                                           **_env_overrides(args))
            env_point(envs[task], n, args, lambda row, key=key, base=base:
                      rec.row(key, dict(base, **row)))
        except Exception as e:  # noqa: BLE001 (e.g. device out of memory: the next point)
            traceback.print_exc()
            rec.row(key, dict(base, error=_one_line(e)))


def env_point(env, n: int, args, emit) -> None:
    """Compile time, first call and steady-state steps/s of a scan of the vmapped env step."""
    T = int(args.env_steps)
    k_reset, k_act = jax.random.split(jax.random.PRNGKey(args.seed))
    t0 = time.perf_counter()
    states = jax.jit(jax.vmap(env.reset))(jax.random.split(k_reset, n))
    actions = jax.random.uniform(k_act, (T, n, env.action_size), jnp.float32, -1, 1)
    jax.block_until_ready((states, actions))
    reset_s = time.perf_counter() - t0

    def run(s, xs):
        _, ok = acting.unroll(env, s, lambda s, a: a, xs=xs,
                              record=lambda s, a, s2: s2.metrics["physics_ok"].min())
        return ok.min()

    t0 = time.perf_counter()
    compiled = jax.jit(run).lower(states, actions).compile()
    row = {"steps": T, "compile_s": time.perf_counter() - t0, "reset_first_call_s": reset_s}
    emit(dict(row, note="compiled; timing"))
    t0 = time.perf_counter()
    jax.block_until_ready(compiled(states, actions))
    row["first_call_s"] = time.perf_counter() - t0
    times = []
    while len(times) < args.repeats and (not times or time.time() + times[-1] < args._deadline):
        t0 = time.perf_counter()
        ok = jax.block_until_ready(compiled(states, actions))
        times.append(time.perf_counter() - t0)
    call = statistics.median(times)
    row.update(call_s=call, timed_calls=len(times), env_steps_per_s=n * T / call,
               physics_steps_per_s=n * T * env.config.n_substeps / call,
               n_substeps=env.config.n_substeps, physics_ok=float(ok))
    row.update(_memory())
    emit(row)
    print(f"[env] {env.task_name} {env.physics} {n} envs: {row['env_steps_per_s']:,.0f} env "
          f"steps/s, compile {row['compile_s']:.1f} s", flush=True)


def _memory() -> dict:
    m = memory()
    return {k: m.get(k) for k in ("device_peak_mb", "host_peak_rss_mb")}


def train_config(args, task: str, num_envs: int | None, **extra):
    """The stage's TrainConfig: the accelerator preset (--smoke: the CPU preset, tiny)."""
    if args.smoke:
        T = SMOKE_EPISODE
        return build_config(task, num_envs, device="cpu", episode_length=T,
                            **{**SMOKE_TRAIN, "buffer_size": 20 * T * (num_envs or 2), **extra})
    return build_config(task, num_envs, device=_accel_device(), **extra)


def stage_train(args, rec: Recorder) -> None:
    """Stage 2: compile, first epoch, timed epochs, then the rollout share if time is left."""
    cfg = train_config(args, args.train_task, args.train_envs, n_cycles=args.train_cycles,
                       seed=args.seed)
    check_physics_backend(cfg.physics, cfg.num_envs)
    env = mjx_envs.make(cfg.task, physics=cfg.physics, **_env_overrides(args))
    T = env.episode_length
    row = dict(task=cfg.task, physics=env.physics, num_envs=cfg.num_envs,
               batch_size=cfg.batch_size, n_batches=cfg.n_batches, n_cycles=cfg.n_cycles,
               hidden=list(cfg.hidden), buffer_size=cfg.buffer_size)
    key = f"{cfg.task}/{cfg.num_envs}"
    rec("plan", rows={key: row})
    fns = make_train_fns(env, cfg)
    state = jax.block_until_ready(fns.init())
    t0 = time.perf_counter()
    epoch = fns.train_epoch.lower(state).compile()
    row.update(compile_s=time.perf_counter() - t0, num_devices=fns.num_devices, note="compiled")
    rec.row(key, row)
    t0 = time.perf_counter()
    state, m = jax.block_until_ready(epoch(state))
    row.update(first_epoch_s=time.perf_counter() - t0, note="first epoch done")
    rec.row(key, row)
    walls = []
    while len(walls) < args.repeats and time.time() + row["first_epoch_s"] < args._deadline:
        t0 = time.perf_counter()
        state, m = jax.block_until_ready(epoch(state))
        walls.append(time.perf_counter() - t0)
        wall = statistics.median(walls)
        row.update(epoch_s=wall, cycle_s=wall / cfg.n_cycles, timed_epochs=len(walls),
                   env_steps_per_s=cfg.n_cycles * cfg.num_envs * T / wall,
                   updates_per_s=cfg.n_cycles * cfg.n_batches / wall,
                   finite=not bool(jax.numpy.any(m["nonfinite"])), note="")
        row.update(_memory())
        rec.row(key, row)
    if not walls:
        row.update(note="no time left for a timed epoch")
        rec.row(key, row)
        return
    if time.time() + 2 * row["first_epoch_s"] < args._deadline:
        row.update(_rollout_time(fns, state, cfg.num_envs))
        row["rollout_share"] = row["rollout_s_per_cycle"] / row["cycle_s"]
        rec.row(key, row)
    print(f"[train_epoch] {cfg.task} {env.physics} {cfg.num_envs} envs: "
          f"{row['env_steps_per_s']:,.0f} env steps/s, {row['updates_per_s']:,.1f} updates/s, "
          f"compile {row['compile_s']:.1f} s", flush=True)


def _rollout_time(fns, state, n: int) -> dict:
    """The exploration rollout of one cycle alone (its own program): first call, median of 3."""
    key = jax.random.PRNGKey(1)
    t0 = time.perf_counter()
    jax.block_until_ready(fns.rollout(state, key, n, True))
    first = time.perf_counter() - t0
    times = []
    for i in range(3):
        t0 = time.perf_counter()
        jax.block_until_ready(fns.rollout(state, jax.random.fold_in(key, i), n, True))
        times.append(time.perf_counter() - t0)
    return {"rollout_first_call_s": first, "rollout_s_per_cycle": statistics.median(times)}


class _Stop(Exception):
    pass


def stage_learn(args, rec: Recorder, task: str, process_start: float,
                min_stage_s: float) -> None:
    """Stage 3 for one task: runner.train until the target or the stage's deadline; a record
    after every epoch (curve, time and env steps to the target, best success)."""
    t_process = process_start
    extra = dict(n_epochs=1, n_cycles=2) if args.smoke else {}
    cfg = train_config(args, task, args.learn_envs, keep_checkpoints=1, seed=args.seed, **extra)
    row = dict(task=task, physics=cfg.physics, num_envs=cfg.num_envs, batch_size=cfg.batch_size,
               n_batches=cfg.n_batches, n_cycles=cfg.n_cycles, n_epochs=cfg.n_epochs,
               epoch_env_steps=cfg.n_cycles * cfg.num_envs * (SMOKE_EPISODE if args.smoke else 50),
               n_test_episodes=cfg.n_test_episodes, epochs=0, reached=False, curve=[],
               note="compiling / first epoch")
    rec("plan", rows={task: row})
    rec.row(task, row)

    def on_epoch(r):
        s, steps, wall = float(r["test_success_rate"]), int(r["env_steps"]), float(r["wall_time"])
        row["curve"].append([steps, round(wall, 2), s])
        row.update(epochs=int(r["epoch"]), env_steps=steps, train_wall_s=wall,
                   process_s=time.time() - t_process, note="")
        if row.get("best_success") is None or s > row["best_success"]:
            row.update(best_success=s, env_steps_at_best=steps, wall_at_best_s=wall)
        if reaches(s, args.target) and not row["reached"]:
            row.update(reached=True, wall_to_target_s=wall, env_steps_to_target=steps,
                       process_to_target_s=time.time() - t_process)
        rec.row(task, row)
        print(f"[learn {task}] epoch {r['epoch']}: {steps:,} env steps, {wall:.1f} s, test "
              f"success {s:.2f}", flush=True)
        if row["reached"]:
            raise _Stop
        if time.time() >= args._deadline - min_stage_s:
            row["note"] = "stopped at the stage's time cap"
            raise _Stop

    try:
        train(cfg, RunOptions(os.path.join(args.out, "runs", task),
                              env_overrides=_env_overrides(args),
                              hooks=SimpleNamespace(epoch=on_epoch), force=True,
                              command="gpu_check",
                              time_budget_s=max(1.0, args._deadline - time.time())))
    except _Stop:
        pass
    except Exception as e:
        row.update(error=_one_line(e), note="")
        rec.row(task, row)
        raise
    if not row["reached"] and row["epochs"] >= cfg.n_epochs:
        row["note"] = "epoch budget done"
    rec.row(task, row)

