"""Finger grasp faces as box-shaped convex meshes (C: general convex collision, + multiccd;
MJX: convex-convex manifold). meshf.load_model(scene) -> MjModel."""
import itertools
import mujoco
import numpy as np
import mjx_envs.model as model

HALF = np.array([0.017, 0.011, 0.040])


def _edit(spec):
    verts = np.array(list(itertools.product(*[(-h, h) for h in HALF]))).ravel().tolist()
    spec.add_mesh(name="finger_box_mesh", uservert=verts)
    fingers = {}
    for b in spec.bodies:
        for g in b.geoms:
            if g.name.endswith(("_finger1", "_finger2")):
                fingers[g.name] = (b, g)
    for p in spec.pairs:
        for attr in ("geomname1", "geomname2"):
            fname = getattr(p, attr)
            if fname in fingers and p.friction[0] > 1.0:
                body, g = fingers[fname]
                nm = fname + "_mesh"
                if spec.geom(nm) is None:
                    body.add_geom(name=nm, type=mujoco.mjtGeom.mjGEOM_MESH, meshname="finger_box_mesh",
                                  pos=list(g.pos), contype=0, conaffinity=0, group=3, density=0.0)
                setattr(p, attr, nm)


def load_model(scene, timestep=None, cone=None, multiccd=True):
    with model.scene_path(scene) as path:
        spec = mujoco.MjSpec.from_file(str(path))
        _edit(spec)
        m = spec.compile()
    if timestep is not None:
        m.opt.timestep = float(timestep)
    if cone is not None:
        m.opt.cone = model.CONES[cone]
    if not multiccd:   # mujoco 4: multiccd is on unless disabled
        m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_MULTICCD)
    return m
