"""The MJCF scenes as MuJoCo models, in every physics version (MuJoCo and NumPy only: no JAX).

The scenes ship inside the package: ``mjx_envs/assets`` (in a source tree a link to the
top-level ``assets/``) is read through ``importlib.resources``, so an installed wheel finds them
too. Both the JAX env (`mjx_envs.core`) and the NumPy simulator (`mjx_envs.numpy_env`) load
their model here.

Physics versions (the current one: `mjx_envs.settings.PHYSICS_VERSION`, the default of every
task's ``physics_version``). 1: up to 2026-12-04 (5 mm margin on every finger pair, thin finger
boxes, finger-pot body and finger-bar middle/cap friction 0.5 / 1.5). 2: finger boxes 5 mm
larger on every side with margin 0 (MJX's box-box collision ignores contact margins), friction
0.05 on the finger pairs that only block (pot body; bar middle and caps). 3: MJX returns each
box-box contact point once, as the C engine does (the scenes' numeric `MJX_UNIQUE_CONTACTS`,
which the C engine ignores), and pot's finger-handle contacts are softer (solimp 0.9 0.95); on
the C engine, push and pick up act in versions 2 and 3 alike. See docs/MJX_VS_C.md.
4 (opt-in, `mjx_envs.settings.LATEST_PHYSICS_VERSION`): the grasp pairs' fingers as box-shaped
convex meshes, so that a tilted finger gives the same contact points on both engines
(`PHYSICS_V4`). 5 (opt-in): version 4, and MJX collides a box with the table plane at every
penetrating bottom corner, as the C engine does (`PHYSICS_V5`; MJX only). 6 (opt-in): version 5,
and the C engine's Newton line search runs up to 50 iterations where MJX keeps the scene's
(`PHYSICS_V6`; C engine only). 7 (opt-in): version 6, and in pick up every finger pair, not
only the grasp pairs, collides the finger's mesh copy (`PHYSICS_V7`; C engine only). 8
(opt-in): version 6 (not 7), and in pick up the finger pairs with the bar's caps collide the
finger's mesh copy (`PHYSICS_V8`; C engine only). 9 (opt-in): version 8, and the C engine's
pot handle pairs are stiffer (`PHYSICS_V9`; C engine only). The scenes
in assets/ are the current version; `load_model` builds the others from them (version 2:
`PHYSICS_V2`; version 1: that and `PHYSICS_V1`; version 4: `PHYSICS_V4`; version 5: that and
`PHYSICS_V5`; version 6: those and `PHYSICS_V6`; version 7: those and `PHYSICS_V7`; version 8:
version 6's and `PHYSICS_V8`; version 9: version 8's and `PHYSICS_V9`), so that a
run or a policy file acts with the physics it was trained on (`physics_version_note`
says when it does not).
"""

from __future__ import annotations

import contextlib
import copy
import importlib.resources
from collections.abc import Iterator
from pathlib import Path

import mujoco
import numpy as np

from mjx_envs import registry, settings

NUM_ARMS = 2
CONES = {"elliptic": mujoco.mjtCone.mjCONE_ELLIPTIC,
         "pyramidal": mujoco.mjtCone.mjCONE_PYRAMIDAL}

MJX_UNIQUE_CONTACTS = "mjx_unique_contact_points"
"""Name of a scene's custom numeric: 1 = MJX returns each contact point of a box-box or
convex-convex pair once, as the C engine does (`mjx_envs.physics.mjx_contacts`)."""

MJX_BOX_MESHES = "mjx_box_meshes"
"""Name of a scene's custom numeric: 1 = MJX collides a (box, box-shaped mesh) pair with its
box-box collider, the mesh as a box of its geom's size (`mjx_envs.physics.mjx_contacts`)."""

