"""A trained policy's MJX actions replayed open loop on the C engine: for the episodes MJX
solves closed loop, does the C engine, given the very same actions from the same reset state,
also solve them? If it does, the closed-loop gap comes from the policy reacting to slightly
different states; if it does not, the two engines turn the same actions into different
outcomes. Per episode: the first control step at which the object centres part by 5 mm, and
where each engine's object ends.

    python experiments/engine_parity/open_loop.py RUN --episodes 128 --seed 9090 [--step N] \
        [--json OUT.json]

Run it alone on a CPU (MJX in chunks of 32)."""

from __future__ import annotations

import argparse
import json
import sys
from collections import Counter

import jax
import numpy as np

from daddpg_jax.algo import acting
from daddpg_jax.analysis import evaluation
from mjx_envs import observation as obs_lib

PART = 0.005
"""metres between the engines' object centres that count as parted"""


def _play(policy, keys, actions=None):
    """(success [N], object centres [T, N, 3], actions [T, N, A]) closed loop, or open loop
    with ``actions`` [T, N, A]."""
    env, act = policy.env, policy.act

    def record(s, a, s2):
        sens = env.backend.sensordata(s2.data)
        obj = obs_lib.read_object_sensors(jax.numpy, env.sensors, sens, sens.shape[:-1])["pos"]
        return dict(obj=obj, a=a, success=s2.metrics["success"])

    if actions is None:
        def actors(s, _):
            return act(policy.params, s.obs["observation"], s.obs["desired_goal"])
        fn = jax.jit(lambda k: acting.rollout(env, actors, k, record=record)[1])
        tr = fn(keys)
    else:
        fn = jax.jit(lambda k, xs: acting.rollout(env, lambda s, x: x, k, xs=xs,
                                                  record=record)[1])
        tr = fn(keys, actions)
    tr = jax.device_get(tr)
    return np.asarray(tr["success"][-1]) > 0.5, np.asarray(tr["obj"]), np.asarray(tr["a"])


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("run")
    p.add_argument("--episodes", type=int, default=128)
    p.add_argument("--seed", type=int, default=9090)
    p.add_argument("--step", type=int, default=None)
    p.add_argument("--chunk", type=int, default=32)
    p.add_argument("--json", default=None)
    a = p.parse_args(argv)
    pol = {e: evaluation.load_policy(a.run, step=a.step, best=a.step is None, physics=e)
           for e in ("mjx", "c")}
    keys = np.asarray(acting.episode_keys(jax.random.PRNGKey(a.seed), a.episodes))
    rows = []
    for lo in range(0, a.episodes, a.chunk):
        k = keys[lo:lo + a.chunk]
        m_ok, m_obj, m_act = _play(pol["mjx"], k)
        c_ok, c_obj, _ = _play(pol["c"], k)                       # C closed loop
        o_ok, o_obj, _ = _play(pol["c"], k, actions=m_act)        # MJX's actions on C
        dist = np.linalg.norm(o_obj - m_obj, axis=-1)             # [T, n]
        for i in range(len(k)):
            parted = np.flatnonzero(dist[:, i] > PART)
            rows.append(dict(episode=lo + i, mjx=bool(m_ok[i]), c=bool(c_ok[i]),
                             c_open_loop=bool(o_ok[i]),
                             parted_at=int(parted[0]) if len(parted) else None,
                             final_gap_mm=round(1e3 * float(dist[-1, i]), 1)))
        print(f"episodes {lo}-{lo + len(k) - 1} done", flush=True)
    groups = {"solved by MJX only": [r for r in rows if r["mjx"] and not r["c"]],
              "solved by both": [r for r in rows if r["mjx"] and r["c"]],
              "solved by C only": [r for r in rows if r["c"] and not r["mjx"]]}
    table = {}
    for name, g in groups.items():
        parted = [r["parted_at"] for r in g if r["parted_at"] is not None]
        table[name] = dict(n=len(g), c_open_loop_solves=sum(r["c_open_loop"] for r in g),
                           parted=len(parted),
                           parted_at_median=float(np.median(parted)) if parted else None,
                           parted_at=dict(Counter(parted)))
    print(json.dumps(table, indent=1))
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(dict(run=a.run, step=a.step, episodes=a.episodes, seed=a.seed,
                           part_m=PART, table=table, rows=rows), fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
