"""The exported policy in plain NumPy (no JAX, Flax or MuJoCo): what a robot computer runs.

    from daddpg_jax.deploy import NumpyPolicy
    policy = NumpyPolicy.load("policy.npz")
    action = policy.act(observation, desired_goal)        # [2, 25], [2, 3] -> [8] float32
    per_arm = policy.act_per_arm(observation, desired_goal)  # -> [2, 4] (row 0 = left arm)

Both accept extra leading (batch) axes: [..., 2, obs], [..., 2, 3] -> [..., 8] / [..., 2, 4].
The computation repeats the trainer's ``TrainFns.act`` step for step in float32 (clip, normalize,
build each variant's actor inputs, MLP, tanh), and matches it to 1e-5 on CPU.

What depends on the algorithm variant (number of agents, what each actor sees, the size of
each agent's action slot) is read from the variant's row in ``daddpg_jax.algo.variants``; the
task's settings from ``mjx_envs.settings``. Both are standard library only, so this module
imports NumPy and the standard library only: keep it that way (tests/test_deploy.py checks it
in a subprocess where importing jax or mujoco fails).
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from typing import Any

import numpy as np

from daddpg_jax.algo import variants
from mjx_envs import schema
from mjx_envs import settings as task_settings_lib

FORMAT_VERSION = 1
"""Version of the ``.npz`` layout, written by ``daddpg_jax.running.export`` and read here."""


class PolicyFormatError(ValueError):
    """The .npz file is not a policy export this code can read."""


def task_settings(task: str, saved: Mapping[str, Any] | None = None):
    """The task's settings (a ``mjx_envs.settings.TaskConfig``) holding the values in ``saved``
    (a policy export's ``env``; keys that are not fields, such as ``dt``, are ignored). Fields
    that ``saved`` lacks (an export written before the field existed) keep the values of
    ``mjx_envs.settings.default_config(task)``. Raises ValueError for an unknown task or a value
    outside its field's range."""
    return task_settings_lib.saved_config(task, saved or {})


def env_settings(task: str, saved: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """A policy export's env settings, JSON-ready: every field of ``task_settings(task,
    saved)``, ``dt`` (the control period, ``timestep * n_substeps`` unless saved) and any other
    key ``saved`` holds. A task that ``mjx_envs.settings`` does not know keeps ``saved`` as is."""
    out = dict(saved or {})
    if task in task_settings_lib.TASK_SETTINGS:
        out.update(schema.to_dict(task_settings(task, saved)))
    if "dt" not in out and "timestep" in out and "n_substeps" in out:
        out["dt"] = float(out["timestep"]) * int(out["n_substeps"])
    return out


def _check_input(name: str, x, tail: tuple[int, ...]) -> np.ndarray:
    try:
        arr = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{name} must be an array of numbers: {e}") from None
    if arr.ndim < len(tail) or tuple(arr.shape[arr.ndim - len(tail):]) != tail:
        want = "[..., " + ", ".join(map(str, tail)) + "]"
        raise ValueError(f"{name} must have shape {want}, got {list(arr.shape)}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains NaN or infinite values")
    return arr.astype(np.float32)


class NumpyPolicy:
    """Deterministic actors of an exported run (format: ``daddpg_jax/running/export.py``)."""

    def __init__(self, weights: list[np.ndarray], biases: list[np.ndarray],
                 obs_mean, obs_std, goal_mean, goal_std, meta: dict[str, Any]):
        self.meta = meta
        self.algo = str(meta["algo"])
        if self.algo not in variants.VARIANTS:
            raise PolicyFormatError(f"unknown algo {self.algo!r} in policy file; this code "
                                    f"reads {', '.join(variants.ALGOS)}")
        self.variant = variants.get(self.algo)
        self.task = str(meta["task"])
        self.obs_size = int(meta["obs_size"])
        self.goal_size = int(meta["goal_size"])
        self.num_arms = int(meta.get("num_arms", 2))
        self.action_size = int(meta["action_size"])
        self.arm_action = int(meta["arm_action"])
        n = meta["normalizer"]
        self.clip_obs = np.float32(n["clip_obs"])
        self.norm_clip = np.float32(n["norm_clip"])
        self.weights = [np.ascontiguousarray(w, np.float32) for w in weights]
        self.biases = [np.ascontiguousarray(b, np.float32) for b in biases]
        self.obs_mean = np.asarray(obs_mean, np.float32)
        self.obs_std = np.asarray(obs_std, np.float32)
        self.goal_mean = np.asarray(goal_mean, np.float32)
        self.goal_std = np.asarray(goal_std, np.float32)
        self.num_agents = int(self.weights[0].shape[0])
        try:
            self._env = env_settings(self.task, meta.get("env"))
        except ValueError as e:
            raise PolicyFormatError(f"env settings of the policy file: {e}") from None
        self._validate()

    # -- loading ------------------------------------------------------------------------------

    @classmethod
    def load(cls, path) -> NumpyPolicy:
        path = os.fspath(path)
        if not os.path.exists(path):
            raise FileNotFoundError(f"policy file {path!r} not found")
        try:
            with np.load(path, allow_pickle=False) as f:
                data = {k: f[k] for k in f.files}
        except (OSError, ValueError) as e:
            raise PolicyFormatError(f"{path!r} is not a readable .npz policy file: {e}") from None
        if "meta" not in data:
            raise PolicyFormatError(f"{path!r} has no 'meta' entry: not a policy export")
        meta = json.loads(str(data["meta"]))
        version = int(meta.get("format_version", -1))
        if version != FORMAT_VERSION:
            raise PolicyFormatError(f"{path!r} has format version {version}; this code reads "
                                    f"version {FORMAT_VERSION}")
        n_layers = len(meta["layer_sizes"])
        try:
            ws = [data[f"actor/W{i}"] for i in range(n_layers)]
            bs = [data[f"actor/b{i}"] for i in range(n_layers)]
            norm = [data[k] for k in ("obs_norm/mean", "obs_norm/std", "goal_norm/mean",
                                      "goal_norm/std")]
        except KeyError as e:
            raise PolicyFormatError(f"{path!r} misses array {e}") from None
        return cls(ws, bs, *norm, meta=meta)

    def _validate(self):
        v = self.variant
        if (self.num_arms, self.arm_action) != (variants.NUM_ARMS, variants.ARM_ACTION):
            raise PolicyFormatError(f"{self.num_arms} arms with {self.arm_action} action "
                                    f"entries each; this code drives {variants.NUM_ARMS} arms "
                                    f"with {variants.ARM_ACTION}")
        if self.action_size != self.num_arms * self.arm_action:
            raise PolicyFormatError(f"action size {self.action_size}, expected "
                                    f"{self.num_arms * self.arm_action}")
        if self.num_agents != v.num_agents:
            raise PolicyFormatError(f"{self.num_agents} agents for algo {self.algo} "
                                    f"(expected {v.num_agents})")
        a_in = v.input_dims(self.obs_size, self.goal_size)[0]
        if int(self.meta["actor_input_dim"]) != a_in:
            raise PolicyFormatError(f"actor input size {self.meta['actor_input_dim']}, expected "
                                    f"{a_in} for algo {self.algo}")
        prev = a_in
        for i, (w, b) in enumerate(zip(self.weights, self.biases, strict=True)):
            if w.ndim != 3 or w.shape[0] != self.num_agents or w.shape[1] != prev:
                raise PolicyFormatError(f"actor layer {i} weights have shape {w.shape}")
            if b.shape != (self.num_agents, w.shape[2]):
                raise PolicyFormatError(f"actor layer {i} biases have shape {b.shape}")
            prev = w.shape[2]
        if prev != v.agent_action_dim:
            raise PolicyFormatError(f"actor output size {prev}, expected {v.agent_action_dim}")
        for name, arr, size in (("obs", self.obs_mean, self.obs_size),
                                ("obs", self.obs_std, self.obs_size),
                                ("goal", self.goal_mean, self.goal_size),
                                ("goal", self.goal_std, self.goal_size)):
            if arr.shape != (self.num_arms, size):
                raise PolicyFormatError(f"{name} normalizer has shape {arr.shape}")
        if not all(np.all(np.isfinite(x)) for x in self.weights + self.biases):
            raise PolicyFormatError("actor weights contain NaN or infinite values")
        if np.any(self.obs_std <= 0) or np.any(self.goal_std <= 0):
            raise PolicyFormatError("normalizer std must be positive")

    # -- properties the robot side uses -------------------------------------------------------

    @property
    def env(self) -> dict[str, Any]:
        """Env settings of the run (dt, max_delta, workspace boxes, ...): the values saved with
        the policy, and ``mjx_envs.settings.default_config(task)``'s for fields the file lacks
        (see `env_settings`). A copy: changing it changes nothing in the policy."""
        return json.loads(json.dumps(self._env))

    @property
    def obs_layout(self) -> dict[str, tuple[int, int]]:
        return {k: (int(v[0]), int(v[1])) for k, v in self.meta["obs_layout"].items()}

    def info(self) -> dict[str, Any]:
        """A JSON-ready summary (what the policy service's GET /info returns)."""
        m = self.meta
        return dict(format_version=m["format_version"], task=self.task, algo=self.algo,
                    num_agents=self.num_agents, obs_size=self.obs_size, goal_size=self.goal_size,
                    action_size=self.action_size, obs_layout=m["obs_layout"],
                    obs_fields=m.get("obs_fields"), layer_sizes=m["layer_sizes"],
                    action=m["action"], env=self.env,
                    checkpoint_step=m.get("source", {}).get("checkpoint_step"))

    # -- inference ----------------------------------------------------------------------------

    def _normalize(self, x, mean, std):
        x = np.clip(x, -self.clip_obs, self.clip_obs)
        return np.clip((x - mean) / std, -self.norm_clip, self.norm_clip)

    def _actor_inputs(self, o, g):
        """o [B, 2, obs], g [B, 2, 3] (normalized) -> [A, B, in], as the variant's row says
        (``networks.actor_inputs``): 'both' = every agent sees the flattened (o_1, o_2, g_1,
        g_2); 'own' = agent i sees its arm's (o_i, g_i)."""
        if self.variant.actor_sees == variants.BOTH:
            b = o.shape[0]
            x = np.concatenate([o.reshape(b, -1), g.reshape(b, -1)], -1)
            return np.broadcast_to(x, (self.num_agents,) + x.shape)
        return np.moveaxis(np.concatenate([o, g], -1), -2, 0)

    def _forward(self, x):
        """x [A, B, in] -> [A, B, out]."""
        n = len(self.weights)
        for i, (w, b) in enumerate(zip(self.weights, self.biases, strict=True)):
            x = np.matmul(x, w) + b[:, None, :]
            x = np.maximum(x, np.float32(0.0)) if i < n - 1 else np.tanh(x)
        return x

    def act(self, observation, desired_goal) -> np.ndarray:
        """Joint action [..., 8] in [-1, 1] (arm 0's [dx, dy, dz, finger], then arm 1's)."""
        o = _check_input("observation", observation, (self.num_arms, self.obs_size))
        g = _check_input("desired_goal", desired_goal, (self.num_arms, self.goal_size))
        lead_o, lead_g = o.shape[:-2], g.shape[:-2]
        if lead_o != lead_g:
            raise ValueError(f"observation and desired_goal have different leading axes: "
                             f"{list(lead_o)} vs {list(lead_g)}")
        o = o.reshape((-1,) + o.shape[-2:])
        g = g.reshape((-1,) + g.shape[-2:])
        o = self._normalize(o, self.obs_mean, self.obs_std)
        g = self._normalize(g, self.goal_mean, self.goal_std)
        pi = self._forward(self._actor_inputs(o, g))
        a = np.concatenate(list(pi), -1)  # the agents' action slots in agent order
        return a.reshape(lead_o + (self.action_size,)).astype(np.float32)

    def act_per_arm(self, observation, desired_goal) -> np.ndarray:
        """Actions [..., 2, 4]: row i is arm i's [dx, dy, dz, finger]."""
        a = self.act(observation, desired_goal)
        return a.reshape(a.shape[:-1] + (self.num_arms, self.arm_action))

    __call__ = act
