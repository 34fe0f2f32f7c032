"""The robot's rules written once (mjx_envs/limit_rules.py): NumPy and JAX agree, the robot
client's safety layer and the trainer's env apply them alike."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mjx_envs
from daddpg_jax.algo import resolve
from daddpg_jax.cli.train import build_parser
from daddpg_jax.deploy import trained_limits
from daddpg_jax.deploy.limits import RobotLimits
from daddpg_jax.deploy.safety import SafetyFilter
from mjx_envs import limit_rules, settings
from mjx_envs.numpy_env import NumpyDualArmEnv
from mjx_envs.schema import ConfigError

SIM = "daddpg_jax/deploy/limits/sim.toml"
CELL = "daddpg_jax/deploy/limits/ur3_cell.toml"


def _case(rng, low, high):
    """A random current target, proposed move, tool positions and link points (arms near each
    other often enough that the clearance rule acts in about 1 case of 6)."""
    cur = rng.uniform(low, high).astype(np.float32)
    prop = (cur + rng.normal(0, 0.05, (2, 3))).astype(np.float32)
    tool = (cur + rng.normal(0, 0.01, (2, 3))).astype(np.float32)
    tool[:, 1] += rng.uniform(-0.25, 0.0) * np.array([1, -1], np.float32)
    base = np.array([[0, 0.25, 0.4], [0, -0.25, 0.4]], np.float32)
    frac = np.array([0, 0.3, 0.7, 0.9, 1.0], np.float32)[None, :, None]
    links = base[:, None] + frac * (tool - base)[:, None] + rng.normal(0, 0.02, (2, 5, 3))
    return cur, prop, tool, links.astype(np.float32)


@pytest.mark.parametrize("path", [SIM, CELL])
def test_numpy_and_jax_agree(path):
    """The whole rule set over NumPy (the safety layer) and jitted JAX on 400 random moves:
    the same targets (1e-6 m) and interventions, except where a predicted gap ties its
    threshold to float32 rounding (~2 s, one jit)."""
    safety = SafetyFilter(RobotLimits.load(path).safety_limits())
    jl = limit_rules.Limits(*map(jnp.asarray, safety.rules))
    f = jax.jit(lambda c, p, lp, t: limit_rules.apply(jnp, jl, c, p, lp, t, jnp.zeros(2)))
    rng = np.random.default_rng(0)
    refused = 0
    for _ in range(400):
        cur, prop, tool, links = _case(rng, safety.limits.workspace_low,
                                       safety.limits.workspace_high)
        d = safety.filter(cur, prop, links, tool=tool)
        t, _, flags = f(cur, prop, links, tool)
        refused += "clearance" in d.reasons
        tie = min(abs(d.clearance_after - d.clearance_before),
                  abs(d.clearance_after - safety.limits.min_clearance)) < 1e-5
        if not tie:
            np.testing.assert_allclose(np.asarray(t), d.target, atol=1e-6)
            assert [k for k in ("workspace", "speed", "clearance") if bool(flags[k])] == \
                d.reasons
    assert refused > 20


def test_numpy_env_step_is_the_safety_layer():
    """NumpyDualArmEnv under ``robot_limits`` moves its targets as the robot client's safety
    layer does (command_targets -> SafetyFilter.filter) over 30 steps of random actions
    towards the other arm (~1 s)."""
    safety = SafetyFilter(RobotLimits.load(CELL).safety_limits())
    flat = limit_rules.Limits(*safety.rules).flat()
    env = NumpyDualArmEnv({"robot_limits": flat}, task="reach")
    ref = NumpyDualArmEnv({}, task="reach")
    rng = np.random.default_rng(1)
    res = env.reset(rng)
    ref_res = ref.reset(np.random.default_rng(1))
    for _ in range(30):
        a = rng.uniform(-1, 1, 8).astype(np.float32)
        a[[1, 5]] = [-1.0, 1.0]  # towards the middle
        proposed, ctrl = ref.command_targets(a)
        d = safety.filter(ref.target, proposed, ref_res.link_points,
                          tool=ref_res.observation[:, 0:3])
        ref_res = ref.step_targets(d.target, safety.finger_opening(ctrl))
        res = env.step(a)
        np.testing.assert_array_equal(res.target, ref_res.target)
    assert safety.counts.get("speed", 0) > 0


def test_limits_flag_values_and_checks():
    """--limits gives the file's values at --speed-scale; refuses a control period other than
    the task's (~0.1 s)."""
    values = resolve.limits_values(CELL, 0.5, "reach", {})
    assert len(values) == limit_rules.FLAT_SIZE
    assert values[12] == pytest.approx(0.25 * 0.5 * 0.04)
    with pytest.raises(ConfigError, match="control period"):
        resolve.limits_values(CELL, None, "reach", {"n_substeps": 2})
    assert limit_rules.from_config(np, type("C", (), {"robot_limits": ()})) is None


