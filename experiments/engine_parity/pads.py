"""Finger pads on the grasp pairs, for probes only (the shipped scenes are not changed): the
finger boxes' grasp contact pairs (friction > 1) are replaced by pairs between the object and
small pad geoms on each finger's inner face, so both engines make one contact per sphere (or two
per capsule) instead of box-box manifolds of different sizes.

Pad kinds (`PADS`): ``spheres`` (2 x 4 spheres of 6 mm), ``dense`` (4 x 9 touching spheres of
4 mm), ``caps`` / ``caps3`` (2 or 3 capsules along the finger), ``recessed`` (the dense grid set
``OUT_M`` beyond the finger box's face, the finger box kept in its pair as a blocker at friction
0.05), ``meshf`` / ``meshf_noccd`` (the finger boxes as convex meshes, with or without
multiccd), ``meshneck`` / ``meshneck_noccd`` (the grasped object geoms, the bar's necks or the
pot's handles, as box-shaped convex meshes in the grasp pairs; the fingers stay boxes), and
``meshf_mjxbox`` / ``meshneck_mjxbox`` (the same, with the numeric of physics version 4: MJX
collides the meshes as boxes, the C engine as meshes with multi-contact; ``meshf_mjxbox`` is
physics version 4's ``mjx_envs.model.PHYSICS_V4``); ``v4_all_fingers`` is version 4 with every
finger pair (also those of friction 1 or less: the bar's middle and caps, the pot's body) on the
finger's mesh copy, ``v5_all_fingers`` the same in physics version 5 (MJX's box-on-table
contacts at every penetrating corner) and ``v6_all_fingers`` in version 6 (the C engine's line
search at 50 iterations; ``v6``: version 6 itself, to compare with).
`model(kind, scene)` builds one model; `patch(kind)` makes every model the package loads
(trainer, evaluation, the parity measurement) carry the pads.
"""

from __future__ import annotations

import itertools
import os

import mujoco
import numpy as np

import mjx_envs.core as core
import mjx_envs.model as model_lib
import mjx_envs.numpy_env as numpy_env

DENSE_ZS = tuple(0.001 + 0.008 * k for k in range(9))
SPHERES = {
    "spheres": dict(r=0.006, xs=(-0.01, 0.01), zs=(0.005, 0.025, 0.045, 0.065)),
    "dense": dict(r=0.004, xs=(-0.012, -0.004, 0.004, 0.012), zs=DENSE_ZS),
}
CAPSULES = {
    "caps": dict(r=0.006, xs=(-0.011, 0.011), zc=0.035, half=0.032),
    "caps3": dict(r=0.006, xs=(-0.011, 0.0, 0.011), zc=0.035, half=0.032),
}
PADS = (*SPHERES, *CAPSULES, "recessed", "meshf", "meshf_noccd", "meshneck", "meshneck_noccd",
        "meshf_mjxbox", "meshneck_mjxbox", "v4_all_fingers", "v5_all_fingers",
        "v6_all_fingers", "v6", "v6_mid_fingers", "v6_cap_fingers")
VERSION_KINDS = ("v4_all_fingers", "v5_all_fingers", "v6_all_fingers", "v6", "v6_mid_fingers",
                 "v6_cap_fingers")
"""kinds that edit a physics version's scene (their edit takes the scene's name)"""
BLOCKER_WORDS = {"v6_mid_fingers": ("bar_mid",),
                 "v6_cap_fingers": model_lib.PHYSICS_V8["mesh_blockers"]["scene_pickup.xml"]}
"""the object geoms whose finger pairs ``v6_mid_fingers`` / ``v6_cap_fingers`` move to the
fingers' mesh copies (`mjx_envs.model.mesh_pairs_with`; version 7 moves both)"""
GRASP_SCENES = ("scene_pickup.xml", "scene_pot.xml")
MESH_HALF = np.array([0.017, 0.011, 0.040])   # the finger box's half sizes


def _fingers(spec) -> dict:
    """{finger geom name: (body, geom)} of the four finger boxes."""
    return {g.name: (b, g) for b in spec.bodies for g in b.geoms
            if g.name.endswith(("_finger1", "_finger2"))}


def _grasp_pairs(spec, fingers):
    """(pair, finger name, other geom name) of each finger's grasp pair (friction > 1)."""
    for p in [p for p in spec.pairs
              if (p.geomname1 in fingers or p.geomname2 in fingers) and p.friction[0] > 1.0]:
        fname = p.geomname1 if p.geomname1 in fingers else p.geomname2
        yield p, fname, (p.geomname2 if fname == p.geomname1 else p.geomname1)


def _pad_pair(spec, name, other, p):
    spec.add_pair(geomname1=name, geomname2=other, condim=p.condim, friction=list(p.friction),
                  solref=list(p.solref), solimp=list(p.solimp), margin=p.margin, gap=p.gap)


