"""MJX's box-box contact points, each once (physics version 3, `mjx_envs.physics.mjx_contacts`):
the pure de-duplication, that `import_mjx` installs it, and (MJX tier) on a box lying with one
edge on another box: MJX repeats the edge's two points to fill its 4 slots unless the model
carries the numeric, and then returns the C engine's two points."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from mjx_envs import model
from mjx_envs.physics import backends, mjx_contacts


def test_unique_points_drops_only_repeats_of_an_earlier_point_of_the_same_pair():
    """Pair 0 repeats its two points ([a, b, a, b]); pair 1 has four distinct points, one of
    them at pair 0's position (another pair: kept) (~0.1 s)."""
    a, b = [0.1, 0.2, 0.3], [0.1, 0.2, 0.34]
    pos = jnp.asarray([a, b, a, b, a, [0, 0, 0], [1, 0, 0], [0, 1, 0]], jnp.float32)
    dist = jnp.asarray([-1e-3, -2e-3, -1e-3, -2e-3, -1e-3, -1e-3, 1.0, -5e-4], jnp.float32)
    out = np.asarray(mjx_contacts.unique_points(dist, pos, 4))
    np.testing.assert_array_equal(
        out, np.float32([-1e-3, -2e-3, 1.0, 1.0, -1e-3, -1e-3, 1.0, -5e-4]))
    assert out.dtype == np.float32


def test_import_mjx_installs_the_unique_points_collider():
    """Idempotent: a second install keeps one wrapper (~2 s: imports MJX)."""
    backends.import_mjx()
    from mujoco.mjx._src import collision_driver
    from mujoco.mjx._src.types import GeomType

    box_box = collision_driver._COLLISION_FUNC[(GeomType.BOX, GeomType.BOX)]
    assert box_box.__module__ == mjx_contacts.__name__   # the wrapper of `install`
    mjx_contacts.install()
    assert collision_driver._COLLISION_FUNC[(GeomType.BOX, GeomType.BOX)] is box_box
    assert box_box.ncon == 4


def _edge_on_box(unique: bool) -> mujoco.MjModel:
    """A 4 cm cube tilted 0.2 rad about x, one edge 1 mm into a fixed box below it."""
    numeric = (f'<custom><numeric name="{model.MJX_UNIQUE_CONTACTS}" data="1"/></custom>'
               if unique else "")
    z = 0.02 * (np.cos(0.2) + np.sin(0.2)) - 0.001
    return mujoco.MjModel.from_xml_string(f"""
<mujoco><compiler angle="radian"/>{numeric}
  <worldbody>
    <geom name="floor" type="box" size="0.1 0.1 0.02" pos="0 0 -0.02"/>
    <body pos="0 0 {z}" euler="0.2 0 0"><freejoint/>
      <geom name="cube" type="box" size="0.02 0.02 0.02"/></body>
  </worldbody>
</mujoco>""")


def _contacts_c(m):
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    return np.array([d.contact.pos[i] for i in range(d.ncon)])


def _contacts_mjx(m):
    mjx = backends.import_mjx()
    mm = mjx.put_model(m)
    d = jax.jit(mjx.forward)(mm, mjx.make_data(mm))
    con = d._impl.contact
    active = np.asarray(con.dist < con.includemargin)
    return np.asarray(con.pos)[active]


@pytest.mark.mjx
def test_mjx_returns_the_c_engine_s_edge_points_once_when_the_model_asks():
    """An edge on a face: the C engine gives its 2 end points; MJX without the numeric gives
    them 4 times in all (each point at least twice), with it the same 2 points as C, within
    0.5 mm (~10 s: two small MJX compiles)."""
    c = _contacts_c(_edge_on_box(unique=True))
    assert len(c) == 2
    repeated = _contacts_mjx(_edge_on_box(unique=False))
    assert len(repeated) == 4
    assert len(np.unique(np.round(repeated, 6), axis=0)) == 2
    once = _contacts_mjx(_edge_on_box(unique=True))
    assert len(once) == 2
    for p in c:
        assert np.linalg.norm(once[:, :2] - p[:2], axis=-1).min() < 5e-4
