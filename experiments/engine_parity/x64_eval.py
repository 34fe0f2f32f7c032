"""A trained run's checkpoint on MJX in float64 (JAX's x64 mode), against the same episodes'
float32 MJX and C figures: whether an MJX -> C gap comes from MJX's float32 arithmetic or from
the engines' algorithms. Probe only: the MJX backend's inputs are cast to the model's float
type in this process.

    JAX_ENABLE_X64=1 python experiments/engine_parity/x64_eval.py RUN --episodes 96 --seed 9090

Run it alone on a CPU (MJX in float64 is slower than in float32)."""

from __future__ import annotations

import argparse
import os
import sys

import jax
import jax.numpy as jnp
import numpy as np

from daddpg_jax.analysis import evaluation
from mjx_envs.physics import backends


def _cast_backend() -> None:
    """MjxBackend.init/step take their inputs in the model's float type (float64 under x64)."""
    init, step = backends.MjxBackend.init, backends.MjxBackend.step

    def f64(x):
        return jnp.asarray(x, jnp.float64) if x is not None else x

    def init64(self, qpos, qvel, mocap_pos, params=None):
        return init(self, f64(qpos), f64(qvel), f64(mocap_pos), params)

    def step64(self, data, ctrl, mocap_pos, params=None):
        return step(self, data, f64(ctrl), f64(mocap_pos), params)

    backends.MjxBackend.init, backends.MjxBackend.step = init64, step64


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("run")
    p.add_argument("--episodes", type=int, default=96)
    p.add_argument("--seed", type=int, default=9090)
    p.add_argument("--step", type=int, default=None)
    a = p.parse_args(argv)
    if not jax.config.jax_enable_x64:
        p.error("set JAX_ENABLE_X64=1")
    _cast_backend()
    pol = evaluation.load_policy(a.run, step=a.step, best=a.step is None, physics="mjx")
    s, traj = evaluation.evaluate(pol, a.episodes, a.seed)
    print(f"mjx float64: success {float(np.mean(traj['success'])):.3f} over {a.episodes} "
          f"episodes (seed {a.seed}); physics faults {float(np.mean(traj['physics_fault'])):.3f}",
          flush=True)
    np.save(os.path.join(os.path.dirname(a.run.rstrip('/')) or '.', 'x64_success.npy'),
            np.asarray(traj["success"]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
