"""Physics versions: the current scenes and version 1's (`mjx_envs.model.PHYSICS_V1`,
applied by `mjx_envs.model.load_model`), so that older runs and policy files act with the
physics they were trained on. tests/data/physics_v1.npz holds, per scene, every model array in
which version 1's MJCF files (git 5157332^, assets/) differed from today's, compiled by MuJoCo:
version 1 as built here must equal them and agree with today's model everywhere else."""

from __future__ import annotations

import os

import numpy as np
import pytest

import mjx_envs
from daddpg_jax.cli import evaluate as evaluate_cli
from mjx_envs import registry, settings
from mjx_envs.model import MJX_UNIQUE_CONTACTS, PHYSICS_V1, load_model
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
    for bad in (0, settings.PHYSICS_VERSION + 1):
        with pytest.raises(ValueError, match="physics_version"):
            load_model("scene_push.xml", physics_version=bad)
        with pytest.raises(ConfigError, match="physics_version"):
            registry.task_config("push", physics_version=bad)
        assert evaluate_cli.main(["no_such_run", "--physics-version", str(bad)]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "--physics-version must be in" in err