MJX_FINITE_LINESEARCH = "mjx_finite_linesearch"
"""Name of a scene's custom numeric: 1 = MJX's Newton line search treats an elliptic cone's
squared tangential residual that float32 cancels to zero or below as 0, where MJX's own
expression takes the square root of a negative number and the solver stalls at its warm start
(`mjx_envs.physics.mjx_solver`)."""

PHYSICS_V4 = dict(scenes=("scene_pickup.xml", "scene_pot.xml"), grasp_friction=1.0)
"""Physics version 4 (opt-in: `mjx_envs.settings.LATEST_PHYSICS_VERSION`), as differences from
the shipped scenes: in the named scenes each finger pair whose sliding friction exceeds
``grasp_friction`` (the grasp pairs: finger-neck, finger-handle) collides a copy of the finger
box as a box-shaped convex mesh (geom ``<finger>_mesh``: no mass, group 3, in no other pair),
and the scene has the numerics `MJX_BOX_MESHES` and `MJX_FINITE_LINESEARCH`. A tilted finger corner
on a face then gives the same contact points on both engines: the C engine's multi-contact
convex collider (multiccd) where its box-box returns the deepest corner alone, MJX's box-box
(docs/MJX_VS_C.md); and MJX's solver no longer stalls where float32 cancels a cone residual,
which threw the bar in MJX's physics faults (the C engine ignores both numerics)."""

MJX_PLANE_BOX_CORNERS = "mjx_plane_box_corners"
"""Name of a scene's custom numeric: 1 = MJX collides a (plane, box) pair at each of the box's
bottom corners that penetrates the plane, up to 4, as the C engine's ``mjc_PlaneBox`` does
(`mjx_envs.physics.mjx_contacts`); without it MJX keeps only the corners within 1 mm of the
deepest, so a box pressed into the table at a tilt rests on one or two points in MJX and on four
in C. The C engine ignores it."""

PHYSICS_V5 = dict(scenes=PHYSICS_V4["scenes"], numerics=(MJX_PLANE_BOX_CORNERS,))
"""Physics version 5 (opt-in: `mjx_envs.settings.LATEST_PHYSICS_VERSION`), as differences from
version 4: the scenes named here also have the numerics named here. It changes MJX only: on the
C engine version 5 acts as version 4 (docs/MJX_VS_C.md, "Physics version 5")."""

MJX_LS_ITERATIONS = "mjx_ls_iterations"
"""Name of a scene's custom numeric: the line-search iterations MJX's solver takes, where the
model's own ``opt.ls_iterations`` (which the C engine takes) differs (`mjx_model`)."""

PHYSICS_V6 = dict(scenes=PHYSICS_V4["scenes"], c_ls_iterations=50)
"""Physics version 6 (opt-in: `mjx_envs.settings.LATEST_PHYSICS_VERSION`), as differences from
version 5: in the scenes named here the model's ``opt.ls_iterations`` (the C engine's Newton line
search) is ``c_ls_iterations``, and the numeric `MJX_LS_ITERATIONS` keeps MJX at the scene's own
value. The scenes' 15 let the C engine's Newton solver stop early where two fingers press the
object into the table, and the integrator then throws the object (docs/MJX_VS_C.md, "Physics
version 6"). It changes the C engine only: on MJX version 6 acts as version 5, but an MJX run
that trains from grasped starts (``grasp_start_fraction``) starts from other states, since they
are recorded with the C engine (`mjx_envs.tasks.grasp_start`)."""

PHYSICS_V7 = dict(scenes=("scene_pickup.xml",))
"""Physics version 7 (opt-in: `mjx_envs.settings.LATEST_PHYSICS_VERSION`), as differences from
version 6: in the scenes named here every finger pair collides the finger's box-shaped mesh
copy, also the pairs that only block (the bar's middle and caps, friction 0.05), not only the
grasp pairs of version 4. A tilted finger box on the bar's middle got its deepest corner alone
from the C engine's box-box collision where MJX's returns every penetrating corner; the mesh
copy gives the C engine MJX's points (multiccd), and MJX collides the copy as the box it had
(`MJX_BOX_MESHES`), so version 7 changes the C engine only. Pot's scene is left as in version
6: there the same change made the C engine's pot grasps worse (docs/MJX_VS_C.md, "Physics
version 7")."""

