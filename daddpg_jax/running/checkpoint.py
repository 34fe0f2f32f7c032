"""Orbax checkpoints of a TrainState in RUN_DIR/checkpoints/{step}, plus RUN_DIR/config.json.

Each checkpoint holds the item `state` (agents, targets, optimizer states, normalizers, key,
counters) and, when asked, the item `buffer` (the replay buffer: large). Restoring without a
saved buffer keeps the template's buffer (e.g. a fresh empty one from `init`): training then
resumes with the same networks and normalizers but refills the replay from scratch, so it is
not bit-identical to an uninterrupted run. With the buffer saved, 1 epoch + resume + 1 epoch
equals a 2-epoch run. Orbax writes to a temporary directory and renames it when complete, so a
killed run resumes from the last complete checkpoint. The last `keep` checkpoints are kept.
Demonstration episodes (TrainConfig.n_demos) are never saved: `init` plays the same ones again
from the seed, and restoring keeps the template's.
"""

from __future__ import annotations

import dataclasses
import datetime
import importlib.metadata
import json
import os
import subprocess

import jax
import jax.numpy as jnp
import numpy as np
import orbax.checkpoint as ocp
from flax import serialization


def checkpoint_dir(run_dir) -> str:
    return os.path.join(os.path.abspath(os.fspath(run_dir)), "checkpoints")


def _manager(run_dir, keep: int | None = None) -> ocp.CheckpointManager:
    opts = ocp.CheckpointManagerOptions(max_to_keep=keep, create=True)
    return ocp.CheckpointManager(checkpoint_dir(run_dir), options=opts)


def _split(state):
    tree = serialization.to_state_dict(state)
    buffer = tree.pop("buffer")
    # demonstrations are not saved: init replays them from the seed (same episodes)
    tree.pop("demos", None)
    return tree, buffer


def save(run_dir, state, step: int, save_buffer: bool = False, keep: int = 3) -> str:
    """Saves `state` as checkpoint `step` (blocking until written). Returns its directory."""
    tree, buffer = _split(state)
    items = {"state": ocp.args.StandardSave(tree)}
    if save_buffer:
        items["buffer"] = ocp.args.StandardSave(buffer)
    with _manager(run_dir, keep) as mngr:
        mngr.save(int(step), args=ocp.args.Composite(**items), force=True)
        mngr.wait_until_finished()
    return os.path.join(checkpoint_dir(run_dir), str(int(step)))


class RunDirError(FileNotFoundError):
    """A directory is not a run directory, or lacks the asked-for checkpoint."""


def check_run_dir(run_dir, step: int | None = None) -> list:
    """Checks that ``run_dir`` is a training run with checkpoint ``step`` (default: any) and
    returns its checkpoint steps; raises :class:`RunDirError` with a message for the user."""
    run_dir = os.fspath(run_dir)
    if not os.path.isdir(run_dir):
        raise RunDirError(f"run directory {run_dir!r} does not exist")
    if not os.path.exists(os.path.join(run_dir, "config.json")):
        raise RunDirError(f"{run_dir!r} has no config.json: not a training run directory "
                          "(written by experiments/run.py)")
    steps = all_steps(run_dir)
    if not steps:
        raise RunDirError(f"run {run_dir!r} has no checkpoint under {checkpoint_dir(run_dir)} "
                          "(a run writes one at the end of each epoch)")
    if step is not None and int(step) not in steps:
        raise RunDirError(f"run {run_dir!r} has no checkpoint {step}; available: {steps}")
    return steps


def all_steps(run_dir):
    if not os.path.isdir(checkpoint_dir(run_dir)):
        return []
    with _manager(run_dir) as mngr:
        return sorted(mngr.all_steps())


def latest_step(run_dir) -> int | None:
    steps = all_steps(run_dir)
    return steps[-1] if steps else None


