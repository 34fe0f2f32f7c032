"""Library code behind the experiment tools that their own tests run only in subprocesses or
in marked tiers: the GPU check's stage records and the scripted
rollout of daddpg-scripted-demo. In-process, fast (the rollout compiles one C-engine program of
a 5-step reach episode, ~3 s)."""

import json

import numpy as np

import mjx_envs
from daddpg_jax.analysis import scripted_rollout
from daddpg_jax.tools import gpu_check, gpu_check_stages


def test_stage_records_read_back_into_the_report(tmp_path):
    """A stage's records (appended by the child) are what the parent merges: rows by key, the
    last record of a key winning; values JSON cannot hold become numbers or text."""
    path = str(tmp_path / "env.jsonl")
    rec = gpu_check_stages.Recorder(path)
    rec("plan", rows={"push/2": {"task": "push"}})
    rec.row("push/2", {"task": "push", "env_steps_per_s": np.float32(12.5)})
    rec.row("push/2", {"task": "push", "env_steps_per_s": 20.0, "dtype": np.dtype("float32")})
    rec("done")
    records = gpu_check.read_records(path)
    assert [r["kind"] for r in records] == ["plan", "row", "row", "done"]
    assert records[1]["env_steps_per_s"] == 12.5 and records[2]["dtype"] == "float32"
    args = gpu_check.parse_args(["--smoke", "--out", str(tmp_path)])
    report = gpu_check.new_report(args, [])
    gpu_check.merge_records(report, "env", records)
    (row,) = report["stages"]["env"]["rows"]
    assert row["env_steps_per_s"] == 20.0 and report["stages"]["env"]["done"]
    json.dumps(report)   # the report stays JSON


def test_one_line_errors_are_cut():
    assert gpu_check_stages._one_line(ValueError("a\nb")) == "ValueError: a"
    assert len(gpu_check_stages._one_line(ValueError("x" * 1000), width=50)) == 50


def test_zero_actions_leave_the_arms_at_rest():
    """The zero policy's rollout: [time, episode, ...] arrays; arms at rest, so the gripper
    (mocap) targets do not move and the final distance is the start's."""
    env = mjx_envs.make("reach", physics="c", episode_length=5)
    traj = scripted_rollout.rollout(env, "zero", episodes=2, seed=0)
    assert traj["success"].shape == (5, 2) and traj["goal"].shape[:2] == (5, 2)
    np.testing.assert_allclose(traj["mocap"][-1], traj["mocap"][0], atol=1e-6)
    dist = scripted_rollout.final_distance(traj)
    assert dist.shape == (2,) and np.all(dist > 0)
