"""MJX's box-box and convex contact points, each point once (physics version 3), and
box-shaped meshes collided as boxes (physics version 4).

MJX's box-box and convex-convex collisions (``mujoco/mjx/_src/collision_convex.py``) return a
fixed set of 4 contact points per pair, chosen by ``_manifold_points`` as arg-maxima over the
clipped contact polygon. When fewer than 4 points penetrate (a finger's edge lying on a face:
2 points, the usual case in a grasp), the same point is returned two or three times and becomes
two or three identical constraint rows. MuJoCo's C engine returns each point once. Repeated rows
act as one contact with a fraction of the regularization, i.e. a stiffer one: at the C engine's
grasped states of the scripted pick-up controller MJX counted 15.9 finger contacts against C's
8.8, and held a bar pulled down with 3x its weight with a 0.8 mm drop against C's 3.1 mm; with
each point once, 9.2 contacts and a 2.95 mm drop (docs/MJX_VS_C.md, "Each contact point once").
MJX's own plane-convex collision already drops its repeats (``plane_convex``: ``unique``); this
module does the same for the pairs that do not.

`install` puts a wrapper in front of MJX's box-box and convex-convex colliders. The wrapper
changes nothing unless the model asks for it with the custom numeric `NUMERIC` = 1 (the scenes
of physics version 3 do; `mjx_envs.model.load_model` removes it for older versions), so MJX runs
of older physics versions, and any other model in the process, step exactly as before. A
repeated point keeps its position and gets MJX's "no contact" distance (1.0, the value
``plane_convex`` and the clipped manifold use), so its constraint rows are inactive. The C
engine ignores the numeric.

Physics version 4's grasp pairs hold a finger box as a box-shaped convex mesh
(`mjx_envs.model.PHYSICS_V4`): the C engine collides it with its multi-contact convex collider,
which returns the same points as MJX's box-box at any tilt, where the C engine's box-box
returns one corner and MJX's convex-convex can return one point where the faces lie flat.
`install` also routes MJX's (box, mesh) pairs to its box-box collider (with the wrapper above),
the mesh as a box of its geom's size, for a model with the numeric `BOX_MESHES` = 1
(`mjx_envs.model.check_box_meshes` holds for it); other models collide as before.

MJX's plane-convex collision keeps only the vertices within 1 mm of the deepest one as its
manifold. A bar pressed into the table at a tilt of a few millimetres over its length then rests
on one or two points in MJX and on its four bottom corners in C (``mjc_PlaneBox``: every corner
below the box's centre that penetrates, up to 4), and the two engines turn the same state into
different motions (docs/MJX_VS_C.md, "Physics version 5"). For a model with the numeric
`PLANE_BOX_CORNERS` = 1, `install` routes MJX's (plane, box) pairs to `plane_box_corners`, which
keeps C's corners; other models collide as before.
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp

from mjx_envs.model import MJX_BOX_MESHES as BOX_MESHES
from mjx_envs.model import MJX_PLANE_BOX_CORNERS as PLANE_BOX_CORNERS
from mjx_envs.model import MJX_UNIQUE_CONTACTS as NUMERIC

TOLERANCE = 1e-6
"""two points of one pair closer than this (metres) are one point; distinct manifold points
lie millimetres apart, a repeat is the identical array element"""
NO_CONTACT = 1.0
"""the distance MJX gives a manifold point that does not touch"""


def unique_points(dist: jnp.ndarray, pos: jnp.ndarray, ncon: int,
                  tol: float = TOLERANCE) -> jnp.ndarray:
    """``dist`` [P * ncon] of P pairs with ``ncon`` points each (positions ``pos`` [P * ncon,
    3]) with every point that repeats an earlier point of its pair set to `NO_CONTACT`."""
    d = dist.reshape(-1, ncon)
    p = pos.reshape(-1, ncon, 3)
    close = jnp.linalg.norm(p[:, :, None] - p[:, None, :], axis=-1) < tol
    earlier = jnp.tril(jnp.ones((ncon, ncon), bool), -1)  # [k, j]: j before k
    repeat = (close & earlier).any(-1)
    return jnp.where(repeat, jnp.asarray(NO_CONTACT, d.dtype), d).reshape(dist.shape)


def _unique(collide):
    # lazy: see `install`
    from mujoco.mjx._src import collision_driver

    def collide_unique(m, d, key, geom):
        dist, pos, frame = collide(m, d, key, geom)
        if collision_driver._numeric(m, NUMERIC) == 1:  # a static field of the model
            dist = unique_points(dist, pos, collide.ncon)
        return dist, pos, frame

    collide_unique.ncon = collide.ncon
    return collide_unique


def plane_box_corners(plane, box):
    """One (plane, box) pair's contacts as the C engine's ``mjc_PlaneBox`` makes them: the box's
    corners below its centre (along the plane's normal) that penetrate the plane, up to 4, each
    at the midpoint between the surfaces, chosen by MJX's own 4-point manifold. ``plane``: MJX's
    GeomInfo, ``box``: its ConvexInfo of the box (``mesh.box``). Returns (dist [4], pos [4, 3],
    frame [4, 3, 3]); an unused slot has distance `NO_CONTACT`."""
    # lazy: see `install`
    from mujoco.mjx._src import math as mjx_math
    from mujoco.mjx._src.collision_convex import _manifold_points

    vert = box.vert
    n_box = box.mat.T @ plane.mat[:, 2]                       # the plane's normal, box frame
    depth = (box.mat.T @ (plane.pos - box.pos) - vert) @ n_box  # > 0: the corner penetrates
    corner = (depth >= 0) & (vert @ n_box <= 0)               # C's corners
    idx = _manifold_points(vert, corner, n_box)
    n = plane.mat[:, 2]
    unique = jnp.tril(idx == idx[:, None]).sum(axis=1) == 1
    dist = jnp.where(unique & corner[idx], -depth[idx], NO_CONTACT)
    pos = box.pos + vert[idx] @ box.mat.T - 0.5 * jnp.minimum(dist, 0.0)[:, None] * n
    frame = jnp.stack([mjx_math.make_frame(n)] * 4, axis=0)
    return dist, pos, frame


def _plane_boxes(plane_box):
    # lazy: see `install`
    from mujoco.mjx._src import collision_driver
    from mujoco.mjx._src.collision_convex import collider

    corners = collider(ncon=plane_box.ncon)(plane_box_corners)

    def collide_plane_box(m, d, key, geom):
        if collision_driver._numeric(m, PLANE_BOX_CORNERS) == 1:  # a static field of the model
            return corners(m, d, key, geom)
        return plane_box(m, d, key, geom)

    collide_plane_box.ncon = plane_box.ncon
    collide_plane_box.keeps_box_corners = True
    return collide_plane_box


def _box_meshes(box_mesh):
    # lazy: see `install`
    from mujoco.mjx._src import collision_driver
    from mujoco.mjx._src.types import GeomType

    def collide_as_boxes(m, d, key, geom):
        if collision_driver._numeric(m, BOX_MESHES) == 1:  # a static field of the model
            as_box = dataclasses.replace(key, types=(GeomType.BOX, GeomType.BOX),
                                         data_ids=(-1, -1))
            # the table's box-box at call time (with whatever wraps it then)
            box_box = collision_driver._COLLISION_FUNC[(GeomType.BOX, GeomType.BOX)]
            return box_box(m, d, as_box, geom)
        return box_mesh(m, d, key, geom)

    collide_as_boxes.ncon = box_mesh.ncon
    collide_as_boxes.routes_box_meshes = True
    return collide_as_boxes


def install() -> None:
    """Wraps MJX's box-box and convex-convex colliders and routes its (box, mesh) pairs
    (idempotent). Called by `mjx_envs.physics.backends.import_mjx`, i.e. before any MJX function
    of this package is traced."""
    # lazy: MJX's private collision table loads only with MJX (`backends.import_mjx`)
    from mujoco.mjx._src import collision_convex, collision_driver
    from mujoco.mjx._src.types import GeomType

    table = collision_driver._COLLISION_FUNC
    for types, collide in list(table.items()):
        if collide in (collision_convex.box_box, collision_convex.convex_convex):
            table[types] = _unique(collide)
    box_mesh, box_box = table[(GeomType.BOX, GeomType.MESH)], table[(GeomType.BOX, GeomType.BOX)]
    if not getattr(box_mesh, "routes_box_meshes", False):
        assert box_mesh.ncon == box_box.ncon, "MJX's box-mesh and box-box manifold sizes differ"
        table[(GeomType.BOX, GeomType.MESH)] = _box_meshes(box_mesh)
    plane_box = table[(GeomType.PLANE, GeomType.BOX)]
    if not getattr(plane_box, "keeps_box_corners", False):
        assert plane_box.ncon == 4, "MJX's plane-box manifold is no longer 4 points"
        table[(GeomType.PLANE, GeomType.BOX)] = _plane_boxes(plane_box)
