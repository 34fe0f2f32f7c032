"""A tiny pure-JAX dual-arm "point reach" env that follows docs/ENV_CONTRACT.md.

Each gripper is a point moved by `max_delta * action[:3]` per step and clipped to a box; the
finger entry is ignored. Each arm has its own random goal; the arms' goal regions overlap in the
middle so the points can come close. Used by the trainer tests so they run in seconds.
With `fault_goal_x` set it reports `metrics["physics_ok"]` like the MuJoCo envs: 0 from step 1
on in the episodes whose left-arm goal x is above that value (physics-fault tests).

Observation per arm (25, Fetch layout with the object terms zero): gripper pos (3), object pos
(3), object rel pos (3), finger pos (2), object rot (3), object velp (3), object velr (3),
gripper velp (3), finger vel (2).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
from flax import struct


@struct.dataclass
class State:
    data: dict
    obs: dict
    reward: jax.Array
    done: jax.Array
    metrics: dict
    info: dict


@dataclasses.dataclass(frozen=True)
class ToyConfig:
    episode_length: int = 50
    max_delta: float = 0.05
    threshold: float = 0.05
    clearance: float = 0.05
    contact_penalty: float = 0.05
    dt: float = 0.04
    box_lo: tuple = (-0.3, -0.3, 0.0)
    box_hi: tuple = (0.3, 0.3, 0.3)
    start: tuple = ((-0.1, 0.0, 0.15), (0.1, 0.0, 0.15))
    goal_range: float = 0.15
    fault_goal_x: float | None = None   # set: report metrics["physics_ok"], 0 from step 1 on
    #                                     in episodes whose left goal x is above it


class ToyReach:
    num_arms = 2
    action_size = 8
    obs_size = 25
    goal_size = 3
    info_keys = ("arm_contact_penalty",)

    def __init__(self, **overrides):
        self.config = dataclasses.replace(ToyConfig(), **overrides)
        self.episode_length = self.config.episode_length
        self.reward_range = (-1.0 - self.config.contact_penalty, 0.0)
        self._lo = jnp.asarray(self.config.box_lo, jnp.float32)
        self._hi = jnp.asarray(self.config.box_hi, jnp.float32)
        self._start = jnp.asarray(self.config.start, jnp.float32)

    # --- contract functions -------------------------------------------------------------
    def compute_reward(self, achieved_goal, desired_goal, info):
        d = jnp.linalg.norm(achieved_goal - desired_goal, axis=-1)
        r = -(d >= self.config.threshold).astype(jnp.float32)
        for k in self.info_keys:
            r = r + info[k]
        return r

    def success(self, achieved_goal, desired_goal):
        d = jnp.linalg.norm(achieved_goal - desired_goal, axis=-1)
        return jnp.all(d < self.config.threshold, axis=-1).astype(jnp.float32)

    def reset(self, key) -> State:
        c = self.config
        goal = self._start + jax.random.uniform(key, (2, 3), jnp.float32, -c.goal_range,
                                                c.goal_range)
        goal = jnp.clip(goal, self._lo, self._hi)
        pos = self._start
        return self._make_state(pos, jnp.zeros_like(pos), goal, jnp.int32(0))

    def step(self, state: State, action) -> State:
        c = self.config
        a = jnp.clip(action.astype(jnp.float32), -1.0, 1.0).reshape(2, 4)
        pos0 = state.data["pos"]
        pos = jnp.clip(pos0 + c.max_delta * a[:, :3], self._lo, self._hi)
        return self._make_state(pos, (pos - pos0) / c.dt, state.data["goal"],
                                state.info["step"] + 1)

    # --- helpers ------------------------------------------------------------------------
    def _make_state(self, pos, vel, goal, step) -> State:
        c = self.config

        def z(n):
            return jnp.zeros((2, n), jnp.float32)

        obs = jnp.concatenate([pos, z(3), z(3), z(2), z(3), z(3), z(3), vel, z(2)], -1)
        gap = jnp.linalg.norm(pos[0] - pos[1])
        contact = (gap < c.clearance).astype(jnp.float32)
        info = {"arm_contact_penalty": -c.contact_penalty * contact * jnp.ones(2, jnp.float32),
                "step": step.astype(jnp.int32)}
        reward = self.compute_reward(pos, goal, info)
        d = jnp.linalg.norm(pos - goal, axis=-1)
        metrics = {"success": self.success(pos, goal), "arm_contact": contact,
                   "goal_reward": jnp.mean(-(d >= c.threshold).astype(jnp.float32)),
                   "arm_contact_penalty": jnp.mean(info["arm_contact_penalty"])}
        if c.fault_goal_x is not None:   # a stand-in for an engine that froze (C backend)
            fault = (step >= 1) & (goal[0, 0] > c.fault_goal_x)
            metrics["physics_ok"] = 1.0 - fault.astype(jnp.float32)
        return State(data={"pos": pos, "goal": goal},
                     obs={"observation": obs, "achieved_goal": pos, "desired_goal": goal},
                     reward=reward,
                     done=(step >= c.episode_length).astype(jnp.float32),
                     metrics=metrics, info=info)


def make(**overrides) -> ToyReach:
    return ToyReach(**overrides)
