"""The wrapped envs' golden record: a short rollout (6 envs, 10 steps of fixed random actions,
C engine) of configs with physics randomization, perturbations, action history and grasped
starts on. A refactor of the env's wrappers must reproduce it (tests/test_wrappers.py; the
golden epoch covers the default configs only); a deliberate change records it again:

    python -m tests.golden_wrapped          # rewrites tests/data/golden_wrapped.npz
"""
import os

import jax
import numpy as np

import mjx_envs

RECORD = os.path.join(os.path.dirname(__file__), "data", "golden_wrapped.npz")
CASES = {
    "reach": ("reach", dict(base_offset=0.01, base_yaw=3.0, finger_force=0.2, action_scale=0.1,
                            obs_noise=0.01, obs_period=2, latency=1, action_history=2)),
    "pickup": ("pickup", dict(obs_noise=0.015, obs_dropout=0.1, obs_bias=0.005, latency=1,
                              base_offset=0.005, base_yaw=2.0, finger_force=0.2,
                              action_scale=0.1, object_mass=0.3, object_size=0.002,
                              object_friction=0.3, table_height=0.005,
                              grasp_start_fraction=0.5, n_grasp_states=8, action_history=1,
                              goal_rest_fraction=0.2)),
    "push": ("push", dict(object_size=0.005, table_height=0.005, obs_dropout=0.3, obs_bias=0.01,
                          latency=2, object_friction=0.3)),
}
KEPT = ("obs", "reward", "done", "data.qpos", "data.mocap_pos", "metrics['success']",
        "metrics['goal_distance']", "info['physics']['params']", "info['action_history']",
        "info['perturb']['held']")
"""the state leaves compared (paths start with one of these, after the state's name)"""


def rollout(case: str) -> dict:
    """name -> array of the kept leaves of the first state (``s0.``) and the steps
    (``traj.``), plus ``fields``: every leaf path of the state."""
    task, overrides = CASES[case]
    env = mjx_envs.make(task, physics="c", **overrides)
    keys = jax.random.split(jax.random.PRNGKey(3), 6)
    actions = jax.random.uniform(jax.random.PRNGKey(4), (10, 6, 8), minval=-1.3, maxval=1.3)

    def run(keys):
        s = jax.vmap(env.reset)(keys)
        return s, jax.lax.scan(lambda s, a: (jax.vmap(env.step)(s, a),) * 2, s, actions)[1]

    s0, traj = jax.jit(run)(keys)
    out, fields = {}, []
    for name, tree in (("s0", s0), ("traj", traj)):
        for path, leaf in jax.tree_util.tree_leaves_with_path(tree):
            p = jax.tree_util.keystr(path)[1:]
            fields.append(f"{name}.{p}")
            if p.startswith(KEPT):
                out[f"{name}.{p}"] = np.asarray(leaf)
    out["fields"] = np.asarray(sorted(fields))
    return out


if __name__ == "__main__":
    record = {f"{case}/{k}": v for case in CASES for k, v in rollout(case).items()}
    np.savez_compressed(RECORD, **record)
