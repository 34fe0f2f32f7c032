"""Physics versions: the current scenes and version 1's (`mjx_envs.model.PHYSICS_V1`,
applied by `mjx_envs.model.load_model`), so that older runs and policy files act with the
physics they were trained on. tests/data/physics_v1.npz holds, per scene, every model array in
which version 1's MJCF files (git 5157332^, assets/) differed from today's, compiled by MuJoCo:
version 1 as built here must equal them and agree with today's model everywhere else."""

from __future__ import annotations

import os

import mujoco
import numpy as np
import pytest

import mjx_envs
from daddpg_jax.cli import evaluate as evaluate_cli
from mjx_envs import registry, settings
from mjx_envs.model import (
    MJX_BOX_MESHES,
    MJX_FINITE_LINESEARCH,
    MJX_LS_ITERATIONS,
    MJX_PAIR_SOLIMP,
    MJX_UNIQUE_CONTACTS,
    PHYSICS_V1,
    PHYSICS_V4,
    PHYSICS_V6,
    PHYSICS_V7,
    PHYSICS_V8,
    PHYSICS_V9,
    check_box_meshes,
    load_model,
    mjx_model,
    physics_changed,
    physics_version_note,
)
from mjx_envs.numpy_env import NumpyDualArmEnv
from mjx_envs.schema import ConfigError

V1 = os.path.join(os.path.dirname(os.path.abspath(__file__)), "data", "physics_v1.npz")
SCENES = ("scene_reach.xml", "scene_push.xml", "scene_pickup.xml", "scene_pot.xml")


@pytest.fixture(scope="module")
def recorded():
    with np.load(V1) as f:
        return {k: f[k] for k in f.files}


def _arrays(m) -> dict:
    out = {}
    for name in dir(m):
        if name.startswith("_"):
            continue
        try:
            v = getattr(m, name)
        except Exception:   # noqa: BLE001 (properties some builds do not have)
            continue
        if isinstance(v, np.ndarray):
            out[name] = v
    return out


@pytest.mark.parametrize("scene", SCENES)
def test_version_1_is_the_recorded_scene(scene, recorded):
    """Every array version 1 changed equals the record; every other equals version 2's (the
    record was taken when version 2 was current) (~0.2 s)."""
    old = _arrays(load_model(scene, physics_version=1))
    new = _arrays(load_model(scene, physics_version=2))
    changed = {k.split("/", 1)[1]: v for k, v in recorded.items()
               if k.startswith(scene[:-4] + "/")}
    assert {"geom_size", "geom_rbound"} <= set(changed)   # the finger boxes, in every scene
    for name, v in changed.items():
        np.testing.assert_array_equal(old[name], v, err_msg=name)
        assert not np.array_equal(new[name], v), name
    for name in set(old) - set(changed):
        np.testing.assert_array_equal(old[name], new[name], err_msg=name)


NUMERIC_ARRAYS = {"numeric_adr", "numeric_size", "numeric_data", "name_numericadr", "names",
                  "names_map"}
"""the arrays that hold a custom numeric: its address, size, value and name"""


@pytest.mark.parametrize("scene", SCENES)
def test_version_2_is_today_s_scene_without_version_3_s_changes(scene):
    """Version 3 adds `MJX_UNIQUE_CONTACTS` = 1 (the C engine ignores it) and softens
    pot's four finger-handle pairs; version 2 as built here lacks the numeric and has their old
    solimp: every other array is equal (~0.2 s)."""
    v2, v3 = load_model(scene, physics_version=2), load_model(scene)
    assert v2.nnumeric == 0 and v3.nnumeric == 1
    assert v3.numeric(MJX_UNIQUE_CONTACTS).data.tolist() == [1.0]
    old, new = _arrays(v2), _arrays(v3)
    assert set(old) == set(new)
    handles = [i for i in range(v3.npair) if "pot_handle" in v3.geom(int(v3.pair_geom2[i])).name]
    assert len(handles) == (4 if scene == "scene_pot.xml" else 0)
    for i in handles:
        assert old["pair_solimp"][i][:2].tolist() == [0.95, 0.99]
        assert new["pair_solimp"][i][:2].tolist() == [0.9, 0.95]
        new["pair_solimp"][i] = old["pair_solimp"][i]
    for name in set(old) - NUMERIC_ARRAYS:
        if name.startswith("name_") and name.endswith("adr"):   # addresses into `names`
            assert _names(v2, old[name]) == _names(v3, new[name]), name
        else:
            np.testing.assert_array_equal(old[name], new[name], err_msg=name)