PHYSICS_V8 = dict(mesh_blockers={"scene_pickup.xml": ("bar_cap_l", "bar_cap_r")})
"""Physics version 8 (opt-in: `mjx_envs.settings.LATEST_PHYSICS_VERSION`), as differences from
version 6 (not 7): in the scenes named in ``mesh_blockers`` the finger pairs with the named
object geoms collide the finger's box-shaped mesh copy (pick up: the bar's caps, 4 pairs), where
version 7 moved every finger pair (also the bar's middle). On the C engine version 7's middle
pairs cost one MJX-trained policy as much as its cap pairs gained another; with the caps alone
the eight MJX-trained pick-up checkpoints screened came closest to MJX (docs/MJX_VS_C.md,
"Physics version 8"). MJX collides the copies as the boxes they copy (`MJX_BOX_MESHES`), so
version 8 changes the C engine only."""

PHYSICS_V9 = dict(c_pair_solimp={
    "scene_pot.xml": {"pot_handle_l": (0.92, 0.97, 0.001, 0.5, 2.0),
                      "pot_handle_r": (0.92, 0.97, 0.001, 0.5, 2.0)},
})
"""Physics version 9 (opt-in: `mjx_envs.settings.LATEST_PHYSICS_VERSION`), as differences from
version 8: in the scenes named here the C engine's finger pairs with the named object geoms
(pot: the handles, the grasp pairs) get this solimp, stiffer than the scene's (0.9 0.95), and
one numeric per pair (`MJX_PAIR_SOLIMP`) keeps MJX at the scene's own. At the same positions of
a pot grasp MJX's box-box collision returns more points than the C engine's (3.1-3.6 against
2.7-3.4 per finger pair, 5-18 % more summed depth), so MJX's grasp acts stiffer; with the C
engine's handle pairs this much stiffer, four MJX-trained pot checkpoints came within 0.05 of
MJX on the C engine (+0.010 to +0.046), where version 8 left them up to 0.073 above
(docs/MJX_VS_C.md, "Physics version 9"); trained on MJX in version 9, three of three best
and two of three weak pot checkpoints agree, but a C-trained pot policy now leans to the C
engine (+0.077). It changes the C engine only (and the grasped starts of an MJX run, which the
C engine records)."""

MJX_PAIR_SOLIMP = "mjx_pair_solimp:"
"""Prefix of a scene's custom numerics ``mjx_pair_solimp:<geom1>:<geom2>`` (5 values): the
solimp MJX simulates for that pair where the model's own (which the C engine takes) differs
(`mjx_model`; version 9)."""

PHYSICS_V2 = dict(
    pair_solimp={
        "scene_pot.xml": {"pot_handle_l": (0.95, 0.99, 0.001, 0.5, 2.0),
                          "pot_handle_r": (0.95, 0.99, 0.001, 0.5, 2.0)},
    },
)
"""Physics version 2, as differences from the shipped scenes besides the numeric
`MJX_UNIQUE_CONTACTS` (which it lacks): per scene the solimp of the finger pairs with the named
object geoms."""

PHYSICS_V1 = dict(
    finger_size=(0.012, 0.006, 0.035),
    finger_pair_margin=0.005,
    pair_friction={
        "scene_pickup.xml": {"bar_mid": (1.5, 1.5, 0.01, 0.0001, 0.0001),
                             "bar_cap_l": (1.5, 1.5, 0.01, 0.0001, 0.0001),
                             "bar_cap_r": (1.5, 1.5, 0.01, 0.0001, 0.0001)},
        "scene_pot.xml": {"pot_body": (0.5, 0.5, 0.005, 0.0001, 0.0001)},
    },
)
"""Physics version 1, as differences from the shipped scenes: the half-sizes of every finger
box (geoms ``<arm>_finger1/2``), the margin of every contact pair with a finger, and per scene
the friction of the finger pairs with the named object geoms."""


