"""Multi-device training: one mesh over the devices, data parallel over envs and batch.

With n_dev > 1 devices (several GPUs, ``XLA_FLAGS=--xla_force_host_platform_device_count`` on a
CPU, or the devices of several processes joined by daddpg_jax/running/distributed.py) the
trainer wraps the body of every cycle in ``jax.shard_map`` over a 1-d mesh with
axis ``AXIS``:

- each device steps ``num_envs / n_dev`` envs (the C engine's ``pure_callback`` runs per shard);
- the replay buffer's episode (capacity) axis is sharded: each device writes its own episodes
  into its own ring; the ring index and size stay replicated scalars (every device inserts the
  same number of episodes per cycle; the state holds the global values, each device uses
  value / n_dev locally);
- each device samples ``batch_size / n_dev`` transitions from its shard; gradients are averaged
  with ``lax.pmean`` before the Optax update, so parameters and optimizer states stay replicated
  and one update equals the unsharded update on the concatenated global batch (tested to 1e-5);
- normalizer statistics of the new transitions are merged across devices (psum of counts and
  Chan's formula), metrics are ``pmean``-ed, and each device draws its own randomness from
  ``fold_in(key, axis_index)``.

n_dev == 1: the state lives on a mesh of one device (the same shardings, one shard each) and
the cycle runs without shard_map, which on one device changes the rounding of the last bits
(daddpg_jax/algo/train.py).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

AXIS = "dev"
"""Name of the device axis of the training mesh."""


def shard_map(f, mesh: Mesh, in_specs, out_specs, check_vma: bool = True):
    """``jax.shard_map`` (jax >= 0.7), falling back to ``jax.experimental.shard_map``."""
    if hasattr(jax, "shard_map"):
        return jax.shard_map(f, mesh=mesh, in_specs=in_specs, out_specs=out_specs,
                             check_vma=check_vma)
    # lazy: only old jax (< 0.7) has it here
    from jax.experimental.shard_map import shard_map as _sm  # pragma: no cover (old jax)

    return _sm(f, mesh=mesh, in_specs=in_specs, out_specs=out_specs, check_rep=check_vma)


def resolve_num_devices(requested: int = 0, devices: Sequence | None = None) -> int:
    """Number of devices to use: ``requested`` (0 = all devices: ``jax.devices()``, which spans
    every process of a multi-process job, where all of them must be used)."""
    avail = len(devices) if devices is not None else jax.device_count()
    n = avail if not requested else int(requested)
    if n < 1 or n > avail:
        raise ValueError(f"num_devices={requested} but {avail} device(s) are available")
    if devices is None and jax.process_count() > 1 and n != avail:
        raise ValueError(f"num_devices={requested}: a job of {jax.process_count()} processes "
                         f"trains on all its {avail} devices (num_devices=0 or {avail})")
    return n


def make_mesh(n_dev: int, devices: Sequence | None = None) -> Mesh:
    """A 1-d mesh (axis AXIS) over the first n_dev devices (default: ``jax.devices()``, those
    of every process, ordered by process)."""
    devs = list(devices if devices is not None else jax.devices())[:n_dev]
    return Mesh(np.asarray(devs), (AXIS,))


def check_divisible(num_envs: int, batch_size: int, n_dev: int) -> None:
    """num_envs and batch_size must split evenly over the devices."""
    bad = [f"{name}={v}" for name, v in (("num_envs", num_envs), ("batch_size", batch_size))
           if v % n_dev]
    if bad:
        raise ValueError(
            f"{' and '.join(bad)} not divisible by the {n_dev} devices in use: every device "
            f"runs num_envs/{n_dev} envs and samples batch_size/{n_dev} transitions. Pick "
            f"multiples of {n_dev}, or set num_devices (e.g. --set num_devices=1).")


def sharded_capacity(capacity: int, n_dev: int) -> int:
    """Capacity in episodes rounded up to a multiple of n_dev (unchanged for n_dev == 1)."""
    return int(math.ceil(capacity / n_dev) * n_dev)


def _is_spec(x) -> bool:
    return isinstance(x, P)


def train_state_specs(abstract_state):
    """PartitionSpecs of a TrainState: replay storage sharded on its episode axis, all else
    replicated."""
    rep = jax.tree.map(lambda _: P(), abstract_state)
    buf_data = jax.tree.map(lambda _: P(AXIS), abstract_state.buffer.data)
    return rep.replace(buffer=rep.buffer.replace(data=buf_data))


def named_shardings(mesh: Mesh, specs):
    return jax.tree.map(lambda s: NamedSharding(mesh, s), specs, is_leaf=_is_spec)


def on_mesh(tree) -> bool:
    """True when some array of ``tree`` is laid out on a mesh (a NamedSharding, as the trainer's
    state is on any number of devices)."""
    return any(isinstance(getattr(x, "sharding", None), NamedSharding)
               for x in jax.tree.leaves(tree))
