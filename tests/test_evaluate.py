"""Evaluation of a trained run (daddpg_jax/analysis/evaluation.py, experiments/evaluate.py): Wilson
interval, output fields, agreement with the run's own logged test success, CLI and video."""

import csv
import dataclasses
import json
import os
import subprocess
import sys

import numpy as np
import pytest

from daddpg_jax.algo import losses, replay
from daddpg_jax.algo import train as train_lib
from daddpg_jax.analysis import evaluation
from daddpg_jax.cli import evaluate as evaluate_cli
from daddpg_jax.deploy import NumpyPolicy
from daddpg_jax.running import checkpoint as ckpt
from daddpg_jax.running import run_record, runner
from daddpg_jax.running.checkpoint_policy import RunPolicy
from daddpg_jax.running.export import export_run
from daddpg_jax.running.runner import train
from mjx_envs import episode_starts
from tests import conftest
from tests.conftest import call_main, run_options, tree_equal

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
N_TEST = 12
TINY = conftest.TINY.replace(task="reach", physics="c", num_envs=2, n_cycles=2, n_batches=2,
                             batch_size=64, buffer_size=10_000, n_test_episodes=N_TEST,
                             n_epochs=1, seed=1)


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    d = str(tmp_path_factory.mktemp("eval") / "reach_tiny")
    train(TINY, run_options(d))
    return d


@pytest.fixture(scope="module")
def policy(run_dir):
    return evaluation.load_policy(run_dir)


def test_wilson_interval_hand_computed():
    # p = 0.95, n = 100, z = 1.96: centre (0.95 + 0.019207) / 1.038415 = 0.933351,
    # half 1.96 / 1.038415 * sqrt(0.000475 + 0.0000960) = 0.045103
    lo, hi = evaluation.wilson_interval(95, 100)
    assert lo == pytest.approx(0.888250, abs=1e-5) and hi == pytest.approx(0.978456, abs=1e-5)
    lo, hi = evaluation.wilson_interval(7, 20)
    assert lo == pytest.approx(0.181192, abs=1e-5) and hi == pytest.approx(0.567146, abs=1e-5)
    lo, hi = evaluation.wilson_interval(0, 10)   # not empty at p = 0
    assert lo == 0.0 and hi == pytest.approx(0.277533, abs=1e-5)
    assert evaluation.wilson_interval(10, 10)[0] == pytest.approx(0.722467, abs=1e-5)
    with pytest.raises(ValueError):
        evaluation.wilson_interval(11, 10)


def test_evaluate_fields_and_logged_success(policy, run_dir):
    s, traj = evaluation.evaluate(policy, episodes=N_TEST)  # default seed = the run's eval_seed
    for k in ("success_rate", "successes", "success_ci95", "arm_contact_rate",
              "arm_contact_ci95", "final_distance_mean", "final_distance_median", "episodes",
              "seed", "checkpoint", "task", "algo", "physics"):
        assert k in s, k
    assert s["checkpoint"] == 1 and s["episodes"] == N_TEST and s["seed"] == TINY.eval_seed
    lo, hi = s["success_ci95"]
    assert 0.0 <= lo <= s["success_rate"] <= hi <= 1.0
    assert (lo, hi) == pytest.approx(evaluation.wilson_interval(s["successes"], N_TEST))
    assert set(s["final_distance_mean"]) == {"left", "right"}
    assert all(v > 0 for v in s["final_distance_mean"].values())
    import csv

    with open(os.path.join(run_dir, "metrics.csv")) as f:
        row = list(csv.DictReader(f))[-1]
    # same episodes and actors as the trainer's evaluation of that epoch
    assert s["success_rate"] == pytest.approx(float(row["test_success_rate"]))
    assert s["arm_contact_rate"] == pytest.approx(float(row["test_arm_contact_rate"]))
    assert s["final_distance_mean"]["left"] == pytest.approx(
        float(row["test_final_distance_left"]), rel=1e-4)
    T = policy.env.episode_length
    assert traj["qpos"].shape[:2] == (N_TEST, T + 1)
    assert traj["mocap"].shape == (N_TEST, T + 1, 2, 3) and traj["goal"].shape == (N_TEST, 2, 3)
    # deterministic: the same seed gives the same result, another seed other episodes
    s2, traj2 = evaluation.evaluate(policy, episodes=N_TEST)
    np.testing.assert_array_equal(traj["final_distance"], traj2["final_distance"])
    _, traj3 = evaluation.evaluate(policy, episodes=N_TEST, seed=5)
    assert not np.array_equal(traj["goal"], traj3["goal"])
    assert "success rate" in evaluation.format_summary(s)