def _names(m, addresses) -> list[str]:
    buf = bytes(m.names)
    return [buf[a:buf.index(b"\0", a)].decode() for a in addresses.tolist()]


def test_version_1_differs_where_the_record_says():
    """The finger pairs' margin and the blocking pairs' friction of version 1 (~0.2 s)."""
    v1 = PHYSICS_V1
    m = load_model("scene_pickup.xml", physics_version=1)
    names = [(m.geom(int(a)).name, m.geom(int(b)).name) for a, b in
             zip(m.pair_geom1, m.pair_geom2, strict=True)]
    for i, pair in enumerate(names):
        finger = any(n.endswith(("_finger1", "_finger2")) for n in pair)
        assert m.pair_margin[i] == (v1["finger_pair_margin"] if finger else 0.0)
        if finger and ("bar_mid" in pair or "bar_cap_l" in pair or "bar_cap_r" in pair):
            assert m.pair_friction[i][0] == 1.5
    assert load_model("scene_pickup.xml").pair_margin.max() == 0.0


def test_envs_build_the_version_they_are_given():
    """The JAX env (C backend, no compile) and the NumPy simulator take ``physics_version``
    (~1 s)."""
    v1 = np.asarray(PHYSICS_V1["finger_size"])
    env = mjx_envs.make("push", physics="c", physics_version=1)
    sim = NumpyDualArmEnv(registry.task_config("push", physics_version=1), task="push")
    now = NumpyDualArmEnv(registry.default_config("push"), task="push")
    for model in (env.mj_model, sim.model):
        np.testing.assert_allclose(model.geom_size[model.geom("l_finger1").id], v1)
    assert now.model.geom_size[now.model.geom("l_finger1").id][0] > v1[0]
    assert registry.default_config("push").physics_version == settings.PHYSICS_VERSION


