"""The robot owns its limits: the limits file (TOML/JSON) and its validation, overrides that may
only tighten, --speed-scale, and GET /info that never widens them (a lying service: a +-100 m
box, dt NaN/-1/another period, another action layout or task). Each refused case is one line
and exit 2; an honest service still gives a normal run (positive control).

The client runs in-process and unpaced (--fast) against a policy service in a thread, built on
the checked-in export tests/data/legacy_reach/policy.npz (no JAX): ~6 s for the module."""

from __future__ import annotations

import dataclasses
import json
import math
import os

import numpy as np
import pytest

from daddpg_jax.cli import robot_client
from daddpg_jax.deploy import NumpyPolicy
from daddpg_jax.deploy.limits import SHIPPED, LimitsError, RobotLimits
from daddpg_jax.deploy.server import PolicyServer

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
GOOD = os.path.join(ROOT, "tests", "data", "legacy_reach", "policy.npz")
SIM = os.path.join(SHIPPED, "sim.toml")
CELL = os.path.join(SHIPPED, "ur3_cell.toml")


def _cell_dict():
    import tomllib

    with open(CELL, "rb") as f:
        return tomllib.load(f)


def _toml(d: dict) -> str:
    """A minimal TOML writer for the limits layout (top-level scalars, [left], [right])."""

    def val(v):
        if isinstance(v, str):
            return json.dumps(v)
        if isinstance(v, list):
            return "[" + ", ".join(val(x) for x in v) + "]"
        if isinstance(v, float) and math.isnan(v):
            return "nan"
        if isinstance(v, float) and math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v).lower() if isinstance(v, bool) else repr(v)

    lines = [f"{k} = {val(v)}" for k, v in d.items() if not isinstance(v, dict)]
    for k, v in d.items():
        if isinstance(v, dict):
            lines += [f"[{k}]"] + [f"{kk} = {val(vv)}" for kk, vv in v.items()]
    return "\n".join(lines) + "\n"


# -- the file ----------------------------------------------------------------------------------

def test_shipped_files_and_defaults():
    cell, sim, default = RobotLimits.load(CELL), RobotLimits.load(SIM), RobotLimits()
    assert cell.max_speed == 0.25 and cell.control_period == 0.04 and cell.deadline == 0.03
    assert sim.max_speed == pytest.approx(2.17) and sim.min_clearance == 0.01
    # the defaults are conservative: no faster and no closer than the cell's file
    assert default.max_speed <= cell.max_speed and default.min_clearance >= cell.min_clearance
    np.testing.assert_allclose(cell.workspace_low, default.workspace_low)
    s = cell.safety_limits()
    assert s.max_step == pytest.approx(0.25 * 0.04) and s.deadline_s == 0.03
    assert cell.safety_limits(speed_scale=0.5).max_step == pytest.approx(0.005)
    j = RobotLimits.from_dict(json.loads(json.dumps(_cell_dict())))
    assert dataclasses.replace(j, source="") == dataclasses.replace(cell, source="")
    assert "built-in defaults" in default.describe() and "0.25 m/s" in default.describe()


BAD_VALUES = [
    ("max_speed", float("nan")), ("max_speed", float("inf")), ("max_speed", -1.0),
    ("max_speed", 0.0), ("max_speed", 10.0), ("max_speed", "fast"), ("max_speed", True),
    ("min_clearance", float("nan")), ("min_clearance", -0.5), ("control_period", 0.0),
    ("control_period", 2.0), ("deadline", -1.0), ("deadline", float("nan")),
    ("finger_max", -0.01), ("finger_min", 0.05), ("max_observation_age", 0.0),
    ("unknown_key", 1.0), ("task", 3),
]


@pytest.mark.parametrize("key,value", BAD_VALUES, ids=[f"{k}={v}" for k, v in BAD_VALUES])
def test_bad_values_are_refused_with_one_line(tmp_path, key, value):
    d = {**_cell_dict(), key: value}
    path = tmp_path / "l.toml"
    path.write_text(_toml(d))
    with pytest.raises(LimitsError) as e:
        RobotLimits.load(path)
    assert "\n" not in str(e.value) and str(path) in str(e.value)


@pytest.mark.parametrize("arm,low,high", [
    ("left", [0.3, 0.0, 0.5], [0.2, 0.1, 0.6]),         # empty along x
    ("right", [0.1, 0.0, 0.5], [0.2, 0.0, 0.6]),        # flat along y
    ("left", [-100.0, -100.0, -100.0], [100.0, 100.0, 100.0]),  # beyond any arm's reach
    ("right", [0.1, 0.0, float("nan")], [0.2, 0.1, 0.6]),
    ("left", [0.1, 0.0], [0.2, 0.1, 0.6]),
])
def test_bad_boxes_are_refused(tmp_path, arm, low, high):
    d = _cell_dict()
    d[arm] = {"workspace_low": low, "workspace_high": high}
    path = tmp_path / "l.toml"
    path.write_text(_toml(d))
    with pytest.raises(LimitsError):
        RobotLimits.load(path)