def test_no_checkpoint_is_a_clear_error(tmp_path, run_dir):
    with pytest.raises(evaluation.NoCheckpointError, match="no config.json"):
        evaluation.load_policy(str(tmp_path))
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "config.json").write_text(open(os.path.join(run_dir, "config.json")).read())
    with pytest.raises(evaluation.NoCheckpointError, match="no checkpoint"):
        evaluation.load_policy(str(empty))
    with pytest.raises(evaluation.NoCheckpointError, match="available: \\[1\\]"):
        evaluation.load_policy(run_dir, step=7)
    with pytest.raises(evaluation.NoCheckpointError, match="not both"):
        evaluation.load_policy(run_dir, step=1, best=True)
    with pytest.raises(evaluation.NoCheckpointError, match="no best checkpoint"):
        evaluation.load_policy(str(empty), best=True)


def test_loader_builds_no_training_step(run_dir, policy, monkeypatch, tmp_path):
    """Evaluation and export load a run through one loader (`checkpoint_policy`) that builds no
    training step: with make_train_fns, the learner (optimizers) and the replay buffer's init
    made to fail, the run loads, evaluates (the trainer's logged test success; on the module
    policy's compiled rollout) and exports; its actors and normalizers equal those of the
    TrainState restored the old way (a make_train_fns(...).init() template) and act bit for bit
    as that state's ``act`` on a fixed batch. ~2 s on a 2-core CPU (3.5 s under load) beside
    the module's trained run and policy (the old way's init and both acts compile)."""
    def refuse(*a, **k):
        raise AssertionError("the policy loader built (part of) the training step")

    for obj, name in ((train_lib, "make_train_fns"), (runner, "make_train_fns"),
                      (losses, "make_learner"), (losses, "init_agent_state"), (replay, "init")):
        monkeypatch.setattr(obj, name, refuse)
    loaded = evaluation.load_policy(run_dir)   # checkpoint_policy.load_run_policy
    assert isinstance(loaded, RunPolicy) and loaded.variant.name == TINY.algo
    assert loaded.step == 1 and loaded.cfg == TINY
    s, _ = evaluation.evaluate(dataclasses.replace(policy, params=loaded.params), episodes=N_TEST)
    with open(os.path.join(run_dir, "metrics.csv")) as f:
        row = list(csv.DictReader(f))[-1]
    assert s["success_rate"] == pytest.approx(float(row["test_success_rate"]))
    assert s["final_distance_mean"]["left"] == pytest.approx(
        float(row["test_final_distance_left"]), rel=1e-4)
    exported = NumpyPolicy.load(export_run(run_dir, str(tmp_path / "p.npz")))
    monkeypatch.undo()
    # the old way: the training step's template (smallest buffer), restored
    cfg, _ = ckpt.load_config(run_dir)
    fns = train_lib.make_train_fns(loaded.env, cfg.replace(buffer_size=1, n_demos=0))
    state, step = run_record.restore_readable(run_dir, fns.init())
    assert step == loaded.step
    assert tree_equal(loaded.params.actor, state.agent.actor)
    assert tree_equal(loaded.params.obs_norm, state.obs_norm)
    assert tree_equal(loaded.params.goal_norm, state.goal_norm)
    rng = np.random.default_rng(0)
    o = rng.normal(0.0, 1.0, (64, 2, loaded.env.obs_size)).astype(np.float32)
    o[:6] *= 300.0   # some beyond clip_obs and the normalizer clip
    g = rng.uniform(-0.5, 0.8, (64, 2, 3)).astype(np.float32)
    expected = np.asarray(fns.act(state, o, g))
    np.testing.assert_array_equal(np.asarray(loaded.act(loaded.params, o, g)), expected)
    layers = state.agent.actor["params"]
    for i, (w, b) in enumerate(zip(exported.weights, exported.biases, strict=True)):
        np.testing.assert_array_equal(w, np.asarray(layers[f"Dense_{i}"]["kernel"]))
        np.testing.assert_array_equal(b, np.asarray(layers[f"Dense_{i}"]["bias"]))
    np.testing.assert_allclose(exported.act(o, g), expected, atol=1e-5, rtol=0)


def test_best_checkpoint(run_dir, policy):
    best = evaluation.load_policy(run_dir, best=True)
    assert best.best and not policy.best and best.step == 1
    s, _ = evaluation.evaluate(best, episodes=N_TEST)
    assert s["best"] is True and s["checkpoint"] == 1