def sphere_pads(spec, r, xs, zs, recess=0.0, block=False):
    """Spheres of radius r at (x, z) in xs x zs on each finger's inner face (set `recess` m
    beyond it); the finger box's pair is deleted, or kept at friction 0.05 (`block`)."""
    fingers = _fingers(spec)
    for p, fname, other in list(_grasp_pairs(spec, fingers)):
        body, _ = fingers[fname]
        y = (1.0 if fname.endswith("finger1") else -1.0) * (-0.005 - recess + r)
        for (i, x), (j, z) in itertools.product(enumerate(xs), enumerate(zs)):
            name = f"{fname}_pad{i}{j}"
            if spec.geom(name) is None:
                body.add_geom(name=name, type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[r, 0, 0],
                              pos=[x, y, z], contype=0, conaffinity=0, group=3, density=0.0)
            _pad_pair(spec, name, other, p)
        if block:
            p.friction = [0.05, 0.05, 0.005, 0.0001, 0.0001]
        else:
            spec.delete(p)


def capsule_pads(spec, r, xs, zc, half):
    """Capsules (radius r, half length `half`) along each finger at x in xs, centred at zc."""
    fingers = _fingers(spec)
    for p, fname, other in list(_grasp_pairs(spec, fingers)):
        body, _ = fingers[fname]
        y = (1.0 if fname.endswith("finger1") else -1.0) * (-0.005 + r)
        for i, x in enumerate(xs):
            name = f"{fname}_pad{i}"
            if spec.geom(name) is None:
                body.add_geom(name=name, type=mujoco.mjtGeom.mjGEOM_CAPSULE, size=[r, half, 0],
                              pos=[x, y, zc], contype=0, conaffinity=0, group=3, density=0.0)
            _pad_pair(spec, name, other, p)
        spec.delete(p)


def mesh_fingers(spec):
    """The finger boxes' grasp pairs moved to box-shaped convex meshes of the same size (C:
    general convex collision; MJX: convex-convex manifold)."""
    verts = np.array(list(itertools.product(*[(-h, h) for h in MESH_HALF]))).ravel().tolist()
    spec.add_mesh(name="finger_box_mesh", uservert=verts)
    fingers = _fingers(spec)
    for p in spec.pairs:
        for attr in ("geomname1", "geomname2"):
            fname = getattr(p, attr)
            if fname in fingers and p.friction[0] > 1.0:
                body, g = fingers[fname]
                name = fname + "_mesh"
                if spec.geom(name) is None:
                    body.add_geom(name=name, type=mujoco.mjtGeom.mjGEOM_MESH,
                                  meshname="finger_box_mesh", pos=list(g.pos), contype=0,
                                  conaffinity=0, group=3, density=0.0)
                setattr(p, attr, name)


def mesh_objects(spec):
    """The grasp pairs' object geoms (the other geom of a finger's pair with friction > 1: the
    bar's necks, the pot's handles) moved to box-shaped convex meshes of the same size and pose
    (C: general convex collision, multi-contact unless multiccd is disabled; MJX: convex-convex
    manifold). The boxes stay for the object's inertia and its other pairs."""
    fingers = _fingers(spec)
    geoms = {g.name: (b, g) for b in spec.bodies for g in b.geoms}
    for p, _, other in list(_grasp_pairs(spec, fingers)):
        body, g = geoms[other]
        name = other + "_mesh"
        if spec.geom(name) is None:
            verts = np.array(list(itertools.product(*[(-h, h) for h in g.size[:3]])))
            spec.add_mesh(name=name + "_shape", uservert=verts.ravel().tolist())
            body.add_geom(name=name, type=mujoco.mjtGeom.mjGEOM_MESH, meshname=name + "_shape",
                          pos=list(g.pos), quat=list(g.quat), contype=0, conaffinity=0,
                          group=3, density=0.0)
        if p.geomname1 == other:
            p.geomname1 = name
        else:
            p.geomname2 = name


def recessed_options() -> dict:
    """The recessed pads from the environment: OUT_M (m beyond the face, default 0.001) and
    GRID=dense|spheres (default dense)."""
    grid = os.environ.get("GRID", "dense").replace("coarse", "spheres")
    return dict(SPHERES[grid], recess=float(os.environ.get("OUT_M", "0.001")), block=True)