def test_resume_keeps_the_recorded_limits():
    """~1.3 s: a run trained under a file records its values; --resume keeps them without
    --limits, accepts the same file again and refuses another one, or another speed scale."""
    parser = build_parser()
    cfg, env_over = resolve.resolve_config(parser.parse_args(
        ["--task", "reach", "--limits", CELL, "--speed-scale", "0.5"]), None)
    recorded = tuple(env_over["robot_limits"])
    assert recorded == resolve.limits_values(CELL, 0.5, "reach", {})

    def load(path):
        return cfg, dict(env_over)

    for flags in ([], ["--limits", CELL, "--speed-scale", "0.5"]):
        _, over = resolve.resolve_config(parser.parse_args(["--resume", "runs/x", *flags]),
                                         load)
        assert tuple(over["robot_limits"]) == recorded, flags
    for flags in (["--limits", SIM], ["--limits", CELL], ["--speed-scale", "0.5"]):
        with pytest.raises(ConfigError, match="--resume: --limits|--speed-scale needs"):
            resolve.resolve_config(parser.parse_args(["--resume", "runs/x", *flags]), load)


def test_intervention_penalty_flag():
    """--intervention-penalty C records the env field; it needs limits, refuses C < 0 and, on
    --resume, a value other than the recorded one (~0.2 s)."""
    parser = build_parser()
    cfg, env_over = resolve.resolve_config(parser.parse_args(
        ["--task", "reach", "--limits", SIM, "--intervention-penalty", "0.1"]), None)
    assert env_over["intervention_penalty"] == 0.1
    for flags, match in ((["--intervention-penalty", "0.1"], "needs robot_limits"),
                         (["--limits", SIM, "--intervention-penalty", "-1"], ">= 0")):
        with pytest.raises(ConfigError, match=match):
            resolve.resolve_config(parser.parse_args(["--task", "reach", *flags]), None)

    def load(path):
        return cfg, dict(env_over)

    _, over = resolve.resolve_config(parser.parse_args(["--resume", "runs/x"]), load)
    assert over["intervention_penalty"] == 0.1
    with pytest.raises(ConfigError, match="--resume: --intervention-penalty"):
        resolve.resolve_config(parser.parse_args(
            ["--resume", "runs/x", "--intervention-penalty", "0.2"]), load)


def test_gym_env_and_robot_side_simulator_under_the_penalty_and_versions():
    """The Gymnasium env (NumPy simulator) charges the intervention penalty as the trainer's
    env does: full-speed moves under ur3_cell.toml's 10 mm cap cost -C, a still step nothing,
    and ``compute_reward`` with the step's info gives the step's reward. The robot client's
    simulator takes the served policy's physics version (~1 s)."""
    from daddpg_jax.deploy import robot_session
    from mjx_envs import gym_env

    flat = resolve.limits_values(CELL, None, "reach", {})
    env = gym_env.DualUR3GoalEnv("reach", robot_limits=flat, intervention_penalty=0.3)
    obs, info = env.reset(seed=0)
    assert info["intervention_penalty"].tolist() == [0.0, 0.0]
    for action, pen in ((np.ones(8, np.float32), -0.3), (np.zeros(8, np.float32), 0.0)):
        obs, reward, _, _, info = env.step(action)
        np.testing.assert_allclose(info["intervention_penalty"], [pen, pen])
        np.testing.assert_allclose(env.unwrapped.compute_reward(
            obs["achieved_goal"], obs["desired_goal"], info), reward, atol=1e-6)
    assert robot_session.robot_task("pickup").physics_version == settings.PHYSICS_VERSION
    assert robot_session.robot_task("pickup", 4).physics_version == 4


