"""Training runs under failure (docs/RELIABILITY.md, "Training runs"): used run directories,
unreadable checkpoints, kills at any moment (SIGKILL, then --resume: bit-exact with
--save-buffer), metrics.csv consistency, the best checkpoint, physics faults, the MJX-on-CPU
guard and the non-finite-loss message."""

import csv
import errno
import fcntl
import os
import random
import shutil
import signal
import subprocess
import sys
import time

import jax
import numpy as np
import orbax.checkpoint as ocp
import pytest

from daddpg_jax.algo import train as algo_train
from daddpg_jax.cli import export as export_cli
from daddpg_jax.cli import train as train_cli
from daddpg_jax.running import checkpoint as ckpt
from daddpg_jax.running import run_record, runner
from daddpg_jax.running.metric_columns import METRIC_COLUMNS
from daddpg_jax.running.runner import (
    NonFiniteLoss,
    RunDirError,
    train,
)
from mjx_envs.schema import ConfigError
from tests import conftest, toy_env
from tests.conftest import T, run_options, tree_equal

pytestmark = pytest.mark.usefixtures("arm_recorder")  # every command checked

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
RUN_PY = os.path.join(ROOT, "experiments", "run.py")
TINY = conftest.TINY.replace(n_cycles=2, n_batches=3, n_test_episodes=8, seed=3,
                             save_buffer=True)
TIMING = {"wall_time", "env_steps_per_s", "updates_per_s", "rollout_time", "update_time",
          "eval_time"}
REACH_ARGS = ["--task", "reach", "--physics", "c", "--set", "n_cycles=1", "--set", "n_batches=2",
              "--set", "hidden=16", "--set", "batch_size=32", "--set", "n_test_episodes=4",
              "--set", "buffer_size=2000", "--save-buffer", "--no-progress"]
"""the tiny reach run of the CLI tests and of the kill tests (an epoch: ~0.2 s + checkpoint)"""


@pytest.fixture(scope="module")
def env():
    return toy_env.make(episode_length=T)


def _rows(run_dir):
    path = os.path.join(run_dir, "metrics.csv")
    if not os.path.exists(path):
        return []
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def _epochs(run_dir):
    return [int(r["epoch"]) for r in _rows(run_dir)]


def _learning(rows):
    return [{k: v for k, v in r.items() if k not in TIMING} for r in rows]


def _truncate_a_data_file(run_dir, step):
    d = os.path.join(ckpt.step_dir(run_dir, step), "state", "ocdbt.process_0", "d")
    # the largest: array chunks (a small one may be an unreferenced older b-tree node)
    path = max((os.path.join(d, n) for n in os.listdir(d)), key=os.path.getsize)
    with open(path, "r+b") as f:
        f.truncate(10)
    return path


def _one_error_line(err: str) -> str:
    lines = [ln for ln in err.strip().splitlines() if ln.startswith(("error", "daddpg-train: "))]
    assert "Traceback" not in err and len(lines) == 1, err
    return lines[0]


# -- 1. run directories ----------------------------------------------------------------------

@pytest.fixture(scope="module")
def cli_run(tmp_path_factory):
    """A tiny reach run of 2 epochs written by daddpg-train (in this process)."""
    run = str(tmp_path_factory.mktemp("cli") / "reach")
    assert train_cli.main([*REACH_ARGS, "--epochs", "2", "--out", run]) == 0
    return run


@pytest.mark.e2e
def test_used_out_directory_is_refused_unless_force(cli_run, tmp_path, capsys):
    run = str(tmp_path / "run")
    shutil.copytree(cli_run, run)
    before = sorted(os.listdir(os.path.join(run, "checkpoints")))
    with pytest.raises(SystemExit) as e:
        train_cli.main([*REACH_ARGS, "--epochs", "1", "--out", run])
    line = _one_error_line(capsys.readouterr().err)
    assert e.value.code == 2 and "not empty" in line and "--resume" in line and "--force" in line
    assert sorted(os.listdir(os.path.join(run, "checkpoints"))) == before
    # --force: the old run is deleted, a new one of 1 epoch takes its place
    assert train_cli.main([*REACH_ARGS, "--epochs", "1", "--out", run, "--force"]) == 0
    assert ckpt.all_steps(run) == [1] and _epochs(run) == [1]
    assert ckpt.all_steps(run, best=True) == [1]
    # the library refuses too (no StepAlreadyExistsError traceback from orbax)
    cfg, _ = ckpt.load_config(run)
    with pytest.raises(RunDirError, match="already holds a run"):
        train(cfg, run_options(run))


