"""Throughput measurements used by ``experiments/benchmark.py`` (figures in docs/BENCHMARKS.md).

- :func:`env_throughput`: env-only physics and control steps/s (``acting.rollout``: vmapped
  reset + ``lax.scan``).
- :func:`train_throughput`: the compiled ``train_epoch`` of ``make_train_fns`` with a task preset:
  env steps/s, updates/s, compile time, time of the rollout part of a cycle, wall and CPU time.
- :func:`contacts_per_step`: active contacts per physics state over scripted episodes (C engine:
  ``data.ncon`` after ``mj_forward`` on a plain ``MjData``; MJX: contacts with
  ``dist < includemargin`` in ``mjx.Data``).
- :func:`memory`: peak host RSS and device memory statistics (when the backend reports them).
"""

from __future__ import annotations

import collections
import glob
import os
import re
import resource
import tempfile
import time

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

import mjx_envs
from daddpg_jax.algo import acting
from daddpg_jax.algo.train import make_train_fns
from daddpg_jax.running.host import host_info
from mjx_envs.tasks import scripted


def machine_description() -> str:
    devs = jax.devices()
    kind = devs[0].device_kind if devs else "?"
    host = host_info()
    return (f"{host['cpu']}, {host['cores']} CPU cores, "
            f"jax backend {jax.default_backend()} ({len(devs)} x {kind})")


def load() -> float:
    """1-minute load average of the host (the machine may be shared)."""
    try:
        return float(os.getloadavg()[0])
    except OSError:  # pragma: no cover
        return float("nan")


def memory() -> dict:
    """Peak host RSS of this process so far (MB) and device memory stats of device 0."""
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # KB on Linux
    out = {"host_peak_rss_mb": rss / 1024.0}
    try:
        stats = jax.devices()[0].memory_stats()
    except Exception:  # noqa: BLE001 (backends without stats)
        stats = None
    if stats:
        out["device_peak_mb"] = stats.get("peak_bytes_in_use", 0) / 2**20
        out["device_in_use_mb"] = stats.get("bytes_in_use", 0) / 2**20
        if "bytes_limit" in stats:
            out["device_limit_mb"] = stats["bytes_limit"] / 2**20
    else:
        out["device_peak_mb"] = None
    return out


def env_throughput(env, num_envs: int, n_steps: int | None = None, repeats: int = 3,
                   seed: int = 0) -> dict:
    """Env-only speed: one jitted program = ``acting.rollout`` of random actions (vmapped reset +
    ``lax.scan`` over control steps).

    Returns control steps/s and physics steps/s (= control * n_substeps), summed over envs, and
    the compile time (first call minus a timed call).
    """
    T = int(n_steps or env.episode_length)

    def record(s, a, s2):
        return s2.metrics["success"].mean(), s2.metrics["physics_ok"].min()

    def run(key):
        k_reset, k_act = jax.random.split(key)
        actions = jax.random.uniform(k_act, (T, num_envs, env.action_size), jnp.float32, -1, 1)
        _, (succ, ok) = acting.rollout(env, lambda s, a: a, jax.random.split(k_reset, num_envs),
                                       xs=actions, record=record)
        return succ.mean(), ok.min()

    fn = jax.jit(run)
    key = jax.random.PRNGKey(seed)
    t0 = time.perf_counter()
    jax.block_until_ready(fn(key))
    first = time.perf_counter() - t0
    times = []
    for i in range(repeats):
        t0 = time.perf_counter()
        _, ok = jax.block_until_ready(fn(jax.random.fold_in(key, i + 1)))
        times.append(time.perf_counter() - t0)
    best = float(np.median(times))
    control = num_envs * T / best
    return {
        "task": env.task_name, "physics": env.physics, "num_envs": num_envs, "steps": T,
        "control_steps_per_s": control,
        "physics_steps_per_s": control * env.config.n_substeps,
        "compile_s": max(first - best, 0.0),
        "seconds_per_run": best,
        "physics_ok": float(ok),
    }