def physics_changed(version: int, task: str, engine: str | None = None) -> bool:
    """Whether physics `version` changed how `task` acts on `engine` ("c", "mjx"; None: either):
    versions 2 and 3 changed the finger contacts, so every task with an object (reach and unknown
    tasks: no); on the C engine version 3 changed only the scenes `PHYSICS_V2` names; version 4
    the scenes `PHYSICS_V4` names, on both engines; version 5 those of `PHYSICS_V5`, on MJX;
    version 6 those of `PHYSICS_V6`, on the C engine; version 7 those of `PHYSICS_V7`, on the C
    engine; version 8 those of `PHYSICS_V8`, on the C engine (against version 7: the scenes of
    both, whose C engine they change back or anew); version 9 those of `PHYSICS_V9`, on the C
    engine."""
    if version in (6, 7, 8, 9):   # the C engine only
        scenes = {6: PHYSICS_V6["scenes"], 7: PHYSICS_V7["scenes"],
                  8: tuple(PHYSICS_V8["mesh_blockers"]),
                  9: tuple(PHYSICS_V9["c_pair_solimp"])}[version]
        return (engine != "mjx" and registry.is_task(task)
                and registry.get(task).config.scene in scenes)
    if version == 5:
        return (engine != "c" and registry.is_task(task)
                and registry.get(task).config.scene in PHYSICS_V5["scenes"])
    if version == 4:
        return registry.is_task(task) and registry.get(task).config.scene in PHYSICS_V4["scenes"]
    if version == 3 and engine == "c":
        return (registry.is_task(task) and registry.get(task).config.scene
                in PHYSICS_V2["pair_solimp"])
    return (version in (2, 3) and registry.is_task(task)
            and registry.get(task).object is not None)


def physics_version_note(recorded, task: str, simulated: int | None = None,
                         engine: str | None = None) -> str | None:
    """None when a run or a policy file of `task`, trained with physics version `recorded`, is
    simulated (version `simulated`, default `settings.PHYSICS_VERSION`) with physics that act
    alike on `engine` (None: on either engine); else one line saying which version it was
    trained with and which one simulates it."""
    version = settings.recorded_physics_version(recorded)
    now = settings.PHYSICS_VERSION if simulated is None else int(simulated)
    lo, hi = sorted((version, now))
    if not any(physics_changed(v, task, engine) for v in range(lo + 1, hi + 1)):
        return None
    return (f"trained with physics version {version}, simulated here with version {now} "
            f"(docs/MJX_VS_C.md): its success can differ from the figures logged in "
            f"training")


def _assets():
    return importlib.resources.files("mjx_envs") / "assets"


def scenes() -> list[str]:
    """Names of the MJCF files shipped in ``mjx_envs/assets``."""
    assets = _assets()
    if not assets.is_dir():
        return []
    return sorted(p.name for p in assets.iterdir() if p.name.endswith(".xml"))


@contextlib.contextmanager
def scene_path(scene: str) -> Iterator[Path]:
    """A real file path of ``scene`` for the duration of the ``with`` block.

    Scenes include other files of the folder, so the whole assets folder is made available
    (``importlib.resources.as_file``; a plain installed package or source tree is used in place).
    Raises FileNotFoundError naming the available scenes when ``scene`` is not shipped.
    """
    assets = _assets()
    if not (assets / scene).is_file():
        raise FileNotFoundError(f"scene {scene!r} not found in the package's assets "
                                f"(mjx_envs/assets); available: {scenes()}")
    with importlib.resources.as_file(assets) as folder:
        yield Path(folder) / scene


