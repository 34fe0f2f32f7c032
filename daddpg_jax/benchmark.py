"""Throughput measurements used by ``experiments/benchmark.py`` (figures in docs/BENCHMARKS.md)."""

from __future__ import annotations

import platform
import time

import jax
import jax.numpy as jnp
import numpy as np


def machine_description() -> str:
    devs = jax.devices()
    kind = devs[0].device_kind if devs else "?"
    import os
    return (f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPU cores, "
            f"jax backend {jax.default_backend()} ({len(devs)} x {kind})")


def env_throughput(env, num_envs: int, n_steps: int | None = None, repeats: int = 3,
                   seed: int = 0) -> dict:
    """Env-only speed: one jitted program = vmapped reset + ``lax.scan`` over control steps.

    Returns control steps/s and physics steps/s (= control * n_substeps), summed over envs, and
    the compile time (first call minus a timed call).
    """
    T = int(n_steps or env.episode_length)

    def run(key):
        k_reset, k_act = jax.random.split(key)
        state = jax.vmap(env.reset)(jax.random.split(k_reset, num_envs))
        actions = jax.random.uniform(k_act, (T, num_envs, env.action_size), jnp.float32, -1, 1)

        def body(s, a):
            s = jax.vmap(env.step)(s, a)
            return s, (s.metrics["success"].mean(), s.metrics["physics_ok"].min())

        state, (succ, ok) = jax.lax.scan(body, state, actions)
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
