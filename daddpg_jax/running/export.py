"""Export a trained run to one NumPy ``.npz`` that the robot side loads without JAX.

JAX side of the deployment path (``daddpg_jax/deploy/`` is the NumPy side)::

    from daddpg_jax.running.export import export_run
    export_run("runs/reach", "policy.npz")            # latest checkpoint
    export_run("runs/reach", "policy.npz", step=2)    # a given checkpoint
    export_run("runs/reach", "policy.npz", best=True) # the best test success

File contents (``daddpg_jax.deploy.FORMAT_VERSION`` 1; every array float32, no pickled
objects):

==========================  ==============================================================
key                         value
==========================  ==============================================================
``actor/W{i}``              [A, in_i, out_i] weights of layer i, agent axis first
``actor/b{i}``              [A, out_i] biases of layer i
``obs_norm/mean``, ``std``  [2, obs_size] per-arm observation statistics (std already floored
                            at ``norm_eps``, computed by the trainer's own function)
``goal_norm/mean``, ``std`` [2, 3] per-arm goal statistics
``meta``                    JSON text: format version, task, algo, layer sizes, activations,
                            normalizer clip values and eps, action scaling, observation layout,
                            the env settings of the run (every field of the task's
                            ``mjx_envs.settings`` config, and ``dt``), and where the weights
                            came from
==========================  ==============================================================

``A`` is the variant's ``num_agents`` (``daddpg_jax.variants``): 2 (one actor per arm;
arm 0 = left, each with a 4-d action slot) or 1 (one actor, 8-d output). The actor is
``tanh(W_L relu(... relu(W_0 x + b_0) ...) + b_L)`` on the normalized inputs of
``daddpg_jax.algo.networks.actor_inputs``. The reader (``daddpg_jax.deploy.NumpyPolicy``)
fills env settings an older export lacks from ``mjx_envs.registry.default_config(task)``.
"""

from __future__ import annotations

import json
import os
from typing import Any

import jax
import numpy as np

from daddpg_jax import variants
from daddpg_jax.algo import actors
from daddpg_jax.algo import normalizer as norm
from daddpg_jax.deploy.policy import FORMAT_VERSION, write_policy_file
from daddpg_jax.running.checkpoint_policy import RunPolicyError, load_run_policy
from mjx_envs import limit_rules, schema
from mjx_envs import observation as obs_lib
from mjx_envs.settings import PHYSICS_VERSION


class ExportError(RuntimeError):
    """A run cannot be exported (no checkpoint, missing config, ...); the message says why."""


def _plain(v):
    """A settings value as plain JSON (NumPy scalars and arrays too)."""
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    if isinstance(v, (np.generic, np.ndarray)):
        return _plain(v.tolist())
    return v


def _env_settings(env) -> dict:
    """The env settings of the run, plain JSON: every field of the task's settings
    (``env.config``, a ``mjx_envs.settings`` config, as the run used it) and the control period
    ``dt``."""
    out = {k: _plain(v) for k, v in schema.to_dict(env.config).items()}
    out["dt"] = float(env.dt)
    return out