def load_model(scene: str, timestep: float | None = None, cone: str | None = None,
               physics_version: int | None = None) -> mujoco.MjModel:
    """The scene's model with the task's ``timestep`` and friction ``cone`` (when given), in
    physics version ``physics_version`` (default: the current one, the scene as shipped; the
    others apply this module's record of what they change instead, e.g. `PHYSICS_V1`)."""
    if cone is not None and cone not in CONES:
        raise ValueError(f"cone must be one of {sorted(CONES)}, got {cone!r}")
    version = check_version(physics_version)
    with scene_path(scene) as path:
        if version == settings.PHYSICS_VERSION:
            m = mujoco.MjModel.from_xml_path(str(path))
        else:
            spec = mujoco.MjSpec.from_file(str(path))
            edit_spec(spec, scene, version)
            m = spec.compile()
    if version >= 4:
        check_box_meshes(m)
    if timestep is not None:
        m.opt.timestep = float(timestep)
    if cone is not None:
        m.opt.cone = CONES[cone]
    return m


def check_version(physics_version: int | None) -> int:
    """The physics version asked for (None: the current one); ValueError outside [1, latest]."""
    version = settings.PHYSICS_VERSION if physics_version is None else int(physics_version)
    if not 1 <= version <= settings.LATEST_PHYSICS_VERSION:
        raise ValueError(f"physics_version must be in [1, {settings.LATEST_PHYSICS_VERSION}], "
                         f"got {physics_version!r}")
    return version


def edit_spec(spec: mujoco.MjSpec, scene: str, version: int) -> None:
    """Turns a shipped scene's spec (the current physics version) into ``version``'s."""
    if version < 3:
        _physics_v2(spec, scene)
    if version == 1:
        _physics_v1(spec, scene)
    if version >= 4:
        _physics_v4(spec, scene)
    if version >= 5:
        _physics_v5(spec, scene)
    if version >= 6:
        _physics_v6(spec, scene)
    if version == 7:
        _physics_v7(spec, scene)
    if version >= 8:
        _physics_v8(spec, scene)
    if version >= 9:
        _physics_v9(spec, scene)


def _is_finger(name: str) -> bool:
    return name.endswith(("_finger1", "_finger2"))


def _physics_v2(spec: mujoco.MjSpec, scene: str) -> None:
    """Turns a shipped scene's spec (physics version 3) into version 2 (`PHYSICS_V2`): without
    the numeric that makes MJX return each box-box contact point once
    (`MJX_UNIQUE_CONTACTS`), with version 2's finger-pair solimp."""
    for numeric in list(spec.numerics):
        if numeric.name == MJX_UNIQUE_CONTACTS:
            spec.delete(numeric)
    _finger_pairs(spec, "solimp", PHYSICS_V2["pair_solimp"].get(scene, {}))


def _finger_pairs(spec: mujoco.MjSpec, field: str, values: dict) -> None:
    """Sets ``field`` (e.g. "friction") of every finger pair with an object geom named in
    ``values`` to that geom's value."""
    for pair in spec.pairs:
        names = (pair.geomname1, pair.geomname2)
        if any(_is_finger(n) for n in names):
            for n in names:
                if n in values:
                    setattr(pair, field, values[n])


def _physics_v1(spec: mujoco.MjSpec, scene: str) -> None:
    """Turns a version-2 spec (`_physics_v2`) into version 1 (`PHYSICS_V1`)."""
    v1 = PHYSICS_V1
    for geom in spec.geoms:
        if _is_finger(geom.name):
            geom.size = v1["finger_size"]
    for pair in spec.pairs:
        if any(_is_finger(n) for n in (pair.geomname1, pair.geomname2)):
            pair.margin = v1["finger_pair_margin"]
    _finger_pairs(spec, "friction", v1["pair_friction"].get(scene, {}))


