"""The robot side, in NumPy only (no JAX, Flax or MuJoCo at import): the policy-file reader
(`NumpyPolicy`), the policy service (`server`), the safety layer (`safety`) and the real-robot
conventions (`robot`, `ur3`).

    from daddpg_jax.deploy import NumpyPolicy
    policy = NumpyPolicy.load("policy.npz")

The exporter, which reads orbax checkpoints with JAX, is `daddpg_jax.running.export`.
"""

from daddpg_jax.deploy.policy import FORMAT_VERSION, NumpyPolicy, PolicyFormatError

__all__ = ["FORMAT_VERSION", "NumpyPolicy", "PolicyFormatError"]