def test_an_unknown_version_is_refused(capsys):
    """Out of range: ValueError, ConfigError, and one line + exit 2 from daddpg-evaluate (~0 s)."""
    for bad in (0, settings.LATEST_PHYSICS_VERSION + 1):
        with pytest.raises(ValueError, match="physics_version"):
            load_model("scene_push.xml", physics_version=bad)
        with pytest.raises(ConfigError, match="physics_version"):
            registry.task_config("push", physics_version=bad)
        assert evaluate_cli.main(["no_such_run", "--physics-version", str(bad)]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "--physics-version must be in" in err


def _options(m) -> dict:
    return {k: np.copy(getattr(m.opt, k)) for k in dir(m.opt)
            if not k.startswith("_") and not callable(getattr(m.opt, k))}


@pytest.mark.parametrize("task", ["pickup", "pot", "push"])
def test_version_6_lengthens_the_c_engine_s_line_search_only(task):
    """Version 6 (opt-in): in pick up's and pot's scenes the model (what the C engine, the
    NumPy simulator and the JAX env's C backend simulate) has 50 line-search iterations, and
    the model MJX simulates (`mjx_model`, which `MjxBackend` puts) is version 5's in every array
    and option; push is version 5 exactly (~2 s, MJX imported, nothing compiled)."""
    from mjx_envs.physics import backends

    cfg = registry.task_config(task, physics_version=6)
    v5, v6 = load_model(cfg.scene, physics_version=5), load_model(cfg.scene, physics_version=6)
    a5 = _arrays(v5)
    mj = mjx_model(v6)
    if cfg.scene not in PHYSICS_V6["scenes"]:
        assert mj is v6
        for k, value in _options(v6).items():
            np.testing.assert_array_equal(_options(v5)[k], value, err_msg=k)
        for name, value in _arrays(v6).items():
            np.testing.assert_array_equal(a5[name], value, err_msg=name)
        assert not physics_changed(6, task)
        return
    assert v5.opt.ls_iterations == 15 and v6.opt.ls_iterations == PHYSICS_V6["c_ls_iterations"]
    assert v6.numeric(MJX_LS_ITERATIONS).data.tolist() == [15.0]
    assert mj is not v6 and v6.opt.ls_iterations == 50   # a copy: v6 itself unchanged
    o5, o6 = _options(v5), _options(mj)
    assert o5.keys() == o6.keys()
    for k in o5:
        np.testing.assert_array_equal(o5[k], o6[k], err_msg=k)
    for name, value in _arrays(mj).items():
        if not name.startswith(("numeric", "name_numericadr", "names", "name_")):
            np.testing.assert_array_equal(a5[name], value, err_msg=name)
    assert physics_changed(6, task, "c") and not physics_changed(6, task, "mjx")
    assert physics_version_note(5, task, simulated=6, engine="mjx") is None
    assert physics_version_note(5, task, simulated=6, engine="c") is not None
    # every engine's entry point
    env = mjx_envs.make(task, physics="c", physics_version=6)
    sim = NumpyDualArmEnv(cfg, task=task)
    assert env.mj_model.opt.ls_iterations == sim.model.opt.ls_iterations == 50
    mjx_backend = backends.MjxBackend(v6, cfg.n_substeps)
    assert int(mjx_backend.model.opt.ls_iterations) == 15
    assert backends.CBackend(v6, cfg.n_substeps, nthread=1).mj_model.opt.ls_iterations == 50


@pytest.mark.parametrize("task", ["pickup", "pot", "push"])
def test_version_7_meshes_every_finger_pair_of_pick_up(task):
    """Version 7 (opt-in): in pick up's scene every finger pair, also the bar's middle and caps
    (friction 0.05), names the finger's mesh copy, which version 4 made for the grasp pairs (no
    new geom or mesh); every friction, solref, solimp and option is version 6's. Pot and push
    are version 6 exactly. The change is the C engine's only: MJX collides the copies as the
    boxes they copy (`MJX_BOX_MESHES`; the same 300 episodes on MJX in docs/MJX_VS_C.md,
    "Physics version 7") (~1 s)."""
    models = _c_engine_change(task, 6, 7, PHYSICS_V7["scenes"])
    if models is None:
        return
    _, v6, v7 = models
    moved = _pairs_moved_to_mesh_copies(v6, v7)
    assert len(moved) == 8   # 4 fingers x (the bar's middle, their cap)
    assert not any(v7.geom(int(g)).name.endswith(("_finger1", "_finger2"))
                   for g in (*v7.pair_geom1, *v7.pair_geom2))


def _c_engine_change(task, old: int, new: int, scenes):
    """(task config, model in version ``old``, in version ``new``) where version ``new``
    changes ``task``'s scene (in ``scenes``), having checked that it changes the C engine only
    and that a run of version ``old`` simulated in ``new`` is warned on the C engine alone;
    None, having checked that every array is ``old``'s and no change is reported, elsewhere."""
    cfg = registry.task_config(task, physics_version=new)
    mo, mn = load_model(cfg.scene, physics_version=old), load_model(cfg.scene, physics_version=new)
    if cfg.scene not in scenes:
        ao, an = _arrays(mo), _arrays(mn)
        for name in ao:
            np.testing.assert_array_equal(ao[name], an[name], err_msg=name)
        assert not physics_changed(new, task)
        return None
    assert physics_changed(new, task, "c") and not physics_changed(new, task, "mjx")
    assert physics_version_note(old, task, simulated=new, engine="mjx") is None
    assert physics_version_note(old, task, simulated=new, engine="c") is not None
    return cfg, mo, mn


def _pairs_moved_to_mesh_copies(v6, vn) -> list[tuple[str, str]]:
    """The pairs whose geoms differ between models ``v6`` and ``vn`` (by ``v6``'s geom names),
    having checked that each names the fingers' mesh copies instead of their boxes, that no geom,
    mesh or pair was added, and that every other array and option is ``v6``'s."""
    assert (vn.ngeom, vn.nmesh, vn.npair) == (v6.ngeom, v6.nmesh, v6.npair)
    check_box_meshes(vn)
    moved = []
    for i in range(v6.npair):
        n6 = (v6.geom(int(v6.pair_geom1[i])).name, v6.geom(int(v6.pair_geom2[i])).name)
        nn = (vn.geom(int(vn.pair_geom1[i])).name, vn.geom(int(vn.pair_geom2[i])).name)
        if nn != n6:
            moved.append(n6)
            assert nn == tuple(n + "_mesh" if n.endswith(("_finger1", "_finger2")) else n
                               for n in n6)
    a6, an = _arrays(v6), _arrays(vn)
    for name in a6:
        if not name.startswith(("pair_geom", "pair_signature")):
            np.testing.assert_array_equal(a6[name], an[name], err_msg=name)
    o6, on = _options(v6), _options(vn)
    for k in o6:
        np.testing.assert_array_equal(o6[k], on[k], err_msg=k)
    return moved


@pytest.mark.parametrize("task", ["pickup", "pot"])
def test_version_8_meshes_pick_up_s_cap_pairs_on_version_6(task):
    """Version 8 (opt-in) is version 6 (not 7) with pick up's four finger-cap pairs on the
    fingers' mesh copies: the grasp pairs stay on the copies (version 4), the finger-middle
    pairs stay boxes, nothing else changes. Pot is version 6 exactly. A C-engine change only;
    between versions 7 and 8 the C engine of pick up changes (the middle pairs go back) (~1 s)."""
    models = _c_engine_change(task, 6, 8, PHYSICS_V8["mesh_blockers"])
    if models is None:
        return
    cfg, v6, v8 = models
    assert physics_version_note(7, task, simulated=8, engine="c") is not None
    moved = _pairs_moved_to_mesh_copies(v6, v8)
    assert sorted(moved) == sorted((f"{a}_finger{k}", f"bar_cap_{a}") for a in "lr"
                                   for k in (1, 2))
    from experiments.engine_parity import pads  # the screen's kind is version 8's scene

    a8, screened = _arrays(v8), _arrays(pads.model("v6_cap_fingers", cfg.scene))
    for name in a8:
        np.testing.assert_array_equal(a8[name], screened[name], err_msg=name)


@pytest.mark.parametrize("task", ["pot", "pickup", "push"])
def test_version_9_stiffens_pot_s_handle_pairs_on_the_c_engine_only(task):
    """Version 9 (opt-in) is version 8 with pot's four finger-handle pairs at solimp 0.92 0.97 on
    the C engine; MJX simulates version 8's (one numeric per pair, `mjx_model`), so every
    array of MJX's model is version 8's. Pick up and push are version 8 exactly (~1 s)."""
    models = _c_engine_change(task, 8, 9, PHYSICS_V9["c_pair_solimp"])
    if models is None:
        return
    cfg, v8, v9 = models
    a8, a9 = _arrays(v8), _arrays(v9)
    names = [(v9.geom(int(v9.pair_geom1[i])).name, v9.geom(int(v9.pair_geom2[i])).name)
             for i in range(v9.npair)]
    stiffer = [i for i in range(v9.npair) if not np.array_equal(v8.pair_solimp[i],
                                                                 v9.pair_solimp[i])]
    assert sorted(names[i] for i in stiffer) == sorted(
        (f"{a}_finger{k}_mesh", f"pot_handle_{a}") for a in "lr" for k in (1, 2))
    for i in stiffer:
        np.testing.assert_allclose(v9.pair_solimp[i], (0.92, 0.97, 0.001, 0.5, 2.0))
        np.testing.assert_allclose(v8.pair_solimp[i], (0.9, 0.95, 0.001, 0.5, 2.0))
    extra = [v9.numeric(i).name for i in range(v9.nnumeric)
             if v9.numeric(i).name.startswith(MJX_PAIR_SOLIMP)]
    assert sorted(extra) == sorted(f"{MJX_PAIR_SOLIMP}{a}:{b}" for a, b in
                                   (names[i] for i in stiffer))
    for name in a8:   # the C engine: the handle pairs' solimp and the numerics, nothing else
        if not name.startswith(("pair_solimp", "numeric", "name_numericadr", "names", "name_",
                                "nnumeric")):
            np.testing.assert_array_equal(a8[name], a9[name], err_msg=name)
    m8, m9 = _arrays(mjx_model(v8)), _arrays(mjx_model(v9))
    for name in m8:   # MJX: version 8's model, but for the numerics that say so
        if not name.startswith(("numeric", "name_numericadr", "names", "name_", "nnumeric")):
            np.testing.assert_array_equal(m8[name], m9[name], err_msg=name)
    o8, o9 = _options(mjx_model(v8)), _options(mjx_model(v9))
    for k in o8:
        np.testing.assert_array_equal(o8[k], o9[k], err_msg=k)
    assert NumpyDualArmEnv(cfg, task=task).model.pair_solimp[stiffer[0]][1] == pytest.approx(0.97)
    bad = mujoco.MjSpec.from_string(
        "<mujoco><custom><numeric name='mjx_pair_solimp:a:b' data='1 2 3 4 5'/></custom>"
        "<worldbody><geom name='a' size='1'/></worldbody></mujoco>").compile()
    with pytest.raises(ValueError, match="no such pair"):
        mjx_model(bad)


def _corners(m, g) -> np.ndarray:
    """The 8 corners of box (or box-shaped mesh) geom ``g`` in its body's frame, sorted."""
    rot = np.empty(9)
    mujoco.mju_quat2Mat(rot, m.geom_quat[g])
    signs = np.array([(x, y, z) for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)])
    pts = m.geom_pos[g] + (signs * m.geom_size[g]) @ rot.reshape(3, 3).T
    return pts[np.lexsort(np.round(pts, 6).T)]


