"""The prototype of mjx_envs/physics/mjx_contacts.py (physics version 3): MJX's box-box
collision with each contact point once (a point within TOL of an earlier one of the same pair
is dropped by giving it a positive distance), switched on for the whole process by `install`
(the shipped version follows the scene's numeric). MID=1 in the environment also moves each
point midway between the surfaces, as the C engine reports it. Reaches into MJX's private
collision table (``mujoco.mjx._src``): it ran at git fef0c05 with the MJX of that revision.
"""

from __future__ import annotations

import os

import jax.numpy as jp
from mujoco.mjx._src import collision_driver as cd
from mujoco.mjx._src.types import GeomType

ORIG = cd._COLLISION_FUNC[(GeomType.BOX, GeomType.BOX)]
TOL = 1e-5
MID = os.environ.get("MID") == "1"


def _inside(p, xpos, xmat, size):
    """Largest excess of points p [P, n, 3] over the boxes (xpos [P, 3], xmat [P, 3, 3], size
    [P, 3]) in box coordinates."""
    loc = jp.einsum("pji,pnj->pni", xmat, p - xpos[:, None])
    return (jp.abs(loc) - size[:, None]).max(-1)


def _midway(m, d, geom, dd, pp, frame, n):
    """Each point moved by half its depth along the normal, to the side inside both boxes."""
    nrm = frame.reshape(-1, n, 3, 3)[:, :, 0]
    g1, g2 = geom.T
    xp, xm, sz = d.geom_xpos, d.geom_xmat.reshape(-1, 3, 3), m.geom_size
    ds = jp.minimum(dd, 0.0)[..., None]
    cands = [pp + 0.5 * ds * nrm, pp - 0.5 * ds * nrm]
    ex = [jp.maximum(_inside(c, xp[g1], xm[g1], sz[g1]), _inside(c, xp[g2], xm[g2], sz[g2]))
          for c in cands]
    return jp.where((ex[0] <= ex[1])[..., None], cands[0], cands[1])


def unique_box_box(m, d, key, geom):
    dist, pos, frame = ORIG(m, d, key, geom)
    n = ORIG.ncon
    dd, pp = dist.reshape(-1, n), pos.reshape(-1, n, 3)
    pos_out = _midway(m, d, geom, dd, pp, frame, n).reshape(pos.shape) if MID else pos
    close = jp.linalg.norm(pp[:, :, None] - pp[:, None, :], axis=-1) < TOL
    earlier = jp.tril(jp.ones((n, n), bool), -1)
    dup = (close & earlier[None]).any(-1)
    dd = jp.where(dup, jp.ones_like(dd), dd)
    return dd.reshape(dist.shape), pos_out, frame


unique_box_box.ncon = ORIG.ncon


def install():
    cd._COLLISION_FUNC[(GeomType.BOX, GeomType.BOX)] = unique_box_box
