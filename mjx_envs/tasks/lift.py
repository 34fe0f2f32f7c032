"""What the two lift tasks, pickup and pot, share and that stays JAX-free: their scripted
controller, each module's ``scripted_policy``.

The registry imports the task modules without JAX, so the controller here is a handle that
imports `mjx_envs.tasks.scripted` (JAX) at its first call.
"""

from __future__ import annotations


def scripted_policy(obs, max_delta: float = 0.05):
    """The two-arm grasp (`mjx_envs.tasks.scripted.grasp_policy`): both grippers approach their
    object points (bar necks, pot handles) open, descend, close, and carry the object
    together."""
    from mjx_envs.tasks import scripted  # lazy: the registry reads the task modules without JAX

    return scripted.grasp_policy(obs, max_delta)