# -- 2. checkpoint fallback, restart from epoch 0 --------------------------------------------

@pytest.mark.e2e
def test_resume_falls_back_past_an_unreadable_checkpoint(env, tmp_path, capfd):
    ref, run = str(tmp_path / "ref"), str(tmp_path / "run")
    full = train(TINY.replace(n_epochs=4), run_options(ref, env))
    train(TINY.replace(n_epochs=3), run_options(run, env))
    bad = _truncate_a_data_file(run, 3)
    capfd.readouterr()
    res = train(TINY.replace(n_epochs=4), run_options(run, env, resume=True))
    err = capfd.readouterr().err
    assert f"checkpoint 3 ({ckpt.step_dir(run, 3)}) cannot be read" in err
    assert "OUT_OF_RANGE" in err and "Traceback" not in err and "Exception ignored" not in err
    assert "resuming from checkpoint 2" in err and not os.path.exists(bad)
    assert res.epochs == 4 and _epochs(run) == [1, 2, 3, 4]
    assert _learning(_rows(run)) == _learning(_rows(ref))      # --save-buffer: bit-exact
    assert ckpt.all_steps(run) == ckpt.all_steps(ref) == [2, 3, 4]
    assert full.test_success_rate == res.test_success_rate


@pytest.mark.e2e
def test_resume_with_no_readable_checkpoint_is_one_line(cli_run, tmp_path, capsys):
    run = str(tmp_path / "run")
    shutil.copytree(cli_run, run)
    for step in ckpt.all_steps(run):
        _truncate_a_data_file(run, step)
    assert train_cli.main(["--resume", run, "--epochs", "3", "--no-progress"]) == 2
    err = capsys.readouterr().err
    line = _one_error_line(err)
    assert "no checkpoint of" in line and "can be read" in line and "--force" in line
    assert ckpt.all_steps(run) == [1, 2]          # nothing deleted


@pytest.mark.e2e
def test_run_killed_in_its_first_epoch_restarts_from_epoch_0(env, tmp_path, capfd):
    ref, run = str(tmp_path / "ref"), str(tmp_path / "run")
    train(TINY.replace(n_epochs=2), run_options(ref, env))
    train(TINY.replace(n_epochs=1), run_options(run, env))
    # as if killed while writing checkpoint 1: its row written, the checkpoint not complete
    os.rename(ckpt.step_dir(run, 1), os.path.join(ckpt.checkpoint_dir(run),
                                                  "1.orbax-checkpoint-tmp-123"))
    shutil.rmtree(ckpt.checkpoint_dir(run, best=True))
    capfd.readouterr()
    train(TINY.replace(n_epochs=2), run_options(run, env, resume=True))
    err = capfd.readouterr().err
    assert "no complete checkpoint" in err and "starting it again from epoch 0" in err
    assert _learning(_rows(run)) == _learning(_rows(ref))
    assert sorted(os.listdir(ckpt.checkpoint_dir(run))) == ["1", "2"]


def test_resume_of_a_directory_without_config_is_an_error(env, tmp_path):
    (tmp_path / "x").mkdir()
    with pytest.raises(RunDirError, match="no config.json"):
        train(TINY, run_options(str(tmp_path / "x"), env, resume=True))


# -- 3. metrics.csv --------------------------------------------------------------------------

@pytest.mark.e2e
def test_metrics_rows_beyond_the_checkpoint_and_torn_rows_are_dropped(env, tmp_path):
    ref, run = str(tmp_path / "ref"), str(tmp_path / "run")
    train(TINY.replace(n_epochs=3), run_options(ref, env))
    train(TINY.replace(n_epochs=2), run_options(run, env))
    path = os.path.join(run, "metrics.csv")
    with open(path, "a", newline="") as f:      # a row written, its checkpoint not; a torn row
        f.write("3,480,18,1.0,0.5" + ",0" * (len(METRIC_COLUMNS) - 5) + "\r\n4,640,2")
    train(TINY.replace(n_epochs=3), run_options(run, env, resume=True))
    assert _learning(_rows(run)) == _learning(_rows(ref))


