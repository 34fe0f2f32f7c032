"""Prototype: MJX collides a box-shaped convex mesh as a box, so a pair that the C engine
collides as a convex mesh (mjc_Convex: native CCD with multi-contact, the multiccd flag on by
default in mujoco 4) is collided by MJX's box-box function instead of its convex-convex one.

Why (docs/MJX_VS_C.md, "One point against two"; manifold_static.py): at a static finger-neck
pair, MJX's box-box manifold and the C engine's multi-contact on a box-shaped mesh return the
same points with the same depths at every tilt measured, while the C engine's box-box
(mjc_BoxBox) returns one point where a tilted corner meets a face (MJX: 2-3), and MJX's
convex-convex returns one point (its edge-contact branch) where the face is rotated in its plane
or tilted about one of its edges (C: 2-4).

`install` puts a router in front of MJX's (BOX, MESH) collider: for a model with the custom
numeric `NUMERIC` = 1 it calls the (BOX, BOX) collider of the table (physics version 3's
unique-points wrapper included) with the mesh geom as a box of the geom's size (a mesh geom's
size is its half extents in the mesh frame; exact for a box-shaped mesh, the only meshes a
model with the numeric may have in box pairs: `check`). Any other model is collided as before.
Reaches into MJX's private collision table (``mujoco.mjx._src``), as unique_points.py did.
"""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np

NUMERIC = "mjx_box_meshes"


def check(m: mujoco.MjModel, tol: float = 1e-6) -> None:
    """Raises if the model asks for the routing and one of its meshes is not a box of its
    geoms' size (8 vertices at +-size in the geom frame)."""
    for g in range(m.ngeom):
        if m.geom_type[g] != mujoco.mjtGeom.mjGEOM_MESH:
            continue
        i = int(m.geom_dataid[g])
        v = m.mesh_vert[m.mesh_vertadr[i]:m.mesh_vertadr[i] + m.mesh_vertnum[i]]
        if len(v) != 8 or np.abs(np.abs(v) - m.geom_size[g]).max() > tol:
            raise ValueError(f"geom {m.geom(g).name!r}: its mesh is not a box of its size")


def install() -> None:
    """Routes (BOX, MESH) pairs of a model with the numeric to the box-box collider
    (idempotent; call after mjx_envs' own wrapper, `backends.import_mjx`)."""
    from mujoco.mjx._src import collision_driver as cd
    from mujoco.mjx._src.types import GeomType

    from mjx_envs.physics import backends

    backends.import_mjx()   # physics version 3's wrapper first: it wraps convex_convex itself
    table = cd._COLLISION_FUNC
    box_mesh = table[(GeomType.BOX, GeomType.MESH)]
    if getattr(box_mesh, "routes_box_meshes", False):
        return

    def collide(m, d, key, geom):
        if cd._numeric(m, NUMERIC) == 1:   # a static field of the model
            as_box = dataclasses.replace(key, types=(GeomType.BOX, GeomType.BOX),
                                         data_ids=(-1, -1))
            return table[(GeomType.BOX, GeomType.BOX)](m, d, as_box, geom)
        return box_mesh(m, d, key, geom)

    assert box_mesh.ncon == table[(GeomType.BOX, GeomType.BOX)].ncon
    collide.ncon = box_mesh.ncon
    collide.routes_box_meshes = True
    table[(GeomType.BOX, GeomType.MESH)] = collide
