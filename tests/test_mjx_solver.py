"""MJX's line search kept finite under an elliptic cone (physics version 4,
`mjx_envs.physics.mjx_solver`): the cancellation test, that `import_mjx` installs the wrapper,
and (MJX tier) the state where a pick-up episode's MJX physics fault starts."""

from __future__ import annotations

import os

import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from mjx_envs import model, registry
from mjx_envs.physics import backends, mjx_solver

FAULT_STATE = os.path.join(os.path.dirname(__file__), "data", "mjx_fault_pickup_v4.npz")
"""MJX's data (float32) at the start of the control step in which an MJX-trained pick-up policy
threw the bar (episode 44 of seed 9090, `experiments/engine_parity/fault_probe.py`): the right
fingers land on the bar's middle within this step"""


def test_cancelled_is_true_at_the_cones_apex_and_only_near_it():
    """A step that takes the tangential residual to zero (v = -u / alpha) is cancelled whatever
    the float32 rounding of MJX's expression gives (it is negative in about a third of these
    draws); random steps, and alpha = 0 with a residual, are not; uu = uv = vv = 0 is
    (unchanged by the wrapper) (~0.2 s)."""
    rng = np.random.default_rng(0)
    u = rng.normal(size=(500, 2)).astype(np.float32) * np.float32(10.0) ** rng.integers(
        -4, 3, size=(500, 1)).astype(np.float32)
    alpha = rng.uniform(0.05, 4.0, size=500).astype(np.float32)
    v = (-u / alpha[:, None]).astype(np.float32)

    def terms(u, v):
        return (jnp.sum(u * u, 1), jnp.sum(u * v, 1), jnp.sum(v * v, 1))

    uu, uv, vv = terms(jnp.asarray(u), jnp.asarray(v))
    tsqr = np.asarray(uu + alpha * (2 * uv + alpha * vv))
    assert (tsqr < 0).sum() > 50          # the case MJX's square root turns into NaN
    assert np.asarray(mjx_solver.cancelled(uu, uv, vv, jnp.asarray(alpha))).all()
    w = rng.normal(size=(500, 2)).astype(np.float32)
    uu, uv, vv = terms(jnp.asarray(u), jnp.asarray(w))
    assert not np.asarray(mjx_solver.cancelled(uu, uv, vv, jnp.asarray(alpha))).any()
    assert not np.asarray(mjx_solver.cancelled(uu, uv, vv, jnp.float32(0.0))).any()
    z = jnp.zeros(3, jnp.float32)
    assert np.asarray(mjx_solver.cancelled(z, z, z, jnp.float32(1.0))).all()


def test_import_mjx_installs_the_finite_line_search_once():
    """Idempotent: a second install keeps one wrapper (~2 s: imports MJX)."""
    backends.import_mjx()
    from mujoco.mjx._src import solver

    create = solver._LSPoint.create
    assert getattr(create, "wraps_finite_linesearch", False)
    mjx_solver.install()
    assert solver._LSPoint.create is create


def _pickup_v4(finite: bool) -> mujoco.MjModel:
    cfg = registry.default_config("pickup")
    m = model.load_model(cfg.scene, cfg.timestep, cfg.cone, physics_version=4)
    if not finite:   # MJX's own line search
        m.numeric_data[m.numeric_adr[m.numeric(model.MJX_FINITE_LINESEARCH).id]] = 0.0
    return m


def _bar_spin(physics: str, m: mujoco.MjModel) -> tuple[float, bool]:
    """(|angular velocity| of the bar in rad/s, finite) after one control step from
    FAULT_STATE, warm start included."""
    s = dict(np.load(FAULT_STATE))
    cfg = registry.default_config("pickup")
    be = backends.make_backend(physics, m, cfg.n_substeps)
    data = be.init(jnp.asarray(s["qpos"]), jnp.asarray(s["qvel"]), jnp.asarray(s["mocap_pos"]))
    if physics == "mjx":
        data = data.replace(qacc_warmstart=jnp.asarray(s["qacc_warmstart"]),
                            mocap_quat=jnp.asarray(s["mocap_quat"]))
    new = be.step(data, jnp.asarray(s["ctrl"]), jnp.asarray(s["mocap_pos"]))
    free = [j for j in range(m.njnt) if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE][0]
    adr = m.jnt_dofadr[free]
    spin = float(np.linalg.norm(np.asarray(new.qvel)[adr + 3:adr + 6]))
    return spin, bool(np.asarray(be.ok(new)) > 0.5)


