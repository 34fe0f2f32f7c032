"""The on-disk run (runner + CLI): outputs, resume equality, non-finite stop, --help."""

import csv
import json
import os
import subprocess
import sys

import pytest

from daddpg_jax.analysis.plotting import plot_learning_curve
from daddpg_jax.cli import train as train_cli
from daddpg_jax.running import checkpoint as ckpt
from daddpg_jax.running.metric_columns import METRIC_COLUMNS
from daddpg_jax.running.runner import NonFiniteLoss, RunDirError, train
from tests import conftest, toy_env
from tests.conftest import T, call_main, run_options

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TINY = conftest.TINY.replace(n_cycles=2, n_batches=3, n_test_episodes=8, seed=3,
                             save_buffer=True)


@pytest.fixture(scope="module")
def env():
    return toy_env.make(episode_length=T)


def _rows(run_dir):
    with open(os.path.join(run_dir, "metrics.csv")) as f:
        return list(csv.DictReader(f))


def _learning_columns(rows):
    skip = {"wall_time", "env_steps_per_s", "updates_per_s", "rollout_time", "update_time",
            "eval_time"}
    return [{k: v for k, v in r.items() if k not in skip} for r in rows]


@pytest.mark.e2e  # ~7-15 s: kept out of the default tier's 5 minutes
def test_epoch_time_is_split_into_rollout_update_and_evaluation(env, tmp_path):
    run = str(tmp_path / "t")
    train(TINY.replace(n_epochs=2), run_options(run, env))
    rows = _rows(run)
    for r in rows:
        roll, upd, ev = (float(r[k]) for k in ("rollout_time", "update_time", "eval_time"))
        assert roll > 0 and upd > 0 and ev > 0
        epoch_s = float(r["env_steps"]) / float(r["epoch"]) / float(r["env_steps_per_s"])
        assert roll + upd <= epoch_s * 1.001 + 1e-3
    # the first epoch's rollout time holds the compilation
    assert float(rows[0]["rollout_time"]) > float(rows[1]["rollout_time"])


@pytest.mark.e2e  # a whole training run (default tier kept under 5 min)
def test_run_outputs_and_resume_equals_uninterrupted(env, tmp_path):
    a, b = str(tmp_path / "a"), str(tmp_path / "b")
    full = train(TINY.replace(n_epochs=2), run_options(a, env, plot=plot_learning_curve))
    assert full.epochs == 2 and full.env_steps == 2 * TINY.n_cycles * TINY.num_envs * T
    for name in ("config.json", "metrics.csv", "learning_curve.png"):
        assert os.path.getsize(os.path.join(a, name)) > 0, name
    assert ckpt.all_steps(a) == [1, 2]
    payload = json.load(open(os.path.join(a, "config.json")))
    assert payload["config"]["seed"] == 3 and "jax" in payload["versions"]
    rows = _rows(a)
    assert list(rows[0].keys()) == list(METRIC_COLUMNS)
    assert [int(r["epoch"]) for r in rows] == [1, 2]

    train(TINY.replace(n_epochs=1), run_options(b, env))
    resumed = train(TINY.replace(n_epochs=2), run_options(b, env, resume=True))
    assert resumed.epochs == 2
    assert _learning_columns(_rows(b)) == _learning_columns(rows)