@pytest.mark.parametrize("scene", SCENES)
def test_version_4_meshes_the_grasp_pairs_fingers(scene):
    """Version 4 (opt-in) adds, in pick up's and pot's scenes, a box-shaped mesh copy of each
    finger box (same body, pose and size, no mass, in no other pair) and moves the four grasp
    pairs (friction > 1) to it, plus the numerics `MJX_BOX_MESHES` and `MJX_FINITE_LINESEARCH`;
    every other pair, geom and body is version 3's; push and reach are version 3 exactly
    (~0.3 s)."""
    v3, v4 = load_model(scene), load_model(scene, physics_version=4)
    if scene not in PHYSICS_V4["scenes"]:
        a3, a4 = _arrays(v3), _arrays(v4)
        for name in a3:
            np.testing.assert_array_equal(a3[name], a4[name], err_msg=name)
        assert not physics_changed(4, {"scene_push.xml": "push"}.get(scene, "reach"))
        return
    assert physics_changed(4, {"scene_pickup.xml": "pickup"}.get(scene, "pot"))
    assert v4.numeric(MJX_BOX_MESHES).data.tolist() == [1.0]
    assert v4.numeric(MJX_FINITE_LINESEARCH).data.tolist() == [1.0]
    check_box_meshes(v4)
    meshes = [g for g in range(v4.ngeom) if v4.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH]
    assert len(meshes) == 4 and v4.ngeom == v3.ngeom + 4 and v4.npair == v3.npair
    for g in meshes:
        finger = v4.geom(v4.geom(g).name.removesuffix("_mesh")).id
        assert v4.geom_bodyid[g] == v4.geom_bodyid[finger]
        # MuJoCo turns a mesh to its principal axes (sizes permuted, the quat turned with them):
        # the same box means the same corners in the body's frame
        np.testing.assert_allclose(_corners(v4, g), _corners(v4, finger), atol=1e-6)
        assert v4.geom_contype[g] == v4.geom_conaffinity[g] == 0
    np.testing.assert_array_equal(v3.body_mass, v4.body_mass)
    np.testing.assert_allclose(v3.body_inertia, v4.body_inertia)
    moved = 0
    for i in range(v3.npair):
        n3 = (v3.geom(int(v3.pair_geom1[i])).name, v3.geom(int(v3.pair_geom2[i])).name)
        n4 = (v4.geom(int(v4.pair_geom1[i])).name, v4.geom(int(v4.pair_geom2[i])).name)
        grasp = v3.pair_friction[i][0] > PHYSICS_V4["grasp_friction"] and any(
            n.endswith(("_finger1", "_finger2")) for n in n3)
        assert n4 == tuple(n + "_mesh" if grasp and n.endswith(("_finger1", "_finger2"))
                           else n for n in n3)
        np.testing.assert_array_equal(v3.pair_friction[i], v4.pair_friction[i])
        np.testing.assert_array_equal(v3.pair_solimp[i], v4.pair_solimp[i])
        moved += grasp
    assert moved == 4


