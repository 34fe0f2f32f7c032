"""Episodes of a task's scripted controller (mjx_envs/tasks/scripted.py) or of all-zero actions,
rolled out at once with the env's engine, and their frames: what ``daddpg-scripted-demo``
prints and renders."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from daddpg_jax.algo import acting
from daddpg_jax.analysis.evaluation import write_frames
from mjx_envs.tasks import scripted

POLICIES = ("scripted", "zero")


def rollout(env, policy: str, episodes: int, seed: int = 0) -> dict:
    """`episodes` episodes (reset keys split from PRNGKey(seed)) of the task's scripted
    controller (policy "scripted") or all-zero actions ("zero": the arms hold still). Returns
    NumPy arrays over [time, episode, ...]: qpos, mocap, success, goal, achieved."""
    if policy == "zero":
        def act(obs, max_delta):
            return jnp.zeros(obs["observation"].shape[:-2] + (env.action_size,), jnp.float32)
    else:
        act = scripted.get_policy(env.task_name)

    def record(s, a, s2):
        return (env.backend.qpos(s2.data), env.backend.mocap_pos(s2.data),
                s2.metrics["success"], s2.obs["desired_goal"], s2.obs["achieved_goal"])

    @jax.jit
    def run(keys):
        return acting.rollout(env, lambda s, _: act(s.obs, env.config.max_delta), keys,
                              record=record)[1]

    keys = jax.random.split(jax.random.PRNGKey(seed), episodes)
    qpos, mocap, success, goal, achieved = jax.tree.map(np.asarray, run(keys))
    return dict(qpos=qpos, mocap=mocap, success=success, goal=goal, achieved=achieved)


def final_distance(traj: dict) -> np.ndarray:
    """[arms] goal distance at the last step, mean over the episodes, m."""
    return np.linalg.norm(traj["achieved"][-1] - traj["goal"][-1], axis=-1).mean(axis=0)


def write_video(renderer, traj: dict, path: str, fps: int) -> tuple[str, int]:
    """Episode 0 of `traj` drawn by `renderer` (mjx_envs.render.Renderer) into `path` (a GIF
    beside it without an mp4 writer); (path written, frames)."""
    q, goal, mocap = traj["qpos"], traj["goal"], traj["mocap"]
    frames = [renderer.frame(q[t, 0], goal[t, 0], mocap[t, 0]) for t in range(len(q))]
    return write_frames(path, frames, fps), len(frames)