@pytest.mark.e2e
def test_resume_rewrites_a_metrics_csv_of_older_columns(env, tmp_path):
    """A run whose metrics.csv predates the bc_loss/q_filter_pass columns resumes; the CSV is
    rewritten with every current column (blank where the old rows had none)."""
    run = str(tmp_path / "old")
    train(TINY.replace(n_epochs=1), run_options(run, env))
    old_cols = [c for c in METRIC_COLUMNS if c not in ("bc_loss", "q_filter_pass")]
    rows = _rows(run)
    with open(os.path.join(run, "metrics.csv"), "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=old_cols)
        w.writeheader()
        w.writerows({k: r[k] for k in old_cols} for r in rows)
    train(TINY.replace(n_epochs=2), run_options(run, env, resume=True))
    new = _rows(run)
    assert list(new[0].keys()) == list(METRIC_COLUMNS)
    assert new[0]["bc_loss"] == "" and new[1]["bc_loss"] == "nan"
    assert new[0]["test_success_rate"] == rows[0]["test_success_rate"]


@pytest.mark.e2e
def test_stop_at_success_stops_after_the_first_epoch_at_the_rate(env, tmp_path):
    run = str(tmp_path / "stop")
    res = train(TINY.replace(n_epochs=3), run_options(run, env, stop_at_success=0.0))
    assert res.epochs == 1 and [int(r["epoch"]) for r in _rows(run)] == [1]
    never = train(TINY.replace(n_epochs=2),
                  run_options(str(tmp_path / "never"), env, stop_at_success=1.01))
    assert never.epochs == 2


def test_resume_without_a_run_fails_clearly(env, tmp_path):
    with pytest.raises(RunDirError, match="no config.json"):
        train(TINY.replace(n_epochs=1), run_options(str(tmp_path / "empty"), env, resume=True))


@pytest.mark.e2e
def test_nonfinite_loss_stops_and_keeps_last_good_checkpoint(env, tmp_path):
    run = str(tmp_path / "nan")
    train(TINY.replace(n_epochs=1, save_buffer=False), run_options(run, env))
    # the config rejects NaN settings: NaN rewards (an env whose penalty is NaN) make the
    # critic loss non-finite instead
    nan_env = toy_env.make(episode_length=T, contact_penalty=float("nan"))
    with pytest.raises(NonFiniteLoss, match="last good checkpoint"):
        train(TINY.replace(n_epochs=2, save_buffer=False), run_options(run, nan_env, resume=True))
    assert ckpt.all_steps(run) == [1]
    assert [int(r["epoch"]) for r in _rows(run)] == [1]


def test_cli_help_explains_every_flag_and_field(capsys):
    assert call_main(train_cli.main, ["--help"]) == 0
    text = capsys.readouterr().out
    for flag in ("--task", "--num-envs", "--epochs", "--seed", "--algo", "--her", "--physics",
                 "--out", "--resume", "--set", "--env", "--save-buffer", "--time-budget",
                 "--stop-at-success",
                 "--demos"):
        assert flag in text, flag
    for field in ("gamma", "polyak", "noise_eps", "random_eps", "batch_size", "n_demos",
                  "bc_weight", "q_filter", "max_delta",
                  "distance_threshold", "arm_contact_penalty"):
        assert f"  {field} (" in text, field


def test_cli_rejects_unknown_fields(tmp_path, capsys):
    assert call_main(train_cli.main, ["--set", "gama=0.9", "--out", tmp_path / "x"]) != 0
    assert "unknown --set field 'gama'" in capsys.readouterr().err


def test_cli_rejects_demos_without_a_scripted_controller(tmp_path, capsys):
    run = ["--out", tmp_path / "x"]
    assert call_main(train_cli.main, run + ["--task", "reach", "--demos", "10"]) == 2
    assert "has no scripted controller" in capsys.readouterr().err
    assert call_main(train_cli.main, run + ["--task", "pickup", "--demos", "-1"]) == 2
    assert "n_demos must be >= 0" in capsys.readouterr().err
    assert call_main(train_cli.main, run + ["--stop-at-success", "1.5"]) == 2
    assert "--stop-at-success must be in [0, 1]" in capsys.readouterr().err
    assert not os.path.exists(tmp_path / "x")


@pytest.mark.e2e
def test_cli_trains_reach_tiny(tmp_path):
    """The real reach env through the CLI: one tiny epoch writes every output."""
    run = str(tmp_path / "reach")
    cmd = [sys.executable, os.path.join(ROOT, "experiments", "run.py"), "--task", "reach",
           "--epochs", "1", "--physics", "c", "--out", run, "--no-progress",
           "--set", "n_cycles=2", "--set", "n_batches=2", "--set", "hidden=32,32",
           "--set", "n_test_episodes=10", "--set", "buffer_size=10000"]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert out.returncode == 0, out.stderr[-2000:]
    assert "test success" in out.stdout
    rows = _rows(run)
    assert len(rows) == 1 and int(rows[0]["env_steps"]) == 2 * 2 * 50
    assert 0.0 <= float(rows[0]["test_success_rate"]) <= 1.0
    assert ckpt.all_steps(run) == [1]
    assert os.path.exists(os.path.join(run, "learning_curve.png"))


def test_chunked_test_episodes_give_the_same_metrics(env):
    """The trainer's test episodes in batches (MJX on a CPU: mjx_envs.settings.MJX_CPU_CHUNK)
    give the metrics of one batch: 8 episodes as 3 + 3 + 2 (padded) (~5 s, toy env)."""
    import jax
    import numpy as np

    from daddpg_jax.algo.train import make_train_fns

    whole = make_train_fns(env, TINY)
    chunked = make_train_fns(env, TINY, eval_chunk=3)
    state = whole.init()
    state, _ = whole.train_epoch(state)   # a policy that is not the initial one
    a, b = jax.device_get(whole.evaluate(state)), jax.device_get(chunked.evaluate(state))
    assert set(a) == set(b)
    for k in a:
        np.testing.assert_allclose(a[k], b[k], rtol=1e-6, atol=1e-7, err_msg=k)
    key = jax.random.PRNGKey(11)
    c, d = jax.device_get(whole.evaluate(state, key)), jax.device_get(chunked.evaluate(state, key))
    assert all(np.allclose(c[k], d[k], rtol=1e-6, atol=1e-7) for k in c)
