"""Finger pads as spheres for the grasp pairs: both engines then make one contact per sphere
(sphere-box is analytic in C and MJX), instead of box-box manifolds of different sizes.
import spheres; spheres.patch(r=0.006, xs=(-0.01, 0.01), zs=(0.005, 0.025, 0.045, 0.065))"""
import mujoco
import numpy as np

import mjx_envs.core as core
import mjx_envs.model as model
import mjx_envs.numpy_env as numpy_env

_orig = model.load_model
OPTS = {}


def _edit(spec, r, xs, zs):
    fingers = {}
    for b in spec.bodies:
        for g in b.geoms:
            if g.name.endswith(("_finger1", "_finger2")):
                fingers[g.name] = (b, g)
    grasp = [p for p in spec.pairs
             if (p.geomname1 in fingers or p.geomname2 in fingers) and p.friction[0] > 1.0]
    for p in grasp:
        fname = p.geomname1 if p.geomname1 in fingers else p.geomname2
        other = p.geomname2 if fname == p.geomname1 else p.geomname1
        body, g = fingers[fname]
        sign = 1.0 if fname.endswith("finger1") else -1.0
        y = sign * (-0.005 + r)   # sphere surface on the finger box's inner face
        for i, x in enumerate(xs):
            for j, z in enumerate(zs):
                nm = f"{fname}_pad{i}{j}"
                if spec.geom(nm) is None:
                    body.add_geom(name=nm, type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[r, 0, 0],
                                  pos=[x, y, z], contype=0, conaffinity=0, group=3,
                                  density=0.0)
                spec.add_pair(geomname1=nm, geomname2=other, condim=p.condim,
                              friction=list(p.friction), solref=list(p.solref),
                              solimp=list(p.solimp), margin=p.margin, gap=p.gap)
        spec.delete(p)


def load_model(scene, timestep=None, cone=None, physics_version=None):
    if scene == "scene_reach.xml" or not OPTS:
        return _orig(scene, timestep, cone, physics_version)
    with model.scene_path(scene) as path:
        spec = mujoco.MjSpec.from_file(str(path))
        _edit(spec, **OPTS)
        m = spec.compile()
    if timestep is not None:
        m.opt.timestep = float(timestep)
    if cone is not None:
        m.opt.cone = model.CONES[cone]
    return m


def _fc_init(self, model, object_body):
    self.model, self.data = model, mujoco.MjData(model)
    self.fingers = {}
    for i in range(model.ngeom):
        name = model.geom(i).name
        for f in self.FINGERS:
            if name == f or name.startswith(f + "_pad"):
                self.fingers[i] = f
    self.body = model.body(object_body).id


def patch(**opts):
    OPTS.update(opts)
    from mjx_envs.tasks import grasp_start
    grasp_start.FingerContacts.__init__ = _fc_init
    model.load_model = core.load_model = numpy_env.load_model = load_model