@pytest.mark.mjx
def test_version_4_gives_both_engines_the_same_contact_points():
    """A finger pressed into a bar neck at 24 tilts (flat, about one axis, about two; the
    experiments' static probe, experiments/engine_parity/manifold_static.py) as version 4
    collides it, a box-shaped mesh with MJX's routing: the C engine (multi-contact convex) and
    MJX (its box-box, physics version 3's unique points) return as many points at every pose,
    with summed depths within 0.02 mm (MJX in float32). As boxes (version 3), the C engine
    returns one corner where MJX returns two or three at some of them (~40 s: one compile)."""
    from experiments.engine_parity import manifold_static as ms

    rng = np.random.default_rng(0)
    tilts = [(0, 0, 0), (0, 2, 0), (0, 0, 2)] + [tuple(t) for t in rng.uniform(-3, 3, (21, 3))]
    poses = [ms.finger_pose(t, p) for t, p in zip(tilts, rng.uniform(2e-4, 1.5e-3, 24),
                                                  strict=True)]
    m = ms.model("meshfinger_mjxbox")
    c, mjx = ms.c_points(m, poses), ms.mjx_points(m, poses)
    diff = []
    for a, b in zip(c, mjx, strict=True):
        assert len(a) == len(b), (a, b)
        diff.append(abs(sum(x[0] for x in a) - sum(x[0] for x in b)))  # summed depths, mm
    assert max(diff) < 0.02 and np.mean(diff) < 0.005, diff
    boxes = ms.c_points(ms.model("boxbox"), poses)
    assert sum(len(a) < len(b) for a, b in zip(boxes, mjx, strict=True)) >= 5