def test_malformed_files_are_refused(tmp_path):
    cases = {"a.toml": "max_speed = [", "b.json": '{"max_speed": NaN}', "c.json": "[1, 2]",
             "d.yaml": "max_speed: 1", "e.toml": "max_speed = 0.1\n",  # no [left]/[right]
             "f.json": '\ufeff{"max_speed": 0.1}', "g.toml": "\udcff"}
    for name, text in cases.items():
        path = tmp_path / name
        path.write_bytes(text.encode("utf-8", "surrogateescape"))
        with pytest.raises(LimitsError) as e:
            RobotLimits.load(path)
        assert "\n" not in str(e.value), name
    with pytest.raises(LimitsError, match="cannot read"):
        RobotLimits.load(tmp_path / "missing.toml")


def test_overrides_only_tighten():
    """--max-speed -1 reversed capped steps, nan/inf disabled the cap, --workspace-margin -0.5
    enlarged the box, --min-clearance nan let targets out: all refused now."""
    cell = RobotLimits.load(CELL)
    t = cell.tightened(max_speed=0.1, min_clearance=0.08, workspace_margin=0.01,
                       deadline=0.025, max_observation_age=0.05)
    assert (t.max_speed, t.min_clearance, t.deadline, t.max_observation_age) == \
        (0.1, 0.08, 0.025, 0.05)
    np.testing.assert_allclose(np.asarray(t.workspace_low), np.asarray(cell.workspace_low) + 0.01)
    for kw in ({"max_speed": -1.0}, {"max_speed": float("nan")}, {"max_speed": float("inf")},
               {"max_speed": 0.5}, {"min_clearance": float("nan")}, {"min_clearance": 0.01},
               {"min_clearance": -1.0}, {"workspace_margin": -0.5},
               {"workspace_margin": float("nan")}, {"workspace_margin": 0.2},
               {"deadline": 0.1}, {"deadline": float("nan")}, {"max_observation_age": 1.0}):
        with pytest.raises(LimitsError):
            cell.tightened(**kw)
    for scale in (0.0, -0.5, 1.5, float("nan")):
        with pytest.raises(LimitsError):
            cell.safety_limits(speed_scale=scale)


# -- the client against a service that lies ----------------------------------------------------

class _Lying:
    """The honest policy with GET /info and /act answers changed."""

    def __init__(self, policy, info_env=None, info=None, action=None):
        self._p, self._env, self._info, self._action = policy, info_env, info, action

    def __getattr__(self, name):
        return getattr(self._p, name)

    def info(self):
        out = self._p.info()
        out["env"] = {**out["env"], **(self._env or {})}
        out.update(self._info or {})
        return out

    def act(self, o, g):
        return self._p.act(o, g) if self._action is None else np.asarray(self._action, np.float32)


@pytest.fixture(scope="module")
def policy():
    return NumpyPolicy.load(GOOD)


def _run(policy, tmp_path, capsys, *args, **lie):
    with PolicyServer(_Lying(policy, **lie), port=0) as srv:
        code = robot_client.main(["--server", srv.url, "--fast", "--episodes", "1",
                                  "--json", str(tmp_path / "out.json"), *args])
    cap = capsys.readouterr()
    return code, cap


def _sim_limits(tmp_path) -> str:
    """The simulator's limits with a 2 s deadline and observation age (allowed unpaced): a
    loaded test machine must not turn the positive controls into missed deadlines."""
    import tomllib

    with open(SIM, "rb") as f:
        d = tomllib.load(f)
    path = tmp_path / "sim_slow.json"
    path.write_text(json.dumps({**d, "deadline": 2.0, "max_observation_age": 2.0}))
    return str(path)


def test_honest_service_normal_run(policy, tmp_path, capsys):
    """Positive control: the same client and service, nothing lied: a normal run."""
    lim = _sim_limits(tmp_path)
    code, cap = _run(policy, tmp_path, capsys, "--limits", lim)
    assert code == 0, cap.err
    out = json.loads(cap.out)
    assert out["episodes"] == 1 and out["stops"] == 0 and out["limits"] == lim
    assert cap.err.startswith(f"limits ({lim}): max speed 2.17 m/s")
    assert "success:" in cap.err and "safety interventions" in cap.err