def test_cli_json_and_error(run_dir, tmp_path, capsys):
    """daddpg-evaluate's main in this process, with --save-starts (~2 s)."""
    starts = str(tmp_path / "starts.npz")
    code = call_main(evaluate_cli.main, [run_dir, "--episodes", "8", "--seed", "3", "--json",
                                         "--save-starts", starts])
    out = capsys.readouterr()
    assert code == 0, out.err[-2000:]
    s = json.loads(out.out)
    assert s["episodes"] == 8 and s["seed"] == 3 and len(s["success_ci95"]) == 2
    assert s["starts"] == starts
    saved = episode_starts.load(starts, task="reach")
    assert len(saved) == 8 and saved.success.sum() == s["successes"]
    assert saved.meta["seed"] == 3 and saved.meta["checkpoint"] == 1
    assert call_main(evaluate_cli.main, [tmp_path]) == 2
    assert "no config.json" in capsys.readouterr().err
    assert call_main(evaluate_cli.main, [run_dir, "--physics", "c,mjx", "--save-starts",
                                         starts]) == 2
    assert "--save-starts takes one --physics engine" in capsys.readouterr().err


class _LocalService:
    """The robot loop's policy client without HTTP: the exported NumPy policy in process."""

    def __init__(self, policy):
        self.policy = policy

    def act(self, observation, desired_goal):
        return self.policy.act(observation, desired_goal), {}


def test_robot_side_plays_the_evaluations_episodes(policy, run_dir, tmp_path):
    """The episodes of an evaluation (goals and first states, `mjx_envs.episode_starts`) played
    again by the robot loop (`run_episodes(starts=...)`: the exported policy, the safety layer
    without its clearance rule, the NumPy simulator) end where the trainer's env ended them,
    episode by episode: the same success list and final distances within 0.1 mm (~1 s)."""
    from daddpg_jax.deploy import robot
    from daddpg_jax.deploy.safety import SafetyFilter, SafetyLimits
    from mjx_envs.numpy_env import NumpyDualArmEnv

    n = 4
    _, traj = evaluation.evaluate(policy, episodes=N_TEST, seed=5)  # compiled above
    path = episode_starts.save(str(tmp_path / "s"), "reach", traj["goal"][:n],
                               traj["qpos"][:n, 0], traj["success"][:n])
    starts = episode_starts.load(path, task="reach", nq=traj["qpos"].shape[-1])
    exported = NumpyPolicy.load(export_run(run_dir, str(tmp_path / "p.npz")))
    env = NumpyDualArmEnv(exported.env)
    safety = SafetyFilter(SafetyLimits.from_env(exported.env, min_clearance=-1e9,
                                                deadline_s=5.0))
    logs = []
    out = robot.run_episodes(env, _LocalService(exported), safety, n, starts=starts,
                             on_log=logs.append)
    assert out["episode_success"] == [bool(x) for x in traj["success"][:n]]
    for k, log in enumerate(logs):
        np.testing.assert_allclose(log["goal"], traj["goal"][k], atol=1e-6)
        np.testing.assert_allclose(log["qpos"], traj["qpos"][k, 0], atol=1e-6)
    assert out["mean_final_distance"] == pytest.approx(
        float(traj["final_distance"][:n].mean()), abs=1e-4)
    with pytest.raises(ValueError, match="the starts hold 4"):
        robot.run_episodes(env, _LocalService(exported), safety, n + 1, starts=starts)