def policy_arrays(state, cfg, env, source: dict | None = None) -> dict[str, Any]:
    """The export's arrays and metadata from a TrainState (no file written).

    ``state``: a ``daddpg_jax.algo.train.TrainState`` (only ``agent.actor`` and the normalizers are
    read) or an ``algo.actors.ActorParams`` (the actors and normalizers a checkpoint's loader
    restores); ``cfg``: its TrainConfig; ``env``: the env it was trained on.
    """
    variant = variants.get(cfg.algo)
    state = actors.of_state(state)
    actor = jax.device_get(state.actor)
    layers = actor["params"]
    names = sorted(layers, key=lambda n: int(n.split("_")[-1]))  # Dense_0, Dense_1, ...
    arrays: dict[str, Any] = {}
    sizes = []
    for i, name in enumerate(names):
        w = np.asarray(layers[name]["kernel"], np.float32)
        b = np.asarray(layers[name]["bias"], np.float32)
        arrays[f"actor/W{i}"] = w
        arrays[f"actor/b{i}"] = b
        sizes.append([int(w.shape[1]), int(w.shape[2])])
    n_agents = int(arrays["actor/W0"].shape[0])
    if n_agents != variant.num_agents:
        raise ExportError(f"the actors have {n_agents} agents; algo {cfg.algo} has "
                          f"{variant.num_agents}")
    for key, ns in (("obs_norm", state.obs_norm), ("goal_norm", state.goal_norm)):
        arrays[f"{key}/mean"] = np.asarray(jax.device_get(ns.mean), np.float32)
        arrays[f"{key}/std"] = np.asarray(jax.device_get(norm.std(ns, cfg.norm_eps)), np.float32)
        arrays[f"{key}/count"] = np.asarray(jax.device_get(ns.count), np.float32)
    settings = _env_settings(env)
    k_hist = int(getattr(env, "action_history", 0))
    meta = dict(
        format_version=FORMAT_VERSION,
        task=str(cfg.task),
        algo=str(cfg.algo),
        num_agents=n_agents,
        num_arms=int(env.num_arms),
        obs_size=int(env.obs_size),
        goal_size=int(env.goal_size),
        action_size=int(env.action_size),
        arm_action=int(variants.ARM_ACTION),
        actor_input_dim=int(variant.input_dims(env.obs_size, env.goal_size)[0]),
        layer_sizes=sizes,
        hidden_activation="relu",
        output_activation="tanh",
        normalizer=dict(clip_obs=float(cfg.clip_obs), norm_clip=float(cfg.norm_clip),
                        norm_eps=float(cfg.norm_eps)),
        action=dict(low=-1.0, high=1.0, max_delta=settings["max_delta"],
                    finger_stroke=settings["finger_stroke"],
                    lock_fingers=settings["lock_fingers"],
                    locked_opening=settings["locked_opening"],
                    units="per arm [dx, dy, dz] in max_delta metres per control step, finger "
                          "in [-1, 1] -> opening (a+1)/2*finger_stroke metres"),
        obs_layout={k: [int(a), int(b)] for k, (a, b) in obs_lib.obs_layout(k_hist).items()},
        obs_fields=[[n, int(k)] for n, k in obs_lib.obs_fields(k_hist)],
        arms=["left", "right"],
        env=settings,
        source=dict(source or {}),
        # the physics it was trained on and acts with (the env's: a run's record when exported
        # from a run directory)
        physics_version=int(settings.get("physics_version", PHYSICS_VERSION)),
    )
    if settings.get("robot_limits"):  # trained under a robot limits file (daddpg-train --limits)
        meta["trained_limits"] = limit_rules.describe(settings["robot_limits"])
    arrays["meta"] = np.array(json.dumps(meta, sort_keys=True))
    return arrays


def write_npz(arrays: dict[str, Any], out) -> str:
    """Writes the export atomically (temporary file + rename). Returns the path."""
    out = os.fspath(out)
    if not out.endswith(".npz"):
        raise ExportError(f"output file must end in .npz, got {out!r}")
    return write_policy_file(out, lambda f: np.savez(f, **arrays))


FORMATS = ("npz", "onnx")
"""export formats: the NumPy .npz (above), or one ONNX graph (daddpg_jax/deploy/onnx_policy.py)"""


def export_format(out) -> str:
    """The format of an output path: 'onnx' for a .onnx name, else 'npz'."""
    return "onnx" if os.fspath(out).lower().endswith(".onnx") else "npz"


def write_export(arrays: dict[str, Any], out) -> str:
    """Writes the export in the format of its name (`export_format`). Returns the path."""
    if export_format(out) == "onnx":
        from daddpg_jax.deploy.onnx_policy import write_onnx  # optional extra [onnx]

        return write_onnx(arrays, out)
    return write_npz(arrays, out)


def export_state(state, cfg, env, out, source: dict | None = None) -> str:
    """Exports a TrainState (or ActorParams) held in memory (tests, notebooks) to ``out`` (.npz
    or .onnx)."""
    return write_export(policy_arrays(state, cfg, env, source), out)


def export_run(run_dir, out, step: int | None = None, best: bool = False) -> str:
    """Exports checkpoint ``step`` (default: latest) of the run in ``run_dir`` to ``out``;
    best=True exports the run's best checkpoint (``checkpoints_best/``, the epoch with the best
    test success) instead. The run is loaded by ``checkpoint_policy.load_run_policy`` (the env of
    the standard task: training-only options such as grasped-state starts off, the policy's
    deployment; the actors and normalizers alone restored, no training step built).

    Raises ExportError with a clear message when the run has no config or no checkpoint.
    """
    try:   # the newest readable checkpoint (a warning for each unreadable newer one)
        pol = load_run_policy(run_dir, step, best=best)
    except RunPolicyError as e:   # one line naming the run, file or checkpoint
        raise ExportError(str(e)) from None
    cfg, payload = pol.cfg, pol.payload
    source = dict(run_dir=os.path.abspath(pol.run_dir), checkpoint_step=int(pol.step),
                  best=bool(best), git_revision=payload.get("git_revision"),
                  env_overrides=payload.get("env_overrides"), train_config=cfg.to_dict(),
                  physics_version=int(pol.env.config.physics_version))
    return export_state(pol.params, cfg, pol.env, out, source)