NEWTON_STOP = os.path.join(os.path.dirname(os.path.abspath(__file__)), "data",
                           "c_newton_stop_pot.npz")
"""Six states of an MJX-trained pot policy (physics version 6, seed 0's best checkpoint) played
on MJX in version 5, those where the C engine's control step from MJX's very state parted most
from MJX's (`experiments/engine_parity/step_probe.py RUN --episodes 32 --steps 40
--physics-version 5 --worst 6 --save-states ...`): MJX's state before the step (warm start
included), the control it applied and its object velocity after the step"""


def _object_velocity(m: mujoco.MjModel, s: dict, k: int) -> np.ndarray:
    """The object's linear velocity after one control step of the C engine from state ``k``."""
    d = mujoco.MjData(m)
    d.qpos[:], d.qvel[:] = s["qpos"][k], s["qvel"][k]
    if m.na:
        d.act[:] = s["act"][k]
    d.qacc_warmstart[:], d.ctrl[:], d.mocap_pos[:] = s["warm"][k], s["ctrl"][k], s["mocap"][k]
    for _ in range(int(s["n_substeps"])):
        mujoco.mj_step(m, d)
    va = int(s["va"])
    return d.qvel[va:va + 3].copy()


def test_version_6_keeps_the_c_engine_from_throwing_the_pot_where_version_5_stops_early():
    """From each recorded state the C engine in version 5 (line search of 15) stops its Newton
    solver early and throws the pot: 1.1-2.5 m/s away from MJX's velocity after the step. In
    version 6 (50) it lands within 0.03 m/s of MJX's and within 1 mm/s of the C engine run to
    convergence (tolerance 0, 100 / 50 iterations) (~0.3 s, C engine only)."""
    s = dict(np.load(NEWTON_STOP))
    assert str(s["task"]) == "pot" and int(s["physics_version"]) == 5
    cfg = registry.default_config("pot")
    v5, v6 = (load_model(cfg.scene, cfg.timestep, cfg.cone, physics_version=v) for v in (5, 6))
    converged = load_model(cfg.scene, cfg.timestep, cfg.cone, physics_version=5)
    converged.opt.tolerance, converged.opt.iterations, converged.opt.ls_iterations = 0.0, 100, 50
    va = int(s["va"])
    for k in range(len(s["t"])):
        mjx_v = s["qvel2"][k][va:va + 3]
        v5_v, v6_v = _object_velocity(v5, s, k), _object_velocity(v6, s, k)
        assert np.linalg.norm(v5_v - mjx_v) > 1.0, k
        assert np.linalg.norm(v6_v - mjx_v) < 0.03, k
        np.testing.assert_allclose(v6_v, _object_velocity(converged, s, k), atol=1e-3)


