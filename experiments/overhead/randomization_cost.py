"""What physics randomization costs on an engine: env steps/s of whole episodes (vmapped reset
+ 50 control steps of random actions, one jitted program) with every randomization field off
and on, at a few batch sizes. The reset is timed too: that is where the C engine rewrites its
per-env models.

    python experiments/overhead/randomization_cost.py --task pickup --physics c --sizes 64 256 1024

(the script is a thin caller of this module).
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import time

import jax
import jax.numpy as jnp

import mjx_envs
from daddpg_jax.algo import acting

RANDOMIZED = dict(object_mass=0.3, object_size=0.003, object_friction=0.3, table_height=0.01,
                  base_offset=0.005, base_yaw=2.0, finger_force=0.3, action_scale=0.2)
"""every field on (the reach task drops the object fields)"""


def episode_rate(task: str, physics: str, n: int, over: dict, repeats: int) -> dict:
    env = mjx_envs.make(task, physics=physics, **over)
    T = env.episode_length

    @jax.jit
    def episode(key):
        k_reset, k_act = jax.random.split(key)
        xs = jax.random.uniform(k_act, (T, n, env.action_size), jnp.float32, -1.0, 1.0)
        _, tr = acting.rollout(env, lambda s, a: a, jax.random.split(k_reset, n), xs=xs)
        return tr.metrics["physics_ok"].mean()

    t0 = time.perf_counter()
    jax.block_until_ready(episode(jax.random.PRNGKey(0)))
    first = time.perf_counter() - t0
    times = []
    for i in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(episode(jax.random.PRNGKey(i + 1)))
        times.append(time.perf_counter() - t0)
    med = statistics.median(times)
    return dict(num_envs=n, first_call_s=round(first, 2), episode_s=round(med, 4),
                env_steps_per_s=round(n * T / med, 1))


def main(argv=None):
    p = argparse.ArgumentParser(prog="randomization_cost.py",
                                description=__doc__.split("\n\n")[0])
    p.add_argument("--task", default="pickup", choices=mjx_envs.registry.TASKS)
    p.add_argument("--physics", default="c", choices=mjx_envs.settings.ENGINES)
    p.add_argument("--sizes", type=int, nargs="+", default=[64, 256])
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--out", default=None, help="write the rows as JSON here")
    args = p.parse_args(argv)
    fields = mjx_envs.registry.default_config(args.task).__dataclass_fields__
    on = {k: v for k, v in RANDOMIZED.items() if k in fields}
    rows = []
    for n in args.sizes:
        for label, over in (("off", {}), ("on", on)):
            r = dict(task=args.task, physics=args.physics, randomization=label,
                     **episode_rate(args.task, args.physics, n, over, args.repeats))
            rows.append(r)
            print(json.dumps(r), flush=True)
    if args.out:
        meta = dict(machine=f"{platform.machine()}, {jax.device_count()} x "
                    f"{jax.default_backend()}", fields=on)
        with open(args.out, "w") as f:
            json.dump(dict(meta, rows=rows), f, indent=2)


if __name__ == "__main__":
    raise SystemExit(main())