@pytest.mark.e2e
def test_limits_match_pairs_the_robot_client_with_the_evaluation(run_dir, tmp_path):
    """experiments/limits_match.py end to end on the module's run under sim.toml: export,
    daddpg-evaluate --limits --save-starts, daddpg-serve and daddpg-robot-client --arms sim
    --starts over the same 4 episodes; the row is paired (Newcombe interval, counts over the 4
    episodes), both sides agree episode by episode, and limits_table.py prints the row (~40 s:
    three processes load JAX)."""
    import socket

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    out = tmp_path / "rows"
    r = subprocess.run([sys.executable, os.path.join(ROOT, "experiments", "limits_match.py"),
                        run_dir, "--limits", "daddpg_jax/deploy/limits/sim.toml", "--episodes",
                        "4", "--port", str(port), "--out", str(out)],
                       capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert r.returncode == 0, r.stderr[-3000:]
    row = json.loads((out / "reach_tiny__sim.json").read_text())
    assert row["paired"] is True and row["paired_episodes"] == 4
    assert sum(row["paired_counts"].values()) == 4
    assert row["paired_counts"]["first_only"] == row["paired_counts"]["second_only"] == 0
    lo, hi = row["paired_ci95"]
    assert lo <= row["paired_difference"] == 0.0 <= hi
    assert row["robot_client_success"] == row["evaluate_limits_success"]
    table = subprocess.run([sys.executable, os.path.join(ROOT, "experiments", "limits_table.py"),
                            str(out / "reach_tiny__sim.json")], capture_output=True, text=True,
                           timeout=60, check=True).stdout.splitlines()
    assert len(table) == 3 and table[2].startswith("| reach_tiny | no limits |")
    assert "+0.000 [" in table[2] and "| 0 / 0 |" in table[2]


def test_starts_file_round_trip_and_refusals(tmp_path):
    """`mjx_envs.episode_starts`: what is saved loads back; a file of another task, state size
    or format, with non-finite values or inconsistent shapes is a one-line StartsError; the
    robot client refuses --starts with real arms (~0.1 s)."""
    from daddpg_jax.deploy import robot_session

    rng = np.random.default_rng(0)
    goal, qpos = rng.normal(size=(3, 2, 3)), rng.normal(size=(3, 9))
    path = episode_starts.save(str(tmp_path / "a.npz"), "push", goal, qpos, [1, 0, 1], seed=7)
    s = episode_starts.load(path, task="push", nq=9)
    np.testing.assert_array_equal(s.goal, goal.astype(np.float32))
    assert s.success.tolist() == [True, False, True] and s.meta["seed"] == 7 and len(s) == 3
    assert s.task == "push" and not os.path.exists(path + ".tmp.npz")
    bad = {"reach": dict(task="reach"), "9 coordinates": dict(nq=10)}
    for msg, kw in bad.items():
        with pytest.raises(episode_starts.StartsError, match=msg):
            episode_starts.load(path, **kw)
    with pytest.raises(episode_starts.StartsError, match="no such file"):
        episode_starts.load(str(tmp_path / "none.npz"))
    np.savez(tmp_path / "other.npz", goal=goal)
    with pytest.raises(episode_starts.StartsError, match="not a starts file"):
        episode_starts.load(str(tmp_path / "other.npz"))
    np.savez(tmp_path / "fmt.npz", goal=goal, qpos=qpos, meta=np.array('{"format": "x/9"}'))
    with pytest.raises(episode_starts.StartsError, match="format 'x/9'"):
        episode_starts.load(str(tmp_path / "fmt.npz"))
    qpos[1, 2] = np.nan
    with pytest.raises(ValueError, match="non-finite"):
        episode_starts.save(str(tmp_path / "b"), "push", goal, qpos)
    with pytest.raises(ValueError, match=r"\[N, nq\]"):
        episode_starts.save(str(tmp_path / "b"), "push", goal, qpos[:2])
    assert "--arms sim or ur-sim" in robot_session.check_options(2, "ur", starts=path)
    assert robot_session.check_options(2, "sim", starts=path) is None


@pytest.mark.e2e
def test_video(run_dir, tmp_path):
    """--video through the CLI (a fresh process, so MUJOCO_GL=egl applies before MuJoCo loads)."""
    path = str(tmp_path / "eval.mp4")
    out = subprocess.run([sys.executable, os.path.join(ROOT, "experiments", "evaluate.py"),
                          run_dir, "--episodes", "2", "--video", path, "--video-episodes", "2",
                          "--width", "160", "--height", "120"],
                         capture_output=True, text=True, cwd=ROOT, timeout=300)
    if out.returncode == 1 and "rendering failed" in out.stderr:
        pytest.skip(f"no headless OpenGL here: {out.stderr.strip()[-300:]}")
    assert out.returncode == 0, out.stderr[-2000:]
    written = path if os.path.exists(path) else path[:-4] + ".gif"   # GIF without imageio-ffmpeg
    assert os.path.getsize(written) > 1000
    import imageio.v2 as imageio

    frames = imageio.mimread(written, memtest=False)
    if written.endswith(".mp4"):
        assert len(frames) == 2 * (50 + 1 + 12)
    else:  # GIF writers merge identical consecutive frames (held end frames, still arms)
        assert 50 < len(frames) <= 2 * (50 + 1 + 12)
    assert np.asarray(frames[0]).shape[:2] == (120, 160)
    assert np.asarray(frames[0]).std() > 5  # not a blank image


def test_chunked_evaluation_equals_unchunked(policy):
    """Chunks of 5 (the last padded), with and without the watchdog's worker thread, give the
    same episodes and results as one batch of 12 (C engine; ~3 s: one more program)."""
    whole, tw = evaluation.evaluate(policy, episodes=N_TEST, chunk=None)
    for watchdog in (None, 60.0):
        part, tp = evaluation.evaluate(policy, episodes=N_TEST, chunk=5, watchdog=watchdog)
        assert {k: v for k, v in part.items() if k != "eval_seconds"} == \
            {k: v for k, v in whole.items() if k != "eval_seconds"}
        assert set(tp) == set(tw)
        for k in tw:
            np.testing.assert_array_equal(tp[k], tw[k], err_msg=k)
    assert tw["object"].shape == (N_TEST, policy.env.episode_length + 1, 3)
    assert tw["grip"].shape == (N_TEST, policy.env.episode_length + 1, 2, 3)
    from mjx_envs.physics.backends import default_chunk

    assert default_chunk("c", "cpu") is None
    assert default_chunk("mjx", "cpu") == evaluation.MJX_CPU_CHUNK
    assert default_chunk("mjx", "gpu") is None
    with pytest.raises(ValueError, match="chunk must be"):
        evaluation.evaluate(policy, episodes=2, chunk=0)


def test_compare_one_engine_with_itself(policy):
    """`engines.compare` on the C engine twice (~1 s, programs reused): difference 0, only
    concordant pairs, a zero divergence profile."""
    from daddpg_jax.analysis import engines

    seen = []
    s, trajs = engines.compare({"c": policy, "same": policy}, episodes=N_TEST,
                               report=lambda name, r: seen.append(name))
    assert seen == ["c", "same"] and list(s["engines"]) == ["c", "same"]
    one, _ = evaluation.evaluate(policy, episodes=N_TEST)
    for k in engines.ENGINE_FIELDS:
        if k != "eval_seconds":
            assert s["engines"]["c"][k] == one[k], k
    assert s["engines"]["c"]["final_distance_mean_without_faults"] == pytest.approx(
        one["final_distance_mean"])     # no physics fault here
    d = s["difference"]
    assert d["value"] == 0.0 and d["engines"] == ["c", "same"]
    assert d["paired"]["first_only"] == d["paired"]["second_only"] == 0
    assert d["paired"]["both"] == one["successes"]
    assert d["ci95"][0] < 0 < d["ci95"][1]
    assert s["episodes"] == N_TEST and s["task"] == "reach" and "physics" not in s
    prof = engines.divergence_profile(trajs["c"], trajs["same"])
    assert len(prof["step"]) == policy.env.episode_length + 1 and prof["grip_max_m"].max() == 0
    assert "difference c - same: +0.000" in engines.format_comparison(s)


@pytest.mark.mjx
def test_cli_compares_c_and_mjx(run_dir, tmp_path, capsys):
    """``--physics c,mjx --divergence``: the JSON layout, the paired difference, and the profile
    (MJX reach, 4 episodes in chunks of 2: one MJX compile; ~40 s with a cold compilation
    cache on a 2-core CPU, plus the module's tiny training run)."""
    import csv


    out, div = str(tmp_path / "cmp.json"), str(tmp_path / "div")
    assert evaluate_cli.main([run_dir, "--physics", "c,mjx", "--episodes", "4", "--chunk", "2",
                              "--json", out, "--divergence", div]) == 0
    text = capsys.readouterr().out
    assert "difference c - mjx" in text and "divergence.csv" in text
    s = json.load(open(out))
    assert set(s["engines"]) == {"c", "mjx"} and s["episodes"] == 4
    c, m = s["engines"]["c"], s["engines"]["mjx"]
    assert c["physics"] == "c" and m["physics"] == "mjx"
    for e in (c, m):
        assert e["successes"] == round(4 * e["success_rate"])
        assert 0.0 <= e["physics_fault_rate"] <= 1.0 and set(e["final_distance_mean"]) == {
            "left", "right"}
    d = s["difference"]
    assert d["value"] == pytest.approx(c["success_rate"] - m["success_rate"])
    assert d["ci95"][0] <= d["value"] <= d["ci95"][1] and sum(d["paired"].values()) == 4
    with open(os.path.join(div, "divergence.csv"), newline="") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 50 + 1
    assert float(rows[0]["grip_max_m"]) < 1e-4        # the same start on both engines
    assert all(float(r["grip_mean_m"]) <= float(r["grip_max_m"]) + 1e-12 for r in rows)
    assert os.path.getsize(os.path.join(div, "divergence.png")) > 5000
