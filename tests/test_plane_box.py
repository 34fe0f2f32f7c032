"""MJX's box-on-plane contacts as the C engine makes them (physics version 5,
`mjx_envs.physics.mjx_contacts.plane_box_corners`): the same points and depths as MuJoCo's
``mjc_PlaneBox`` for boxes at random tilts, where MJX's own collider keeps fewer, and the
installation (default tier, ~5 s)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from mjx_envs import model as model_lib
from mjx_envs.physics import backends, mjx_contacts

HALF = (0.05, 0.012, 0.012)
"""the half-sizes of the test box (a bar's cap: long, square section)"""

SCENE = f"""<mujoco><worldbody><geom name="floor" type="plane" size="1 1 0.1"/>
<body name="box" pos="0 0 0.2"><freejoint/><geom name="box" type="box"
size="{HALF[0]} {HALF[1]} {HALF[2]}"/></body></worldbody></mujoco>"""


def _poses(n: int, seed: int = 0):
    """n box poses (position [n, 3], rotation matrix [n, 3, 3]): tilts up to ~20 degrees about
    a random horizontal axis and any yaw, the centre so that the lowest corner is 0-6 mm deep."""
    rng = np.random.default_rng(seed)
    pos, mats = np.zeros((n, 3)), np.zeros((n, 3, 3))
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * HALF
    for i in range(n):
        quat = np.zeros(4)
        axis = np.array([*rng.normal(size=2), 0.0])
        mujoco.mju_axisAngle2Quat(quat, axis / np.linalg.norm(axis), rng.uniform(0, 0.35))
        yaw = np.zeros(4)
        mujoco.mju_axisAngle2Quat(yaw, np.array([0.0, 0.0, 1.0]), rng.uniform(-np.pi, np.pi))
        q = np.zeros(4)
        mujoco.mju_mulQuat(q, yaw, quat)
        mujoco.mju_quat2Mat(mats[i].reshape(9), q)
        low = (corners @ mats[i].T)[:, 2].min()
        pos[i] = [*rng.uniform(-0.2, 0.2, 2), -low - rng.uniform(0.0, 0.006)]
    return pos, mats


def _c_contacts(pos, mats):
    """MuJoCo's (C engine) contacts per pose: a list of (dist [k], pos [k, 3])."""
    m = mujoco.MjModel.from_xml_string(SCENE)
    d = mujoco.MjData(m)
    out = []
    for p, r in zip(pos, mats):
        q = np.zeros(4)
        mujoco.mju_mat2Quat(q, r.reshape(9))
        d.qpos[:] = [*p, *q]
        mujoco.mj_forward(m, d)
        c = d.contact[:d.ncon]
        out.append((np.array([x.dist for x in c]), np.array([x.pos for x in c]).reshape(-1, 3)))
    return out


def _mjx_contacts(fn, pos, mats):
    """(dist [n, 4], pos [n, 4, 3]) of MJX per-pair collider ``fn`` (the plane at the origin)."""
    from mujoco.mjx._src import mesh
    from mujoco.mjx._src.collision_types import GeomInfo

    n = len(pos)

    def run(p, r):
        plane = GeomInfo(pos=jnp.zeros((n, 3)), mat=jnp.tile(jnp.eye(3), (n, 1, 1)),
                         size=jnp.zeros((n, 3)))
        box = mesh.box(GeomInfo(pos=p, mat=r, size=jnp.tile(jnp.asarray(HALF), (n, 1))))
        axes = jax.tree_util.tree_map(lambda x: None, box).replace(
            pos=0, mat=0, size=0, face=0, vert=0)   # as MJX's `collider` batches a box
        return jax.vmap(fn, in_axes=(0, axes))(plane, box)[:2]

    dist, cpos = jax.jit(run)(jnp.asarray(pos, jnp.float32), jnp.asarray(mats, jnp.float32))
    return np.asarray(dist), np.asarray(cpos)


def test_box_corners_match_the_c_engines_plane_box_collision():
    """200 poses: the same contact count, depths and points (float32 rounding) as the C engine,
    while MJX's own plane-convex collider has fewer contacts in over a third of them (~4 s:
    imports and compiles MJX's collider)."""
    backends.import_mjx()
    from mujoco.mjx._src.collision_convex import plane_convex

    # MJX's per-pair function inside its `collider` wrapper
    own_fn = next(c.cell_contents for c in plane_convex.__closure__
                  if getattr(c.cell_contents, "__name__", "") == "plane_convex")
    pos, mats = _poses(200)
    c = _c_contacts(pos, mats)
    dist, cpos = _mjx_contacts(mjx_contacts.plane_box_corners, pos, mats)
    own, _ = _mjx_contacts(own_fn, pos, mats)
    fewer = 0
    for i, (cd, cp) in enumerate(c):
        hit = dist[i] < 0
        assert hit.sum() == len(cd), i
        for d_c, p_c in zip(cd, cp):
            j = np.argmin(np.linalg.norm(cpos[i][hit] - p_c, axis=1))
            assert np.linalg.norm(cpos[i][hit][j] - p_c) < 2e-6, i
            assert abs(dist[i][hit][j] - d_c) < 2e-6, i
        assert np.all(dist[i][~hit] == mjx_contacts.NO_CONTACT)
        fewer += (own[i] < 0).sum() < len(cd)
    assert fewer > 50                     # 76 of these 200


def test_a_box_above_the_plane_has_no_contact():
    """A box 1 mm above the plane: every slot is the no-contact distance (~1 s)."""
    backends.import_mjx()
    pos, mats = _poses(8, seed=1)
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * HALF
    for i in range(8):
        pos[i, 2] = -(corners @ mats[i].T)[:, 2].min() + 0.001
    dist, _ = _mjx_contacts(mjx_contacts.plane_box_corners, pos, mats)
    assert np.all(dist == mjx_contacts.NO_CONTACT)


def test_install_routes_plane_box_pairs_once():
    """`import_mjx` puts the (plane, box) router in MJX's collision table; a second install
    keeps the one router (~0 s once MJX is imported)."""
    backends.import_mjx()
    from mujoco.mjx._src import collision_driver
    from mujoco.mjx._src.types import GeomType

    key = (GeomType.PLANE, GeomType.BOX)
    router = collision_driver._COLLISION_FUNC[key]
    assert getattr(router, "keeps_box_corners", False) and router.ncon == 4
    mjx_contacts.install()
    assert collision_driver._COLLISION_FUNC[key] is router


@pytest.mark.parametrize("task", ["pickup", "pot"])
def test_version_5_is_version_4_with_the_corner_numeric(task):
    """Version 5's scene is version 4's plus the numeric, and it changes MJX only (~1 s)."""
    from mjx_envs import registry

    scene = registry.get(task).config.scene
    v4 = model_lib.load_model(scene, physics_version=4)
    v5 = model_lib.load_model(scene, physics_version=5)
    names = [v5.numeric(i).name for i in range(v5.nnumeric)]
    assert model_lib.MJX_PLANE_BOX_CORNERS in names
    assert v5.nnumeric == v4.nnumeric + 1
    assert (v5.ngeom, v5.npair, v5.nbody) == (v4.ngeom, v4.npair, v4.nbody)
    assert np.array_equal(v5.pair_friction, v4.pair_friction)
    assert model_lib.physics_changed(5, task, "mjx")
    assert not model_lib.physics_changed(5, task, "c")
    assert not model_lib.physics_changed(5, "push")