def test_metrics_csv_is_replaced_atomically(tmp_path, monkeypatch):
    path = str(tmp_path / "metrics.csv")
    rows = [{"epoch": 1, "env_steps": 10}, {"epoch": 2, "env_steps": 20}]
    run_record.write_rows(path, rows[:1])
    before = open(path).read()

    def fail(src, dst):
        raise OSError("killed here")

    monkeypatch.setattr(os, "replace", fail)
    with pytest.raises(OSError):
        run_record.write_rows(path, rows)
    assert open(path).read() == before        # the old file, whole
    monkeypatch.undo()
    run_record.write_rows(path, rows)
    assert _epochs(str(tmp_path)) == [1, 2] and not os.path.exists(path + ".tmp")


# -- 4. the best checkpoint ------------------------------------------------------------------

def _scripted_success(monkeypatch, table):
    """The trainer's evaluation reports test success table[epoch - 1]."""
    real = algo_train.make_train_fns

    def make(env, cfg, **kw):
        fns = real(env, cfg, **kw)

        def evaluate(state, key=None):
            ev = dict(fns.evaluate(state, key))
            ev["success"] = np.float32(table[int(state.cycles) // cfg.n_cycles - 1])
            return ev

        return fns._replace(evaluate=evaluate)

    monkeypatch.setattr(runner, "make_train_fns", make)


@pytest.mark.e2e
def test_best_checkpoint_is_kept_across_resumes(env, tmp_path, monkeypatch):
    _scripted_success(monkeypatch, [0.25, 0.75, 0.5, 0.75, 0.5])
    cfg = TINY.replace(keep_checkpoints=1)
    ref, run = str(tmp_path / "ref"), str(tmp_path / "run")
    train(cfg.replace(n_epochs=5, keep_checkpoints=10), run_options(ref, env))
    train(cfg.replace(n_epochs=3), run_options(run, env))
    assert ckpt.all_steps(run) == [3] and ckpt.all_steps(run, best=True) == [2]
    train(cfg.replace(n_epochs=5), run_options(run, env, resume=True))
    assert ckpt.all_steps(run) == [5] and ckpt.all_steps(run, best=True) == [2]  # earliest tie
    template = algo_train.make_train_fns(env, cfg).init(jax.random.PRNGKey(0))
    best, step = ckpt.restore(run, template, best=True)
    at2, _ = ckpt.restore(ref, template, step=2, restore_buffer=False)
    assert step == 2 and tree_equal(best.agent, at2.agent) and tree_equal(best.obs_norm,
                                                                          at2.obs_norm)


@pytest.mark.e2e
def test_best_checkpoint_is_repaired_on_resume(env, tmp_path, monkeypatch, capfd):
    _scripted_success(monkeypatch, [0.25, 0.75, 0.5, 0.5])
    run = str(tmp_path / "run")
    train(TINY.replace(n_epochs=3), run_options(run, env))
    # killed between checkpoint 2 and its copy to checkpoints_best, and a later best of an
    # abandoned epoch (beyond the checkpoint resumed from) plus a partial copy
    shutil.rmtree(ckpt.step_dir(run, 2, best=True))
    shutil.copytree(ckpt.step_dir(run, 3), ckpt.step_dir(run, 9, best=True))
    os.makedirs(os.path.join(ckpt.checkpoint_dir(run, best=True), ".copy-3"))
    train(TINY.replace(n_epochs=4), run_options(run, env, resume=True))
    assert sorted(os.listdir(ckpt.checkpoint_dir(run, best=True))) == ["2"]
    assert "warning" not in capfd.readouterr().err


@pytest.mark.e2e
def test_export_best(cli_run, tmp_path, capsys):
    from daddpg_jax.deploy import NumpyPolicy

    out = str(tmp_path / "best.npz")
    best = ckpt.all_steps(cli_run, best=True)
    assert len(best) == 1
    assert export_cli.main([cli_run, "--best", "--out", out]) == 0
    meta = NumpyPolicy.load(out).meta["source"]
    assert meta["checkpoint_step"] == best[0] and meta["best"] is True
    assert "(best test success)" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        export_cli.main([cli_run, "--best", "--step", "1", "--out", out])
    old = str(tmp_path / "old")
    shutil.copytree(cli_run, old)
    shutil.rmtree(ckpt.checkpoint_dir(old, best=True))
    assert export_cli.main([old, "--best", "--out", out]) == 2
    assert "no best checkpoint" in capsys.readouterr().err


# -- 5. non-finite loss before any checkpoint -------------------------------------------------

@pytest.mark.e2e  # a whole training run (default tier kept under 5 min)
def test_nonfinite_loss_in_the_first_epoch_says_no_checkpoint(tmp_path):
    nan_env = toy_env.make(episode_length=T, contact_penalty=float("nan"))
    with pytest.raises(NonFiniteLoss) as e:
        train(TINY.replace(n_epochs=1, save_buffer=False),
              run_options(str(tmp_path / "r"), nan_env))
    assert "No checkpoint was written" in str(e.value) and "None" not in str(e.value)


# -- 6. physics faults -----------------------------------------------------------------------

def _expected_fault_rate(env, cfg):
    from daddpg_jax.algo import acting

    keys = acting.episode_keys(jax.random.PRNGKey(cfg.eval_seed), cfg.n_test_episodes)
    goals = np.asarray(jax.vmap(env.reset)(keys).obs["desired_goal"])
    return float(np.mean(goals[:, 0, 0] > env.config.fault_goal_x))


@pytest.mark.e2e
def test_physics_fault_rates_are_logged_and_warned(tmp_path, capfd):
    cfg = TINY.replace(n_epochs=2, save_buffer=False, n_test_episodes=32)
    faulty = toy_env.make(episode_length=T, fault_goal_x=-0.1)
    capfd.readouterr()
    train(cfg, run_options(str(tmp_path / "f"), faulty))
    err = capfd.readouterr().err
    rows = _rows(str(tmp_path / "f"))
    want = _expected_fault_rate(faulty, cfg)
    assert 0.2 < want < 0.8
    for r in rows:
        assert float(r["test_physics_fault_rate"]) == pytest.approx(want)
        assert 0.0 < float(r["train_physics_fault_rate"]) < 1.0
    warnings = [ln for ln in err.splitlines() if "physics faults" in ln]
    assert len(warnings) == 2 and warnings[0].startswith("warning: epoch 1: physics faults")
    # no fault: rate 0, no warning; an env without physics_ok: NaN, no warning
    for e, rate in ((toy_env.make(episode_length=T, fault_goal_x=1.0), "0.0"),
                    (toy_env.make(episode_length=T), "nan")):
        run = str(tmp_path / rate)
        train(cfg.replace(n_epochs=1), run_options(run, e))
        assert _rows(run)[0]["test_physics_fault_rate"] == rate
        assert "physics faults" not in capfd.readouterr().err


@pytest.mark.e2e
def test_c_engine_physics_faults_in_metrics_and_evaluation(cli_run, tmp_path, capfd):
    """A 0.3 s timestep makes MuJoCo's C engine diverge ('Nan, Inf or huge value in QACC'):
    every episode is frozen; the trainer and daddpg-evaluate report it."""
    from daddpg_jax.analysis import evaluation

    assert float(_rows(cli_run)[-1]["test_physics_fault_rate"]) == 0.0
    run = str(tmp_path / "unstable")
    assert train_cli.main([*REACH_ARGS, "--epochs", "1", "--out", run,
                           "--env", "timestep=0.3"]) == 0
    err = capfd.readouterr().err
    row = _rows(run)[0]
    assert float(row["train_physics_fault_rate"]) == 1.0
    assert float(row["test_physics_fault_rate"]) == 1.0
    assert len([ln for ln in err.splitlines() if ln.startswith("warning: epoch 1: physics")]) == 1
    s, _ = evaluation.evaluate(evaluation.load_policy(run), episodes=4)
    assert s["physics_fault_rate"] == 1.0 and s["physics_fault_episodes"] == 4
    assert "physics faults    1.000" in evaluation.format_summary(s)


# -- 7. MJX on a CPU -------------------------------------------------------------------------

def test_mjx_on_cpu_at_256_envs_is_refused_before_compiling(tmp_path):
    """(test episodes are played in batches of MJX_CPU_CHUNK there instead: test_runner.py)"""
    cfg = TINY.replace(task="reach", physics="mjx", num_envs=256)
    t0 = time.perf_counter()
    with pytest.raises(ConfigError, match="use --physics c"):
        train(cfg, run_options(str(tmp_path / "m")))
    assert time.perf_counter() - t0 < 5 and not os.path.exists(tmp_path / "m")
    runner.check_physics_backend("mjx", 256, backend="gpu")   # accelerators: fine
    runner.check_physics_backend("c", 4096)
    runner.check_physics_backend("mjx", 255)


# -- 8. kill -9 at random moments, then --resume ----------------------------------------------

def _launch(args, log):
    return subprocess.Popen([sys.executable, RUN_PY, *args], cwd=ROOT, stdout=log,
                            stderr=subprocess.STDOUT)


def _disk(run):
    """(complete checkpoint steps, names of partial entries) under checkpoints*/."""
    steps, partial = [], []
    for best in (False, True):
        d = ckpt.checkpoint_dir(run, best)
        for n in (os.listdir(d) if os.path.isdir(d) else []):
            if n.isdigit():
                steps += [] if best else [int(n)]
            else:
                partial.append(n)
    return sorted(steps), partial


def _wait_for(pred, proc, timeout=120.0):
    """Polls pred every ms; False if proc ended first."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return True
        if proc.poll() is not None:
            return False
        time.sleep(0.001)
    raise TimeoutError("nothing happened in time")


def _kill(proc, run, mode, rng, t_launch):
    """Kills proc (SIGKILL) as `mode` says; returns what was on disk then (None: it ended):
    complete checkpoints, the partial saves this process left, the CSV's epochs."""
    steps0, partial0 = _disk(run)
    at_launch = max(steps0, default=0)
    if mode == "anytime":
        deadline = t_launch + rng.uniform(0.0, 7.0)
        if not _wait_for(lambda: time.monotonic() >= deadline, proc):
            return None
    else:
        if not _wait_for(lambda: max(_disk(run)[0], default=0) > at_launch, proc):
            return None
        if mode == "in_save":
            if not _wait_for(lambda: set(_disk(run)[1]) - set(partial0), proc):
                return None
        else:
            deadline = time.monotonic() + rng.uniform(0.0, 0.8)
            if not _wait_for(lambda: time.monotonic() >= deadline, proc):
                return None
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    steps, partial = _disk(run)
    return dict(mode=mode, t=round(time.monotonic() - t_launch, 2), steps=steps,
                partial=sorted(set(partial) - set(partial0)), rows=_epochs(run))


def _check_after_kill(k):
    rows, steps = k["rows"], k["steps"]
    assert rows == list(range(1, len(rows) + 1)), k           # contiguous, no duplicate
    assert all(s in rows for s in steps), k                   # no row of a checkpoint lost
    assert not steps or len(rows) <= steps[-1] + 1, k         # at most the epoch being saved


def _interrupted_run(run, epochs, plan, rng, log):
    proc = _launch([*REACH_ARGS, "--epochs", str(epochs), "--out", run], log)
    kills = []
    for mode in plan:
        k = _kill(proc, run, mode, rng, time.monotonic())
        if k is None:     # the run ended before the moment came
            break
        _check_after_kill(k)
        kills.append(k)
        proc = _launch(["--resume", run, "--epochs", str(epochs), "--no-progress"], log)
    assert proc.wait(timeout=300) == 0
    return kills


def _raw(path):
    return ocp.StandardCheckpointer().restore(path)


_REFERENCES = {}


def _reference(tmp_path_factory, epochs):
    if epochs not in _REFERENCES:
        run = str(tmp_path_factory.mktemp("ref") / "run")
        out = subprocess.run([sys.executable, RUN_PY, *REACH_ARGS, "--epochs", str(epochs),
                              "--out", run], cwd=ROOT, capture_output=True, text=True,
                             timeout=300)
        assert out.returncode == 0, out.stderr[-2000:]
        _REFERENCES[epochs] = run
    return _REFERENCES[epochs]


QUICK = ["after_ckpt", "in_save", "anytime"]
KILL_SEED = 20261204
"""the quick plan's fixed schedule of kill moments"""
SLOW = ["after_ckpt", "in_save", "anytime", "anytime", "in_save", "after_ckpt", "anytime",
        "in_save", "anytime", "after_ckpt"]


@pytest.mark.e2e
@pytest.mark.parametrize("epochs, plan, seed", [
    pytest.param(6, QUICK, KILL_SEED, id="6-plan0"),
    pytest.param(12, SLOW, None, marks=pytest.mark.slow, id="12-plan1")])
def test_kill_9_at_random_moments_then_resume_is_bit_exact(tmp_path_factory, epochs, plan, seed):
    """The quick plan kills at moments drawn from a fixed seed (the same moments every run,
    ~40 s: e2e tier); the slow one draws them from the clock (a new schedule each run, ~2 min).
    DADDPG_KILL_SEED=N replays a schedule of either."""
    ref = _reference(tmp_path_factory, epochs)
    seed = int(os.environ.get("DADDPG_KILL_SEED", time.time_ns() % 2**31 if seed is None
                              else seed))
    rng = random.Random(seed)
    run = str(tmp_path_factory.mktemp("killed") / "run")
    with open(os.path.join(os.path.dirname(run), "log.txt"), "w") as log:
        t0 = time.monotonic()
        kills = _interrupted_run(run, epochs, plan, rng, log)
        total = time.monotonic() - t0
    log_text = open(os.path.join(os.path.dirname(run), "log.txt")).read()
    assert "Traceback" not in log_text, log_text[-3000:]
    assert len(kills) >= min(2, len(plan))
    rows, want = _rows(run), _rows(ref)
    assert _epochs(run) == list(range(1, epochs + 1))
    assert _learning(rows) == _learning(want)
    assert ckpt.all_steps(run) == ckpt.all_steps(ref)
    assert ckpt.all_steps(run, best=True) == ckpt.all_steps(ref, best=True)
    for item in ("state", "buffer"):
        got, exp = (_raw(os.path.join(ckpt.step_dir(r, epochs), item)) for r in (run, ref))
        assert tree_equal(got, exp), item
    b = ckpt.all_steps(ref, best=True)[0]
    assert tree_equal(_raw(os.path.join(ckpt.step_dir(run, b, best=True), "state")),
                      _raw(os.path.join(ckpt.step_dir(ref, b, best=True), "state")))
    in_save = sum(1 for k in kills if k["partial"])
    ahead = sum(1 for k in kills if len(k["rows"]) > max(k["steps"], default=0))
    print(f"\n[measured] seed {seed}: {len(kills)} kills survived in {total:.1f} s "
          f"({in_save} while a checkpoint was being written, {ahead} with a CSV row ahead of "
          "the newest checkpoint); kills: "
          + "; ".join(f"{k['mode']} {k['t']} s, ckpts {k['steps']}, partial {k['partial']}, "
                      f"rows {len(k['rows'])}" for k in kills))


# -- 9. runs never mix, and every failure is one line ----------------------------------------

def _hold_lock(run: str) -> int:
    """The run directory's lock, held as another process holds it (its own open file)."""
    os.makedirs(run, exist_ok=True)
    fd = os.open(os.path.join(run, ckpt.LOCK_FILE), os.O_RDWR | os.O_CREAT)
    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    return fd


@pytest.mark.e2e  # a whole training run (default tier kept under 5 min)
def test_a_run_directory_in_use_is_refused_with_one_line(env, tmp_path, capsys):
    """~2 s: the CLI and the library refuse a directory whose lock is held, writing nothing."""
    run = str(tmp_path / "run")
    fd = _hold_lock(run)
    try:
        with pytest.raises(SystemExit) as e:
            train_cli.main([*REACH_ARGS, "--epochs", "1", "--out", run])
        line = _one_error_line(capsys.readouterr().err)
        assert e.value.code == 2 and "another process" in line
        with pytest.raises(ckpt.RunLockedError, match="another process"):
            train(TINY.replace(n_epochs=1), run_options(run, env))
        assert os.listdir(run) == [ckpt.LOCK_FILE]
    finally:
        os.close(fd)
    # released: a directory holding only the lock file counts as empty
    assert train(TINY.replace(n_epochs=1), run_options(run, env)).epochs == 1


@pytest.mark.e2e
def test_two_runs_started_at_once_on_one_out(tmp_path):
    """~30-60 s: two daddpg-train processes on the same new --out; one trains, the other
    stops with one line and writes nothing."""
    run = str(tmp_path / "run")
    procs = [subprocess.Popen([sys.executable, RUN_PY, *REACH_ARGS, "--epochs", "1",
                               "--no-tensorboard", "--out", run], cwd=ROOT, text=True,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE)
             for _ in range(2)]
    outs = [p.communicate(timeout=600) for p in procs]
    codes = [p.returncode for p in procs]
    assert sorted(codes) == [0, 2], outs
    line = _one_error_line(outs[codes.index(2)][1])
    assert "another process" in line or "not empty" in line
    assert ckpt.all_steps(run) == [1] and _epochs(run) == [1]


CORRUPT_CONFIGS = {
    "not JSON": ("{not json", "invalid JSON"),
    "a list": ("[1, 2]", "a JSON list"),
    "no config key": ('{"versions": {}}', "no 'config' entry"),
    "a bad value": ('{"config": {"hidden": "abc"}}', "invalid training config"),
}


@pytest.mark.parametrize("what", CORRUPT_CONFIGS)
def test_corrupt_config_json_is_one_line(cli_run, tmp_path, capsys, what):
    """< 1 s each: --resume, daddpg-export and daddpg-evaluate name the file in one line."""
    from daddpg_jax.cli import evaluate as evaluate_cli

    run = str(tmp_path / "run")
    shutil.copytree(cli_run, run)
    path = os.path.join(run, "config.json")
    text, why = CORRUPT_CONFIGS[what]
    with open(path, "w") as f:
        f.write(text)
    with pytest.raises(SystemExit) as e:
        train_cli.main(["--resume", run, "--epochs", "3", "--no-progress"])
    assert e.value.code == 2
    lines = [_one_error_line(capsys.readouterr().err)]
    assert export_cli.main([run, "--out", str(tmp_path / "p.npz")]) == 2
    lines.append(_one_error_line(capsys.readouterr().err))
    assert evaluate_cli.main([run, "--episodes", "2"]) == 2
    lines.append(_one_error_line(capsys.readouterr().err))
    for line in lines:
        assert path in line and why in line, line
    assert ckpt.all_steps(run) == [1, 2] and not os.path.exists(tmp_path / "p.npz")


def test_export_and_evaluate_fall_back_past_an_unreadable_checkpoint(cli_run, tmp_path,
                                                                      capsys):
    """~5 s: the newest readable checkpoint with a warning, as --resume; one line when none
    (or the asked-for --step) can be read; nothing deleted."""
    from daddpg_jax.cli import evaluate as evaluate_cli
    from daddpg_jax.deploy import NumpyPolicy

    run = str(tmp_path / "run")
    shutil.copytree(cli_run, run)
    _truncate_a_data_file(run, 2)
    out = str(tmp_path / "p.npz")
    assert export_cli.main([run, "--out", out]) == 0
    err = capsys.readouterr().err
    assert f"checkpoint 2 ({ckpt.step_dir(run, 2)}) cannot be read" in err
    assert "OUT_OF_RANGE" in err and "Traceback" not in err and "Exception ignored" not in err
    assert NumpyPolicy.load(out).meta["source"]["checkpoint_step"] == 1
    assert evaluate_cli.main([run, "--episodes", "2", "--json"]) == 0
    cap = capsys.readouterr()
    assert '"checkpoint": 1' in cap.out and "checkpoint 2" in cap.err
    assert "Traceback" not in cap.err
    assert export_cli.main([run, "--step", "2", "--out", out]) == 2
    assert f"checkpoint 2 of {run} cannot be read" in _one_error_line(capsys.readouterr().err)
    _truncate_a_data_file(run, 1)
    for main, argv in ((export_cli.main, [run, "--out", out]),
                       (evaluate_cli.main, [run, "--episodes", "2"])):
        assert main(argv) == 2
        line = _one_error_line(capsys.readouterr().err)
        assert "no checkpoint of" in line and "can be read" in line
    assert ckpt.all_steps(run) == [1, 2]


def test_export_cli_writes_onnx_of_a_run(cli_run, tmp_path, capsys):
    """~2 s: daddpg-export --format onnx; the graph acts as the .npz of the same checkpoint."""
    pytest.importorskip("onnxruntime")
    from daddpg_jax.deploy import NumpyPolicy
    from daddpg_jax.deploy.onnx_policy import OnnxPolicy

    onnx_out, npz_out = str(tmp_path / "p.onnx"), str(tmp_path / "p.npz")
    assert export_cli.main([cli_run, "--format", "onnx", "--out", onnx_out]) == 0
    assert export_cli.main([cli_run, "--out", npz_out]) == 0
    assert f"wrote {onnx_out}" in capsys.readouterr().out
    a, b = OnnxPolicy.load(onnx_out), NumpyPolicy.load(npz_out)
    assert a.meta == b.meta
    rng = np.random.default_rng(0)
    o, g = rng.normal(size=(64, 2, 25)), rng.normal(size=(64, 2, 3))
    np.testing.assert_allclose(a.act(o, g), b.act(o, g), rtol=0, atol=1e-5)


@pytest.mark.e2e  # a whole training run (default tier kept under 5 min)
def test_full_disk_during_a_checkpoint_save_is_one_line_and_resumable(cli_run, tmp_path,
                                                                      monkeypatch, capsys):
    """~5 s: orbax's save fails with ENOSPC halfway (its temporary directory written) at
    epoch 2: one line, exit code 1, no partial checkpoint left; --resume then finishes the
    run as if nothing happened (--save-buffer: the same rows as the uninterrupted run)."""
    run = str(tmp_path / "run")
    real = ocp.CheckpointManager.save

    def full_disk(self, step, *a, **k):
        if int(step) == 2:
            os.makedirs(os.path.join(str(self.directory), f"2{ckpt._ORBAX_TMP}-1", "state"))
            raise ValueError("Failed to write checkpoint") from OSError(
                errno.ENOSPC, "No space left on device")
        return real(self, step, *a, **k)

    monkeypatch.setattr(ocp.CheckpointManager, "save", full_disk)
    assert train_cli.main([*REACH_ARGS, "--epochs", "2", "--out", run]) == 1
    line = _one_error_line(capsys.readouterr().err)
    assert "could not save checkpoint 2" in line and "No space left on device" in line
    assert f"--resume {run}" in line
    assert sorted(os.listdir(ckpt.checkpoint_dir(run))) == ["1"]
    monkeypatch.undo()
    assert train_cli.main(["--resume", run, "--epochs", "2", "--no-progress"]) == 0
    assert _learning(_rows(run)) == _learning(_rows(cli_run))
    assert ckpt.all_steps(run) == [1, 2]


@pytest.mark.parametrize("argv, what", [
    (["--set", "hidden=100000,100000"], "hidden=100000,100000"),
    (["--set", "buffer_size=10000000000"], "buffer_size=10,000,000,000"),
])
def test_sizes_that_cannot_fit_in_memory_are_refused_before_allocating(tmp_path, capsys,
                                                                       argv, what):
    """~2 s each: the training state's size from its shapes, refused in one line."""
    run = str(tmp_path / "run")
    assert train_cli.main([*REACH_ARGS, *argv, "--epochs", "1", "--out", run]) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert what in line and "memory" in line and "available" in line
    assert os.listdir(run) == [ckpt.LOCK_FILE]


def test_evaluation_too_large_for_memory_is_one_line(cli_run, capsys):
    """~2 s: daddpg-evaluate --episodes 1000000000 is refused before allocating."""
    from daddpg_jax.cli import evaluate as evaluate_cli

    assert evaluate_cli.main([cli_run, "--episodes", "1000000000"]) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert "1,000,000,000 episodes" in line and "--episodes" in line


@pytest.mark.e2e  # a whole training run (default tier kept under 5 min)
def test_planted_symlinks_are_never_written_through(env, tmp_path):
    """~3 s: files named as the temporary files of older versions, planted as symlinks in a
    run directory, are not written through (temporary names are new, O_EXCL, random)."""
    victim = tmp_path / "victim"
    victim.write_text("keep")
    run = str(tmp_path / "run")
    train(TINY.replace(n_epochs=1), run_options(run, env))
    planted = ["metrics.csv.tmp", "config.json.tmp", "learning_curve.tmp.png",
               "learning_curve.png.tmp"]
    for name in planted:
        os.symlink(victim, os.path.join(run, name))
    os.symlink(tmp_path, os.path.join(ckpt.checkpoint_dir(run, best=True), ".copy-2"))
    train(TINY.replace(n_epochs=2), run_options(run, env, resume=True))
    ckpt.save_config(run, TINY)
    assert victim.read_text() == "keep" and _epochs(run) == [1, 2]
    assert not [n for n in os.listdir(run) if n.startswith(".tmp-")]
    for name in planted:
        assert os.path.islink(os.path.join(run, name))