def test_the_robot_side_names_its_tighter_limits():
    """`trained_limits.check`: one line naming each limit where the robot is tighter than the
    policy's training; --require-trained-limits refuses that and a policy trained without
    limits (~0.01 s)."""
    sim = RobotLimits.load(SIM).safety_limits()
    cell = RobotLimits.load(CELL).safety_limits()
    trained = limit_rules.describe(resolve.limits_values(SIM, None, "reach", {}))
    info = {"trained_limits": trained}
    assert trained_limits.check(info, sim) is None
    line = trained_limits.check(info, cell)
    assert "max step 10 mm < trained 86.8 mm" in line and "min clearance 0.05 m" in line
    assert "workspace" not in line
    with pytest.raises(ValueError, match="--require-trained-limits"):
        trained_limits.check(info, cell, require=True)
    assert trained_limits.check({}, cell) is None
    with pytest.raises(ValueError, match="trained without robot limits"):
        trained_limits.check({}, cell, require=True)


@pytest.mark.slow
def test_trainer_env_moves_its_targets_as_the_numpy_simulator():
    """The trainer's env (C engine, jitted) under ``robot_limits`` from ur3_cell.toml and the
    NumPy simulator under the robot client's safety layer with the same limits give the same
    targets over 25 steps of actions driving the arms towards each other (speed cap and
    clearance both act), and the env's ``intervention_penalty`` charges both arms exactly in
    the steps the safety layer counts an intervention (~15 s: one jit)."""
    flat = resolve.limits_values(CELL, None, "reach", {})
    safety = SafetyFilter(RobotLimits.load(CELL).safety_limits())
    env = mjx_envs.make("reach", physics="c", robot_limits=flat, intervention_penalty=0.25)
    assert env.info_keys == ("arm_contact_penalty", "intervention_penalty")
    assert env.reward_range[0] == pytest.approx(-1.25)
    ref = NumpyDualArmEnv({}, task="reach")
    res = ref.reset(np.random.default_rng(0))
    step = jax.jit(env.step)
    state = env.reset(jax.random.PRNGKey(0))
    rng = np.random.default_rng(2)
    charged = 0
    for i in range(25):
        a = rng.uniform(-1, 1, 8).astype(np.float32)
        a[[1, 5]] = [-1.0, 1.0]
        if i % 3 == 0:  # a small move: within the speed cap
            a[[0, 1, 2, 4, 5, 6]] *= 0.1
        proposed, ctrl = ref.command_targets(a)
        d = safety.filter(ref.target, proposed, res.link_points, tool=res.observation[:, 0:3])
        res = ref.step_targets(d.target, safety.finger_opening(ctrl))
        state = step(state, jnp.asarray(a))
        np.testing.assert_allclose(np.asarray(env.backend.mocap_pos(state.data))[:2],
                                   res.target, atol=1e-5)
        pen = np.asarray(state.info["intervention_penalty"])
        expect = -0.25 if set(d.reasons) & {"workspace", "speed", "clearance"} else 0.0
        np.testing.assert_array_equal(pen, [expect, expect])
        # the reward carries it, and a relabelled reward (HER: another goal, the same info)
        np.testing.assert_allclose(np.asarray(env.compute_reward(
            state.obs["achieved_goal"], state.obs["desired_goal"], state.info)),
            np.asarray(state.reward), atol=1e-6)
        charged += expect != 0.0
    assert 0 < charged < 25