def test_wide_box_in_info_does_not_widen_the_robot_box(policy, tmp_path, capsys):
    """/info with a +-100 m box and an action pushing every axis to +1: targets reached
    (2.75, 2.65, 3.05) m before; now every target stays in the robot's box: the robot's own
    task (its box) shapes the targets, the served settings are never used."""
    box = {"workspace_low": [[-100.0] * 3] * 2, "workspace_high": [[100.0] * 3] * 2}
    logs = tmp_path / "logs"
    code, cap = _run(policy, tmp_path, capsys, "--limits", _sim_limits(tmp_path), "--log",
                     str(logs), info_env=box, action=[1.0] * 8)
    assert code == 0, cap.err
    out = json.loads(cap.out)
    assert out["gate_refusals"] == {}
    lim = RobotLimits.load(SIM)
    log = json.loads((logs / "episode_00001.json").read_text())
    targets = np.array([s["target"] for s in log["steps"]])
    assert np.all(targets <= np.asarray(lim.workspace_high) + 1e-6)
    assert np.all(targets >= np.asarray(lim.workspace_low) - 1e-6)


@pytest.mark.parametrize("lie,words", [
    ({"info_env": {"dt": float("nan")}}, "NaN"),  # not even valid JSON: refused
    ({"info_env": {"dt": -1.0}}, "control period"),
    ({"info_env": {"dt": 0.02}}, "control period"),
    ({"info_env": {"dt": 0.04, "timestep": 0.02}}, "timestep"),
    ({"info": {"action_size": 6}}, "action layout"),
    ({"info": {"num_arms": 3}}, "action layout"),
    ({"info": {"task": "push"}}, "serves a 'push' policy"),
    ({"info": {"env": None}}, "control period"),
], ids=["dt-nan", "dt-neg", "dt-other", "dt-vs-timestep", "action-size", "arms", "task-limits",
        "no-env"])
def test_info_that_differs_refuses_the_start(policy, tmp_path, capsys, lie, words):
    """dt = NaN switched the speed cap off, dt = -1 reversed it; now the start is refused."""
    lim = tmp_path / "l.toml"
    lim.write_text(_toml({**_cell_dict(), "task": "reach"}))
    code, cap = _run(policy, tmp_path, capsys, "--limits", str(lim), **lie)
    assert code == 2
    err = cap.err.strip().splitlines()
    assert len(err) == 2 and err[0].startswith("limits (") and err[1].startswith("error: ")
    assert words in err[1] and "Traceback" not in cap.err


@pytest.mark.parametrize("args,words", [
    (["--max-speed", "-1"], "--max-speed"), (["--max-speed", "nan"], "--max-speed"),
    (["--max-speed", "inf"], "--max-speed"), (["--max-speed", "5"], "loosen"),
    (["--workspace-margin", "-0.5"], "--workspace-margin"),
    (["--min-clearance", "nan"], "--min-clearance"), (["--min-clearance", "0"], "loosen"),
    (["--speed-scale", "0"], "--speed-scale"), (["--speed-scale", "2"], "--speed-scale"),
    (["--deadline-ms", "100"], "loosen"), (["--limits", "/nonexistent.toml"], "cannot read"),
    (["--episodes", "0"], "--episodes"), (["--policy-sha256", "abc"], "--policy-sha256"),
])
def test_bad_overrides_are_one_line_exit_2(policy, tmp_path, capsys, args, words):
    code, cap = _run(policy, tmp_path, capsys, *args)
    assert code == 2
    lines = cap.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and words in lines[0], lines


def test_paced_run_needs_deadline_within_the_period(policy, tmp_path, capsys):
    lim = tmp_path / "l.json"
    lim.write_text(json.dumps({**_cell_dict(), "deadline": 0.5}))
    with PolicyServer(policy, port=0) as srv:
        assert robot_client.main(["--server", srv.url, "--limits", str(lim)]) == 2
    assert "allowed only unpaced" in capsys.readouterr().err


def test_json_duplicate_keys_are_refused_as_tomls_are(tmp_path):
    """A JSON limits file with a key given twice (top level or inside an arm's box) took the last
    value silently; now it is refused with one line naming the key, as TOML refuses it. The same
    file without the duplicate loads (positive control); ~10 ms."""
    d = _cell_dict()
    good = json.dumps(d)
    (tmp_path / "ok.json").write_text(good)
    assert RobotLimits.load(tmp_path / "ok.json").max_speed == d["max_speed"]
    top = good.replace('"max_speed":', '"max_speed": 100.0, "max_speed":', 1)
    arm = json.dumps({**d, "left": {}}).replace('"left": {}', '"left": {"a": 1, "a": 2}', 1)
    for name, text, key in (("top.json", top, "max_speed"), ("arm.json", arm, "a")):
        path = tmp_path / name
        path.write_text(text)
        assert text.count(f'"{key}":') == 2, text
        with pytest.raises(LimitsError) as e:
            RobotLimits.load(path)
        msg = str(e.value)
        assert "\n" not in msg and f"duplicate key {key!r}" in msg, msg
    (tmp_path / "dup.toml").write_text(f"max_speed = {d['max_speed']}\n" + _toml(d))
    with pytest.raises(LimitsError, match="not valid TOML"):
        RobotLimits.load(tmp_path / "dup.toml")