def edit_for(kind: str):
    """The spec edit of pad kind `kind` (one of PADS)."""
    if kind in SPHERES:
        return lambda spec: sphere_pads(spec, **SPHERES[kind])
    if kind in CAPSULES:
        return lambda spec: capsule_pads(spec, **CAPSULES[kind])
    if kind == "recessed":
        opts = recessed_options()
        return lambda spec: sphere_pads(spec, **opts)
    if kind in ("meshf", "meshf_noccd"):
        return mesh_fingers
    if kind in ("meshneck", "meshneck_noccd"):
        return mesh_objects
    if kind in ("meshf_mjxbox", "meshneck_mjxbox"):
        edit = mesh_fingers if kind == "meshf_mjxbox" else mesh_objects

        def mjxbox(spec):
            edit(spec)
            spec.add_numeric(name=model_lib.MJX_BOX_MESHES, data=[1.0])
        return mjxbox
    if kind == "v4_all_fingers":   # version 4 with every finger pair on the mesh copy
        return lambda spec, scene="scene_pickup.xml": model_lib._physics_v4(spec, scene, -1.0)
    if kind == "v5_all_fingers":   # the same in version 5

        def v5(spec, scene="scene_pickup.xml"):
            model_lib._physics_v4(spec, scene, -1.0)
            model_lib._physics_v5(spec, scene)
        return v5
    if kind == "v6":   # physics version 6 itself (to compare the probes' kinds with)
        return lambda spec, scene="scene_pickup.xml": model_lib.edit_spec(spec, scene, 6)
    if kind == "v6_all_fingers":   # version 6 with every finger pair on the mesh copy

        def v6_all(spec, scene="scene_pickup.xml"):
            model_lib.edit_spec(spec, scene, 6)
            if scene in model_lib.PHYSICS_V4["scenes"]:
                model_lib._mesh_finger_pairs(spec, -1.0)
        return v6_all
    if kind in BLOCKER_WORDS:   # version 6 with some of version 7's blocker pairs

        def v6_some(spec, scene="scene_pickup.xml"):
            model_lib.edit_spec(spec, scene, 6)
            if scene in model_lib.PHYSICS_V7["scenes"]:
                model_lib.mesh_pairs_with(spec, BLOCKER_WORDS[kind])
        return v6_some
    raise ValueError(f"unknown pad kind {kind!r}; one of {', '.join(PADS)}")


def model(kind: str, scene: str, timestep=None, cone=None) -> mujoco.MjModel:
    """The scene's model with pads of `kind`, the task's timestep and cone when given."""
    with model_lib.scene_path(scene) as path:
        spec = mujoco.MjSpec.from_file(str(path))
        if kind in VERSION_KINDS:
            edit_for(kind)(spec, scene)
        else:
            edit_for(kind)(spec)
        m = spec.compile()
    if timestep is not None:
        m.opt.timestep = float(timestep)
    if cone is not None:
        m.opt.cone = model_lib.CONES[cone]
    if kind.endswith("_noccd"):   # mujoco 4: multiccd is on unless disabled
        m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_MULTICCD)
    return m


def like(kind: str, scene: str, reference: mujoco.MjModel) -> mujoco.MjModel:
    """`model` with the timestep and cone of `reference` (the task's own model)."""
    m = model(kind, scene)
    m.opt.timestep, m.opt.cone = reference.opt.timestep, reference.opt.cone
    return m


def finger_geoms(m: mujoco.MjModel) -> np.ndarray:
    """The finger geoms including the pads (for the parity measurement's contact counts)."""
    return np.array([i for i in range(m.ngeom) if "_finger" in (m.geom(i).name or "")])


def _finger_contacts_init(self, model, object_body):
    """grasp_start.FingerContacts.__init__ counting "<finger>_pad*" geoms as the finger."""
    self.model, self.data = model, mujoco.MjData(model)
    self.fingers = {i: f for i in range(model.ngeom) for f in self.FINGERS
                    if model.geom(i).name == f or model.geom(i).name.startswith(f + "_pad")}
    self.body = model.body(object_body).id


def patch(kind: str, scenes=GRASP_SCENES):
    """Every model the package loads of `scenes` carries pads of `kind` (this process only);
    the grasped-start recorder counts the pads as the fingers. With ``recessed``: SETTLE
    (grasp_start.SETTLE_STEPS) and HOLD_HI (the upper end of scripted.HOLD_OPENING) from the
    environment when set."""
    from mjx_envs.tasks import grasp_start, scripted

    edit_for(kind)   # unknown kinds fail here (MJX routes *_mjxbox's meshes as it loads:
    # mjx_envs.physics.mjx_contacts)
    orig = model_lib.load_model

    def load(scene, timestep=None, cone=None, physics_version=None):
        if scene not in scenes:
            return orig(scene, timestep, cone, physics_version)
        return model(kind, scene, timestep, cone)

    grasp_start.FingerContacts.__init__ = _finger_contacts_init
    model_lib.load_model = core.load_model = numpy_env.load_model = load
    if kind == "recessed" and os.environ.get("SETTLE"):
        grasp_start.SETTLE_STEPS = int(os.environ["SETTLE"])
    if kind == "recessed" and os.environ.get("HOLD_HI"):
        scripted.HOLD_OPENING = (scripted.HOLD_OPENING[0], float(os.environ["HOLD_HI"]))