@pytest.mark.mjx
def test_version_7_leaves_mjx_s_finger_contacts_as_they_were():
    """Version 7 moves pick up's blocker pairs to the fingers' mesh copies. MJX routes a (box,
    box-shaped mesh) pair to its box-box collider, the geoms in the other order: at 64 random
    poses of a finger pressed into a box (±3° per axis, 0.2-1.5 mm deep) it returns the same
    points as for the two boxes, with summed depths equal to float rounding; the C engine's
    multi-contact convex collider returns as many, where its box-box returns fewer (~10 s: two
    small compiles)."""
    from experiments.engine_parity import manifold_static as ms

    rng = np.random.default_rng(0)
    tilts = [tuple(t) for t in rng.uniform(-3, 3, (64, 3))]
    poses = [ms.finger_pose(t, p) for t, p in zip(tilts, rng.uniform(2e-4, 1.5e-3, 64),
                                                  strict=True)]
    boxes, meshes = ms.mjx_points(ms.model("boxbox"), poses), ms.mjx_points(
        ms.model("meshfinger_mjxbox"), poses)
    for a, b in zip(boxes, meshes, strict=True):
        assert len(a) == len(b)
        assert abs(sum(x[0] for x in a) - sum(x[0] for x in b)) < 1e-6   # mm
    c_mesh = ms.c_points(ms.model("meshfinger_mjxbox"), poses)
    c_box = ms.c_points(ms.model("boxbox"), poses)
    assert [len(a) for a in c_mesh] == [len(a) for a in meshes]
    assert sum(len(a) < len(b) for a, b in zip(c_box, meshes, strict=True)) >= 16