def has_buffer(run_dir, step: int) -> bool:
    return os.path.isdir(os.path.join(checkpoint_dir(run_dir), str(int(step)), "buffer"))


def restore(run_dir, template, step: int | None = None, restore_buffer: bool | None = None):
    """Restores checkpoint `step` (default: latest) into the structure of `template` (a TrainState
    from `init`, which fixes shapes, dtypes and shardings). restore_buffer=None restores the
    buffer when the checkpoint has one; otherwise the template's buffer is kept.
    Returns (state, step)."""
    if step is None:
        step = latest_step(run_dir)
        if step is None:
            raise FileNotFoundError(f"no checkpoint under {checkpoint_dir(run_dir)}")
    step = int(step)
    if restore_buffer is None:
        restore_buffer = has_buffer(run_dir, step)
    elif restore_buffer and not has_buffer(run_dir, step):
        raise FileNotFoundError(f"checkpoint {step} was saved without the replay buffer")
    tree, buffer = _split(template)
    abstract = lambda t: jax.tree.map(ocp.utils.to_shape_dtype_struct, t)
    items = {"state": ocp.args.StandardRestore(abstract(tree))}
    if restore_buffer:
        items["buffer"] = ocp.args.StandardRestore(abstract(buffer))
    with _manager(run_dir) as mngr:
        out = mngr.restore(step, args=ocp.args.Composite(**items))
    full = dict(out["state"])
    if restore_buffer:
        full["buffer"] = out["buffer"]
    # Orbax returns arrays committed to a device while `init` returns uncommitted ones; jit keys
    # its cache on that, so re-place the restored arrays uncommitted: no recompile on resume.
    # A multi-device template (sharded replay, see daddpg_jax/algo/sharding.py) is committed to its
    # NamedShardings already and orbax restores into exactly those: keep them as they are.
    from daddpg_jax.algo.sharding import is_multi_device

    if not is_multi_device(template):
        full = jax.tree.map(lambda x: jnp.asarray(np.asarray(x)), full)
    if not restore_buffer:
        full["buffer"] = buffer
    full["demos"] = serialization.to_state_dict(template)["demos"]
    return serialization.from_state_dict(template, full), step


def _version(pkg: str) -> str | None:
    try:
        return importlib.metadata.version(pkg)
    except importlib.metadata.PackageNotFoundError:
        return None


def _git_revision(path) -> str | None:
    try:
        out = subprocess.run(["git", "rev-parse", "HEAD"], cwd=path, capture_output=True,
                             text=True, timeout=5)
        return out.stdout.strip() or None
    except (OSError, subprocess.SubprocessError):
        return None


def save_config(run_dir, cfg, **extra) -> str:
    """Writes RUN_DIR/config.json: the TrainConfig, package versions, device, git revision and
    any `extra` JSON-serializable fields (e.g. env overrides)."""
    os.makedirs(run_dir, exist_ok=True)
    cfg_dict = cfg.to_dict() if hasattr(cfg, "to_dict") else dataclasses.asdict(cfg)
    repo = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    payload = dict(
        config=cfg_dict,
        versions={p: _version(p) for p in ("jax", "jaxlib", "flax", "optax", "orbax-checkpoint",
                                           "numpy", "mujoco", "mujoco-mjx", "daddpg-jax")},
        device=str(jax.devices()[0].device_kind), backend=jax.default_backend(),
        git_revision=_git_revision(repo),
        created=datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        **extra,
    )
    path = os.path.join(run_dir, "config.json")
    with open(path, "w") as f:
        json.dump(payload, f, indent=2, sort_keys=True)
    return path


def load_config(run_dir):
    """Reads RUN_DIR/config.json back into a TrainConfig (and returns the whole payload)."""
    from daddpg_jax.algo.config import TrainConfig
    with open(os.path.join(run_dir, "config.json")) as f:
        payload = json.load(f)
    return TrainConfig.from_dict(payload["config"]), payload