def _physics_v4(spec: mujoco.MjSpec, scene: str, grasp_friction: float | None = None) -> None:
    """Turns a shipped scene's spec into version 4 (`PHYSICS_V4`); with ``grasp_friction``, the
    finger pairs above that friction get the mesh copy instead (the engine probes' variants)."""
    if scene not in PHYSICS_V4["scenes"]:
        return
    _mesh_finger_pairs(spec, PHYSICS_V4["grasp_friction"] if grasp_friction is None
                       else grasp_friction)
    spec.add_numeric(name=MJX_BOX_MESHES, data=[1.0])
    spec.add_numeric(name=MJX_FINITE_LINESEARCH, data=[1.0])


def _mesh_finger_pairs(spec: mujoco.MjSpec, above_friction: float) -> None:
    """Every pair of a finger box whose sliding friction exceeds ``above_friction`` names the
    finger's box-shaped convex mesh copy instead (geom ``<finger>_mesh``, made on first use:
    same body and pose, no mass, group 3, in no other pair)."""
    fingers = {g.name: (b, g) for b in spec.bodies for g in b.geoms if _is_finger(g.name)}
    meshes: dict[tuple, str] = {}   # half sizes -> the mesh already made (version 4's)
    for mesh in spec.meshes:
        if mesh.name.startswith("finger_box_"):
            v = np.asarray(mesh.uservert, np.float64).reshape(-1, 3)
            meshes[tuple(float(x) for x in v.max(axis=0))] = mesh.name
    for pair in spec.pairs:
        for attr in ("geomname1", "geomname2"):
            name = getattr(pair, attr)
            if name not in fingers or pair.friction[0] <= above_friction:
                continue
            body, geom = fingers[name]
            if spec.geom(name + "_mesh") is None:
                half = tuple(float(x) for x in geom.size[:3])
                if half not in meshes:
                    meshes[half] = f"finger_box_{len(meshes)}"
                    corners = [(x, y, z) for x in (-half[0], half[0])
                               for y in (-half[1], half[1]) for z in (-half[2], half[2])]
                    spec.add_mesh(name=meshes[half],
                                  uservert=np.asarray(corners, np.float64).ravel().tolist())
                body.add_geom(name=name + "_mesh", type=mujoco.mjtGeom.mjGEOM_MESH,
                              meshname=meshes[half], pos=list(geom.pos), quat=list(geom.quat),
                              contype=0, conaffinity=0, group=3, density=0.0)
            setattr(pair, attr, name + "_mesh")


def _physics_v5(spec: mujoco.MjSpec, scene: str) -> None:
    """Turns a version-4 spec (`_physics_v4`) into version 5 (`PHYSICS_V5`)."""
    if scene in PHYSICS_V5["scenes"]:
        for name in PHYSICS_V5["numerics"]:
            spec.add_numeric(name=name, data=[1.0])


def _physics_v6(spec: mujoco.MjSpec, scene: str) -> None:
    """Turns a version-5 spec (`_physics_v5`) into version 6 (`PHYSICS_V6`)."""
    if scene in PHYSICS_V6["scenes"]:
        spec.add_numeric(name=MJX_LS_ITERATIONS, data=[float(spec.option.ls_iterations)])
        spec.option.ls_iterations = int(PHYSICS_V6["c_ls_iterations"])


def _physics_v7(spec: mujoco.MjSpec, scene: str) -> None:
    """Turns a version-6 spec (`_physics_v6`) into version 7 (`PHYSICS_V7`)."""
    if scene in PHYSICS_V7["scenes"]:
        _mesh_finger_pairs(spec, -1.0)


def _physics_v8(spec: mujoco.MjSpec, scene: str) -> None:
    """Turns a version-6 spec (`_physics_v6`) into version 8 (`PHYSICS_V8`)."""
    mesh_pairs_with(spec, PHYSICS_V8["mesh_blockers"].get(scene, ()))


