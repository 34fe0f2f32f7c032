"""Finger pads as capsules along the finger (both engines: capsule-box, 2 contacts per capsule
on a face). caps.OPTS.update(r=0.006, xs=(-0.011, 0.011), zc=0.035, half=0.032)"""
import mujoco
import mjx_envs.model as model

OPTS = {}


def _edit(spec, r, xs, zc, half):
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
        y = sign * (-0.005 + r)
        for i, x in enumerate(xs):
            nm = f"{fname}_pad{i}"
            if spec.geom(nm) is None:
                body.add_geom(name=nm, type=mujoco.mjtGeom.mjGEOM_CAPSULE, size=[r, half, 0],
                              pos=[x, y, zc], contype=0, conaffinity=0, group=3, density=0.0)
            spec.add_pair(geomname1=nm, geomname2=other, condim=p.condim,
                          friction=list(p.friction), solref=list(p.solref),
                          solimp=list(p.solimp), margin=p.margin, gap=p.gap)
        spec.delete(p)


def load_model(scene, timestep=None, cone=None, physics_version=None):
    with model.scene_path(scene) as path:
        spec = mujoco.MjSpec.from_file(str(path))
        _edit(spec, **OPTS)
        m = spec.compile()
    if timestep is not None:
        m.opt.timestep = float(timestep)
    if cone is not None:
        m.opt.cone = model.CONES[cone]
    return m


def patch(**opts):
    """Use capsule pads in every model the package loads (probe; the scenes stay as shipped)."""
    import os
    import sys
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "finger_pads"))
    import spheres  # its FingerContacts patch counts "<finger>_pad*" geoms as the finger
    import mjx_envs.core as core
    import mjx_envs.numpy_env as numpy_env
    from mjx_envs.tasks import grasp_start

    OPTS.update(opts)
    orig = model.load_model

    def load(scene, timestep=None, cone=None, physics_version=None):
        if scene not in ("scene_pickup.xml", "scene_pot.xml"):
            return orig(scene, timestep, cone, physics_version)
        return load_model(scene, timestep, cone, physics_version)

    grasp_start.FingerContacts.__init__ = spheres._fc_init
    model.load_model = core.load_model = numpy_env.load_model = load


DEFAULT = dict(r=0.006, xs=(-0.011, 0.011), zc=0.035, half=0.032)