def train_throughput(env, cfg, repeats: int = 2, rollout_split: bool = True) -> dict:
    """Speed of the compiled ``train_epoch`` for ``cfg`` (typically a task preset with a reduced
    ``n_cycles``).

    compile_s: ``train_epoch.lower(state).compile()``. One untimed warm-up epoch, then
    ``repeats`` timed epochs (median): env steps/s = n_cycles * num_envs * T / epoch time,
    updates/s = n_cycles * n_batches / epoch time; cpu_s_per_cycle is the process CPU time
    (user + system, all threads), less sensitive than wall time to other load on a shared
    machine. rollout_split: also time the exploration rollout of one cycle alone (its own
    compiled program) to split a cycle into rollout and the rest (insert, normalizer, updates).
    """
    T = int(env.episode_length)
    fns = make_train_fns(env, cfg)
    state = fns.init()
    jax.block_until_ready(state)
    t0 = time.perf_counter()
    epoch = fns.train_epoch.lower(state).compile()
    compile_s = time.perf_counter() - t0
    state, m = epoch(state)
    jax.block_until_ready(state)
    walls, cpus = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        state, m = epoch(state)
        jax.block_until_ready((state, m))
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    wall = float(np.median(walls))
    cpu = float(np.median(cpus))
    out = {
        "task": env.task_name, "physics": env.physics, "num_envs": cfg.num_envs,
        "num_devices": fns.num_devices, "batch_size": cfg.batch_size, "n_batches": cfg.n_batches,
        "n_cycles": cfg.n_cycles, "buffer_episodes": fns.capacity, "hidden": list(cfg.hidden),
        "compile_s": compile_s, "epoch_s": wall, "cycle_s": wall / cfg.n_cycles,
        "cpu_s_per_cycle": cpu / cfg.n_cycles,
        "env_steps_per_s": cfg.n_cycles * cfg.num_envs * T / wall,
        "updates_per_s": cfg.n_cycles * cfg.n_batches / wall,
        "finite": not bool(np.any(np.asarray(m["nonfinite"]))),
    }
    if rollout_split:
        key = jax.random.PRNGKey(1)
        jax.block_until_ready(fns.rollout(state, key, cfg.num_envs, True))
        times = []
        for i in range(max(repeats, 3)):
            t0 = time.perf_counter()
            k = jax.random.fold_in(key, i)
            jax.block_until_ready(fns.rollout(state, k, cfg.num_envs, True))
            times.append(time.perf_counter() - t0)
        out["rollout_s_per_cycle"] = float(np.median(times))
        out["rollout_share"] = out["rollout_s_per_cycle"] / out["cycle_s"]
    out.update(memory())
    return out


def op_profile(env, cfg, logdir: str, top: int = 12) -> dict:
    """XLA op time of one ``train_epoch`` (after a warm-up epoch) from a ``jax.profiler`` trace.

    Aggregates the trace's executor events by op name (numeric suffixes dropped; e.g. all
    ``ynn_fusion.N`` matmul fusions together), so the share of matmuls, optimizer element-wise
    fusions, gathers, copies and the physics ``pure_callback`` can be read off. Returns
    {"total_ms", "wall_s", "ops": [[name, ms, share, count], ...]} (``top`` largest).
    """
    # lazy: a private JAX module (its place may change between versions), for --profile only
    from jax._src.lib import _profile_data

    fns = make_train_fns(env, cfg)
    state = fns.init()
    state, _ = fns.train_epoch(state)
    jax.block_until_ready(state)
    jax.profiler.start_trace(logdir)
    t0 = time.perf_counter()
    state, m = fns.train_epoch(state)
    jax.block_until_ready((state, m))
    wall = time.perf_counter() - t0
    jax.profiler.stop_trace()
    path = sorted(glob.glob(os.path.join(logdir, "**", "*.xplane.pb"), recursive=True))[-1]
    agg, cnt = collections.Counter(), collections.Counter()
    for plane in _profile_data.ProfileData.from_file(path).planes:
        for line in plane.lines:
            if "Eigen" not in line.name and "XLA" not in line.name:
                continue
            for ev in line.events:
                name = ev.name
                if name.startswith(("ThunkExecutor", "end: ")) or "Await" in name:
                    continue
                name = re.sub(r"\.\d+$", "", name)
                agg[name] += ev.duration_ns
                cnt[name] += 1
    total = float(sum(agg.values()))
    ops = [[k, v / 1e6, v / total if total else 0.0, cnt[k]] for k, v in agg.most_common(top)]
    return {"total_ms": total / 1e6, "wall_s": wall, "ops": ops}


