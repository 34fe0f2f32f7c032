"""MJX's Newton line search kept finite under an elliptic cone (physics version 4).

MJX evaluates a line-search point of an elliptic friction cone from the contact's expanded
quadratic: ``tsqr = uu + alpha * (2 * uv + alpha * vv)``, the squared tangential residual at step
``alpha`` (``mujoco/mjx/_src/solver.py``, ``_LSPoint.create``). It is ``|u + alpha v|^2 >= 0``, but
in float32 the sum can cancel to a small negative number; its square root is then NaN and,
although such a contact lies outside the cone's middle zone (weight 0), ``0 * NaN`` makes the
point's cost NaN. Every comparison with a NaN cost is false, so the line search never accepts
the step and the solver returns its starting point (the warm start) for all its iterations.
That is how MJX's physics faults in pick up start (docs/MJX_VS_C.md, "MJX physics faults"): a
finger lands on the bar, the warm start holds forces of the previous substep that no longer fit,
the bar is thrown (~40 m/s, ~480 rad/s within one control step) and the explicit gyroscopic
term of its next substeps blows up to a non-finite state. The same state in float64 MJX and
on the C engine stays bounded.

`install` wraps ``_LSPoint.create``: for a model with the custom numeric `NUMERIC` = 1 (the
scenes of physics version 4 that `mjx_envs.model.PHYSICS_V4` names) a contact whose ``tsqr``
at the point lies within float rounding of 0 or below is given ``uu = uv = vv = 0``, i.e.
``tsqr = 0``: its exact value to rounding, which MJX treats as it treats 0 (bottom zone when the
normal residual is negative, else no cost). Every other contact's inputs, and every point
without such a contact, are unchanged, so the solver computes exactly what it did wherever it
stayed finite. Other models (older physics versions, anything else in the process) run MJX's
own function."""

from __future__ import annotations

import jax.numpy as jnp

from mjx_envs.model import MJX_FINITE_LINESEARCH as NUMERIC

ROUNDING = 8.0
"""a ``tsqr`` at most this many float epsilons of its terms' size counts as 0"""


def cancelled(uu, uv, vv, alpha) -> jnp.ndarray:
    """Per contact: True where ``uu + alpha * (2 uv + alpha vv)`` (MJX's expression) is at or
    below float rounding of zero relative to ``uu + alpha^2 vv`` (negative included)."""
    tsqr = uu + alpha * (2 * uv + alpha * vv)
    eps = jnp.finfo(jnp.result_type(tsqr)).eps
    return tsqr <= ROUNDING * eps * (uu + alpha * alpha * vv)


def _finite_point(create):
    # lazy: see `install`
    from mujoco.mjx._src import collision_driver
    from mujoco.mjx._src.types import ConeType

    def create_finite(m, d, ctx, alpha, jv, quad, quad_gauss, uu, v0, uv, vv):
        if (collision_driver._numeric(m, NUMERIC) == 1   # static fields of the model
                and m.opt.cone == ConeType.ELLIPTIC and jnp.ndim(uu) > 0):
            zero = cancelled(uu, uv, vv, alpha)
            uu, uv, vv = (jnp.where(zero, jnp.zeros_like(x), x) for x in (uu, uv, vv))
        return create(m, d, ctx, alpha, jv, quad, quad_gauss, uu, v0, uv, vv)

    create_finite.wraps_finite_linesearch = True
    create_finite.__wrapped_create__ = create   # MJX's own (the tests compare the two)
    return create_finite


def install() -> None:
    """Wraps MJX's line-search point (idempotent). Called by
    `mjx_envs.physics.backends.import_mjx`, before any MJX function of this package is traced."""
    # lazy: MJX's private solver loads only with MJX (`backends.import_mjx`)
    from mujoco.mjx._src import solver

    create = solver._LSPoint.create   # a classmethod: bound to _LSPoint
    if not getattr(create, "wraps_finite_linesearch", False):
        solver._LSPoint.create = staticmethod(_finite_point(create))
