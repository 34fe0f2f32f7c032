"""The robot side, in NumPy only (no JAX, Flax or MuJoCo at import): the policy-file reader
(`NumpyPolicy`), the policy service (`server`), the safety layer (`safety`), the real-robot
conventions (`robot`, `ur3`), the arms interface with UR arms through ur_rtde (`arms`, imported
lazily) and their simulated controllers (`ursim`), and frame calibration (`calibrate`).

    from daddpg_jax.deploy import NumpyPolicy
    policy = NumpyPolicy.load("policy.npz")

The exporter, which reads orbax checkpoints with JAX, is `daddpg_jax.running.export`.
"""

from daddpg_jax.deploy.policy import FORMAT_VERSION, NumpyPolicy, PolicyFormatError

__all__ = ["FORMAT_VERSION", "NumpyPolicy", "PolicyFormatError"]