def _has_contacts(mj_model) -> bool:
    if mj_model.npair > 0:
        return True
    return bool(np.any((mj_model.geom_contype != 0) | (mj_model.geom_conaffinity != 0)))


def contacts_per_step(env, num_envs: int = 8, steps: int | None = None, seed: int = 0,
                      policy: str = "scripted") -> dict:
    """Active contacts per control step over ``num_envs`` episodes.

    policy: 'scripted' (the task's controller in ``mjx_envs.tasks.scripted``, which grasps and
    pushes, so contacts happen) or 'random' (uniform actions). C engine: the episode is rolled
    out with the env, then each (env, step) state is put into a plain ``MjData`` (qpos, qvel,
    mocap) and ``mj_forward`` gives ``data.ncon`` (contacts within the pair margins). MJX: the
    count of ``contact.dist < contact.includemargin`` in the ``mjx.Data`` after each step, in
    the compiled rollout. Scenes without collision pairs report 0 without rolling out.
    """
    T = int(steps or env.episode_length)
    base = {"task": env.task_name, "physics": env.physics, "num_envs": num_envs, "steps": T,
            "policy": policy}
    if not _has_contacts(env.mj_model):
        return dict(base, contacts_mean=0.0, contacts_max=0, contact_pairs=0)
    if policy == "scripted":
        act_fn = scripted.get_policy(env.task_name)
    else:
        act_fn = None
    is_mjx = env.physics == "mjx"

    def count(data):
        if not is_mjx:
            return jnp.zeros((), jnp.int32)
        impl = getattr(data, "_impl", data)
        c = impl.contact
        return jnp.sum(c.dist < c.includemargin).astype(jnp.int32)

    def policy_fn(s, k):
        if act_fn is None:
            return jax.random.uniform(k, (num_envs, env.action_size), jnp.float32, -1, 1)
        return act_fn(s.obs, env.config.max_delta)

    def record(s, a, s2):
        b = env.backend
        return b.qpos(s2.data), s2.data.qvel, b.mocap_pos(s2.data), jax.vmap(count)(s2.data)

    def run(key):
        k_reset, k_act = jax.random.split(key)
        _, out = acting.rollout(env, policy_fn, jax.random.split(k_reset, num_envs),
                                xs=jax.random.split(k_act, T), record=record)
        return out

    qpos, qvel, mocap, ncon = jax.device_get(jax.jit(run)(jax.random.PRNGKey(seed)))
    if not is_mjx:
        m = env.mj_model
        d = mujoco.MjData(m)
        ncon = np.zeros(qpos.shape[:2], np.int32)
        for t in range(qpos.shape[0]):
            for i in range(qpos.shape[1]):
                mujoco.mj_resetData(m, d)
                d.qpos[:] = qpos[t, i]
                d.qvel[:] = qvel[t, i]
                d.mocap_pos[: mocap.shape[2]] = mocap[t, i]
                mujoco.mj_forward(m, d)
                ncon[t, i] = d.ncon
    ncon = np.asarray(ncon)
    return dict(base, contacts_mean=float(ncon.mean()), contacts_max=int(ncon.max()),
                contacts_mean_final=float(ncon[-1].mean()), contact_pairs=int(env.mj_model.npair))


# ------------------------------------------------------------ daddpg-benchmark's tables -------

def _table(hdr: str, log) -> None:
    log(hdr)
    log("-" * len(hdr))


