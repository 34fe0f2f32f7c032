"""Smoke test of the benchmark suite (daddpg-benchmark): tiny sizes, JSON layout."""

import json
import math

import pytest

from daddpg_jax.cli import benchmark as bench_cli


@pytest.mark.e2e  # a whole training run (default tier kept under 5 min)
def test_benchmark_suite_writes_json(tmp_path):
    out_path = tmp_path / "bench.json"
    bench_cli.run(["--tasks", "push", "--physics", "c", "--mode", "all", "--sizes", "2",
                    "--steps", "5", "--repeats", "1", "--n-cycles", "1", "--contact-envs", "2",
                    "--set", "hidden=16,16", "--set", "n_batches=2", "--set", "buffer_size=1000",
                    "--env", "episode_length=8", "--out", str(out_path)])
    out = json.loads(out_path.read_text())
    assert out["mode"] == "all" and out["devices"] >= 1 and "machine" in out
    assert math.isfinite(out["load_start"])
    (env_row,) = out["results"]
    assert env_row["task"] == "push" and env_row["physics"] == "c" and env_row["num_envs"] == 2
    assert env_row["physics_steps_per_s"] > 0 and env_row["physics_ok"] == 1.0
    (c,) = out["contacts"]
    assert c["contacts_max"] >= 1 and c["contacts_mean"] > 0   # scripted push touches the bar
    (t,) = out["train"]
    assert t["num_envs"] == 2 and t["n_batches"] == 2 and t["hidden"] == [16, 16]
    assert t["finite"] and t["env_steps_per_s"] > 0 and t["updates_per_s"] > 0
    assert t["compile_s"] > 0 and 0 < t["rollout_share"]
    assert t["host_peak_rss_mb"] > 0 and "device_peak_mb" in t
    assert out["train_settings"]["n_cycles"] == 1
    assert out["train_settings"]["overrides"]["hidden"] == [16, 16]