@pytest.mark.mjx
def test_the_finite_line_search_keeps_the_bar_where_mjx_threw_it():
    """From FAULT_STATE, one control step (8 substeps) and the next: with version 4's finite
    line search the bar turns at under 5 rad/s and the state stays finite, as on the C engine
    from the same state (0.4 rad/s; float64 MJX also 0.4). In the rollout that faulted, MJX's
    own line search stalled at its warm start there and threw the bar (~480 rad/s, then a
    non-finite state); whether a given compilation hits the NaN depends on float32 rounding,
    which the next test pins down (~45 s: one compile)."""
    spin, ok = _bar_spin("mjx", _pickup_v4(finite=True))
    assert ok and spin < 5.0
    c_spin, c_ok = _bar_spin("c", _pickup_v4(finite=True))
    assert c_ok and c_spin < 5.0


@pytest.mark.mjx
def test_mjx_line_search_point_is_nan_where_float32_cancels_and_the_wrapper_is_not():
    """MJX's line-search point at FAULT_STATE's contacts (unjitted, so float32 rounds op by op),
    with one elliptic contact's step taking its tangential residual to the cone's apex in a
    way that float32 cancels below zero: MJX's own point has a NaN cost; version 4's wrapper
    gives a finite one, equal to MJX's with that residual exactly zero; with no cancelled
    contact the wrapper returns MJX's point bit for bit; a model without the numeric gets MJX's
    own (~20 s)."""
    from mujoco.mjx._src import forward as mfwd
    from mujoco.mjx._src import solver

    mjx = backends.import_mjx()
    own = solver._LSPoint.create.__wrapped_create__
    finite_m = _pickup_v4(finite=True)
    m = mjx.put_model(finite_m)
    s = dict(np.load(FAULT_STATE))
    d = mjx.make_data(m).replace(**{k: jnp.asarray(s[k]) for k in (
        "qpos", "qvel", "ctrl", "mocap_pos", "mocap_quat", "qacc_warmstart")})
    for stage in (mfwd.fwd_position, mfwd.fwd_velocity, mfwd.fwd_actuation,
                  mfwd.fwd_acceleration):
        d = stage(m, d)
    ctx = solver.Context.create(m, d)
    n = ctx.u.shape[0]
    jv = jnp.zeros_like(ctx.Jaref)
    quad = jnp.zeros((ctx.Jaref.shape[0], 3), jnp.float32)
    gauss = jnp.zeros(3, jnp.float32)
    alpha = jnp.float32(0.7)
    # a contact whose step reaches the apex: v = -u / alpha, float32 gives tsqr < 0
    u, v = np.float32([0.3, 0.1]), None
    rng = np.random.default_rng(1)
    for _ in range(1000):
        u = rng.normal(size=2).astype(np.float32)
        v = (-u / alpha).astype(np.float32)
        uu_, uv_, vv_ = np.float32(u @ u), np.float32(u @ v), np.float32(v @ v)
        if uu_ + alpha * (np.float32(2) * uv_ + alpha * vv_) < 0:
            break
    zeros = np.zeros(n, np.float32)
    uu, uv, vv = zeros.copy(), zeros.copy(), zeros.copy()
    uu[0], uv[0], vv[0] = u @ u, u @ v, v @ v
    v0 = jnp.full(n, -1.0, jnp.float32)
    args = (jv, quad, gauss)
    mine = solver._LSPoint.create(m, d, ctx, alpha, *args, jnp.asarray(uu), v0, jnp.asarray(uv),
                                  jnp.asarray(vv))
    theirs = own(m, d, ctx, alpha, *args, jnp.asarray(uu), v0, jnp.asarray(uv), jnp.asarray(vv))
    apex = own(m, d, ctx, alpha, *args, jnp.asarray(zeros), v0, jnp.asarray(zeros),
               jnp.asarray(zeros))
    assert np.isnan(float(theirs.cost))
    assert np.isfinite(float(mine.cost)) and float(mine.cost) == float(apex.cost)
    assert float(mine.deriv_0) == float(apex.deriv_0)
    w = rng.normal(size=(n, 2)).astype(np.float32)
    uu2, uv2, vv2 = (jnp.asarray(x) for x in (
        np.float32((w * w).sum(1)), np.float32((w * w[::-1]).sum(1)),
        np.float32((w[::-1] * w[::-1]).sum(1))))
    a = mjx_solver.cancelled(uu2, uv2, vv2, alpha)
    assert not np.asarray(a).any()
    p1 = solver._LSPoint.create(m, d, ctx, alpha, *args, uu2, v0, uv2, vv2)
    p2 = own(m, d, ctx, alpha, *args, uu2, v0, uv2, vv2)
    assert float(p1.cost) == float(p2.cost) and float(p1.deriv_1) == float(p2.deriv_1)
    plain = mjx.put_model(_pickup_v4(finite=False))
    p3 = solver._LSPoint.create(plain, d, ctx, alpha, *args, jnp.asarray(uu), v0,
                                jnp.asarray(uv), jnp.asarray(vv))
    assert np.isnan(float(p3.cost))