def env_table(tasks, engines, sizes, env_over: dict, steps: int = 50, repeats: int = 3,
              contacts: str = "auto", contact_envs: int = 8, log=print):
    """Env-only throughput rows (`env_throughput`, every task x engine x size) and contact rows
    (`contacts_per_step`; contacts: auto = for scenes with contact pairs, on, off); `log`
    gets the table's lines."""
    env_rows, contact_rows = [], []
    log("\n[env] env-only throughput (random actions)")
    _table(f"{'task':8s} {'engine':6s} {'envs':>6s} {'control/s':>12s} {'physics/s':>12s} "
           f"{'compile s':>10s}", log)
    for task in tasks:
        for physics in engines:
            env = mjx_envs.make(task, physics=physics, **env_over)
            for n in sizes:
                r = env_throughput(env, n, n_steps=steps, repeats=repeats)
                r["load"] = load()
                env_rows.append(r)
                log(f"{task:8s} {physics:6s} {n:6d} {r['control_steps_per_s']:12,.0f} "
                    f"{r['physics_steps_per_s']:12,.0f} {r['compile_s']:10.1f}")
            if contacts == "on" or (contacts == "auto" and _has_contacts(env.mj_model)):
                c = contacts_per_step(env, num_envs=contact_envs)
                contact_rows.append(c)
                log(f"{task:8s} {physics:6s} contacts/step over {contact_envs} scripted "
                    f"episodes: mean {c['contacts_mean']:.2f}, max {c['contacts_max']}")
    return env_rows, contact_rows


def train_table(tasks, engines, sizes, env_over: dict, make_cfg, repeats: int = 2, log=print):
    """Training throughput rows (`train_throughput` of the compiled train_epoch, every task x
    engine x size; `make_cfg(env, task, physics, num_envs)` gives the TrainConfig); `log`
    gets the table's lines."""
    rows = []
    _table(f"{'task':8s} {'engine':6s} {'envs':>6s} {'dev':>3s} {'batch':>6s} {'upd/cyc':>7s} "
           f"{'env st/s':>10s} {'upd/s':>8s} {'compile s':>9s} {'rollout%':>8s} "
           f"{'cpu s/cyc':>9s} {'RSS MB':>8s} {'dev MB':>8s}", log)
    for task in tasks:
        for physics in engines:
            env = mjx_envs.make(task, physics=physics, **env_over)
            for n in sizes:
                r = train_throughput(env, make_cfg(env, task, physics, n), repeats=repeats)
                r["load"] = load()
                rows.append(r)
                dev_mb = r.get("device_peak_mb")
                dev = "-" if dev_mb is None else f"{dev_mb:8.0f}"
                log(f"{task:8s} {physics:6s} {n:6d} {r['num_devices']:3d} "
                    f"{r['batch_size']:6d} {r['n_batches']:7d} {r['env_steps_per_s']:10,.0f} "
                    f"{r['updates_per_s']:8.1f} {r['compile_s']:9.1f} "
                    f"{100 * r.get('rollout_share', float('nan')):7.0f}% "
                    f"{r['cpu_s_per_cycle']:9.2f} {r['host_peak_rss_mb']:8.0f} {dev:>8s}")
    return rows


def profile_table(task: str, physics: str, n: int, env_over: dict, make_cfg, log=print) -> dict:
    """`op_profile` of one epoch of `task` at n envs (trace in a new temporary directory), with
    its breakdown as lines to `log`."""
    env = mjx_envs.make(task, physics=physics, **env_over)
    cfg = make_cfg(env, task, physics, n)
    profile = op_profile(env, cfg, tempfile.mkdtemp(prefix="daddpg_prof_"))
    profile.update(task=task, physics=physics, num_envs=n)
    log(f"\n[profile] {task} {physics} {n} envs: one epoch of {cfg.n_cycles} cycles, "
        f"{profile['wall_s']:.2f} s wall, {profile['total_ms']:.0f} ms of XLA op time")
    for name, ms, share, count in profile["ops"]:
        log(f"  {name:32s} {ms:9.1f} ms {100 * share:5.1f}% {count:7d} calls")
    return profile