def _physics_v9(spec: mujoco.MjSpec, scene: str) -> None:
    """Turns a version-8 spec (`_physics_v8`) into version 9 (`PHYSICS_V9`): the C engine's
    solimp on the named finger pairs, MJX's (the spec's own) in one numeric per pair."""
    values = PHYSICS_V9["c_pair_solimp"].get(scene, {})
    for pair in spec.pairs:
        names = (pair.geomname1, pair.geomname2)
        hit = [n for n in names if n in values]
        if not hit or not any(_is_finger(n.removesuffix("_mesh")) for n in names):
            continue
        spec.add_numeric(name=f"{MJX_PAIR_SOLIMP}{names[0]}:{names[1]}",
                         data=[float(x) for x in pair.solimp])
        pair.solimp = list(values[hit[0]])


def mesh_pairs_with(spec: mujoco.MjSpec, objects) -> None:
    """The finger pairs with a geom named in ``objects`` name the finger's mesh copy (which
    version 4 made; ValueError without one)."""
    copies = {g.name for b in spec.bodies for g in b.geoms if g.name.endswith("_mesh")}
    for pair in spec.pairs:
        names = (pair.geomname1, pair.geomname2)
        if not any(n in objects for n in names):
            continue
        for attr, name in zip(("geomname1", "geomname2"), names, strict=True):
            if _is_finger(name):
                if name + "_mesh" not in copies:   # version 4 made one per finger
                    raise ValueError(f"finger {name} has no mesh copy")
                setattr(pair, attr, name + "_mesh")


def mjx_model(m: mujoco.MjModel) -> mujoco.MjModel:
    """The model MJX simulates for ``m`` (the C engine simulates ``m`` itself): ``m``, or where
    ``m`` has the numeric `MJX_LS_ITERATIONS` (version 6) or `MJX_PAIR_SOLIMP` ones (version
    9), a copy with that many line-search iterations and those pairs' solimp."""
    out = None
    for i in range(m.nnumeric):
        name, data = m.numeric(i).name, m.numeric(i).data
        if name == MJX_LS_ITERATIONS:
            out = copy.copy(m) if out is None else out
            out.opt.ls_iterations = int(round(float(data[0])))
        elif name.startswith(MJX_PAIR_SOLIMP):
            geoms = tuple(name[len(MJX_PAIR_SOLIMP):].split(":"))
            pair = [j for j in range(m.npair) if (m.geom(int(m.pair_geom1[j])).name,
                                                  m.geom(int(m.pair_geom2[j])).name) == geoms]
            if not pair or len(data) != m.pair_solimp.shape[1]:
                raise ValueError(f"numeric {name!r}: no such pair, or not "
                                 f"{m.pair_solimp.shape[1]} values")
            out = copy.copy(m) if out is None else out
            out.pair_solimp[pair[0]] = data
    return m if out is None else out


def check_box_meshes(m: mujoco.MjModel, tol: float = 1e-6) -> None:
    """ValueError unless every mesh geom of ``m`` is a box of its geom's size (8 vertices at
    +-size in the geom's frame): MJX collides them as such boxes (`MJX_BOX_MESHES`)."""
    for g in range(m.ngeom):
        if m.geom_type[g] != mujoco.mjtGeom.mjGEOM_MESH:
            continue
        i = int(m.geom_dataid[g])
        v = m.mesh_vert[m.mesh_vertadr[i]:m.mesh_vertadr[i] + m.mesh_vertnum[i]]
        if len(v) != 8 or np.abs(np.abs(v) - m.geom_size[g]).max() > tol:
            raise ValueError(f"geom {m.geom(g).name!r}: its mesh is not a box of its size")


def home_state(model: mujoco.MjModel) -> tuple[np.ndarray, np.ndarray]:
    """(qpos [nq], gripper targets [2, 3]) of the scene's ``home`` keyframe, float32."""
    key = model.key("home")
    qpos = np.asarray(key.qpos, np.float32)
    mocap = np.asarray(key.mpos, np.float32).reshape(-1, 3)[:NUM_ARMS]
    return qpos, mocap
