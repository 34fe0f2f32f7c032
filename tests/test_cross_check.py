"""``daddpg-train --cross-check ENGINE`` (daddpg_jax/running/cross_check.py): the flag's checks
and its record in config.json, the closing warning as a pure function, the best checkpoint
played on the other engine once per new best with one compiled program, and whole runs (the
toy env as both "engines": the columns must agree exactly; MJX reach against the C engine:
within the ±0.10 of docs/MJX_VS_C.md)."""

import csv
import json
import math
import os

import jax
import numpy as np
import pytest

from daddpg_jax.algo.train import make_train_fns
from daddpg_jax.cli import train as train_cli
from daddpg_jax.running import checkpoint as ckpt
from daddpg_jax.running import cross_check as xcheck
from daddpg_jax.running.metric_columns import CROSS_COLUMNS, METRIC_COLUMNS, metric_columns
from daddpg_jax.running.runner import RunOptions, RunResult, train
from daddpg_jax.running.tracking import row_scalars
from mjx_envs.schema import ConfigError
from tests import conftest, toy_env
from tests.conftest import T, call_main, tree_equal

TINY = conftest.TINY.replace(n_cycles=2, n_test_episodes=16, cross_check="mjx")
"""the toy runs' config: 'auto' (the C engine on this CPU) checked on 'mjx' (the toy env)"""
TOY = dict(episode_length=T, threshold=0.15, goal_range=0.1, max_delta=0.02)
"""a toy env whose untrained policies already succeed in part of the test episodes (~0.4-0.6),
so that equal columns are not all zeros"""


class CountingToy(toy_env.ToyReach):
    """The toy env, counting how often its reset is traced (once per compiled program that
    plays episodes) and how many were built."""
    built = 0
    traced = 0

    def __init__(self, **kw):
        super().__init__(**kw)
        CountingToy.built += 1

    def reset(self, key):
        CountingToy.traced += 1   # Python runs this only while JAX traces a program
        return super().reset(key)


@pytest.fixture(scope="module")
def parser():
    return train_cli.build_parser("cpu")   # ~0.6 s each (the field listing of --help)


def _resolve(parser, *argv):
    return train_cli.resolve(parser.parse_args([str(a) for a in argv]), None)


def test_flag_is_checked_and_recorded_for_resume(parser, tmp_path, capsys):
    """--cross-check: the other engine only, off by default, in config.json, kept and
    enforced by --resume (no training, ~3 s: three parsers with their --help field listing)."""
    for physics, engine, backend in (("c", "c", "cpu"), ("mjx", "mjx", "cpu"),
                                     ("auto", "c", "cpu"), ("auto", "mjx", "gpu")):
        with pytest.raises(ConfigError, match=f"--cross-check {engine}: the run already "
                                              f"trains on the engine '{engine}'"):
            xcheck.check(physics, engine, backend=backend, multiprocess=False)
    xcheck.check("auto", "mjx", backend="cpu", multiprocess=False)
    xcheck.check("auto", "c", backend="gpu", multiprocess=False)
    xcheck.check("c", "", backend="cpu", multiprocess=True)     # off: nothing to refuse
    with pytest.raises(ConfigError, match="one-process job"):
        xcheck.check("c", "mjx", backend="cpu", multiprocess=True)
    with pytest.raises(ConfigError, match="unknown engine 'warp'"):
        xcheck.check("c", "warp", backend="cpu", multiprocess=False)
    # the command line: one line, exit 2, nothing written
    out = tmp_path / "x"
    assert call_main(train_cli.main, ["--physics", "c", "--cross-check", "c", "--out", out]) == 2
    err = capsys.readouterr().err
    assert "--cross-check c: the run already trains on the engine 'c'" in err
    assert "--cross-check mjx" in err and not out.exists()
    assert call_main(train_cli.main, ["--cross-check", "c", "--out", out]) == 2   # auto = c
    assert "(--physics auto on this cpu)" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        parser.parse_args(["--cross-check", "warp"])
    assert "invalid choice: 'warp'" in capsys.readouterr().err
    with pytest.raises(ConfigError, match="already trains on the engine 'c'"):
        _resolve(parser, "--physics", "c", "--set", "cross_check=c", "--out", out)
    # off by default: the columns of every run so far
    cfg, _, _ = _resolve(parser, "--task", "reach", "--out", out)
    assert cfg.cross_check == "" and metric_columns(cfg.cross_check) == METRIC_COLUMNS
    # recorded in config.json, kept by --resume, which refuses another engine
    run = str(tmp_path / "run")
    cfg, env_over, _ = _resolve(parser, "--task", "reach", "--physics", "mjx", "--cross-check",
                                "c", "--out", run)
    assert cfg.cross_check == "c" and metric_columns("c") == METRIC_COLUMNS + CROSS_COLUMNS
    ckpt.save_config(run, cfg, env_overrides=env_over)
    assert json.load(open(os.path.join(run, "config.json")))["config"]["cross_check"] == "c"
    assert _resolve(parser, "--resume", run)[0].cross_check == "c"
    assert _resolve(parser, "--resume", run, "--cross-check", "c")[0] == cfg
    with pytest.raises(ConfigError, match="--resume: --cross-check mjx differs from the run's "
                                          r"config \(cross_check c\)"):
        _resolve(parser, "--resume", run, "--cross-check", "mjx")
    # a config.json written before the field existed: off
    payload = json.load(open(os.path.join(run, "config.json")))
    del payload["config"]["cross_check"]
    json.dump(payload, open(os.path.join(run, "config.json"), "w"))
    assert _resolve(parser, "--resume", run)[0].cross_check == ""


@pytest.mark.parametrize("test_best, cross_best, warns", [
    (0.9, 0.7, True), (0.1, 0.25, True), (0.5, 0.39, True), (1.0, 0.0, True),
    (0.9, 0.8, False), (0.8, 0.7, False),      # 0.10 apart, whatever the float rounding
    (np.float32(0.8), np.float32(0.7), False), (0.6, 0.55, False), (0.4, 0.4, False),
    (math.nan, 0.5, False), (0.5, math.nan, False), ("", 0.5, False),
])
def test_parting_warning(test_best, cross_best, warns):
    line = xcheck.parting_warning(test_best, cross_best, "mjx", "c", epoch=7)
    assert (line is not None) == warns
    if warns:
        assert "\n" not in line and line.startswith("--cross-check: ")
        assert f"{float(test_best):.3f} on the training engine (mjx)" in line
        assert f"but {float(cross_best):.3f} on c over the same test episodes" in line
        assert f"{abs(test_best - cross_best):.3f} apart (more than 0.10)" in line
        assert "(epoch 7)" in line and "--physics mjx,c" in line


def test_run_result_closing_lines():
    plain = RunResult("r", 3, 300, 12.0, 0.5, stopped="epochs", why="all 3 epochs done")
    assert plain.summary() == ("run r: 3 epochs, 300 env steps, 12 s, test success 0.500; "
                               "stopped: all 3 epochs done") and plain.cross_warning() is None
    cross = dict(physics="mjx", engine="c", test_success_best=0.9, cross_success_best=0.7,
                 cross_best_epoch=2.0)
    part = RunResult("r", 3, 300, 12.0, 0.5, cross=cross)
    assert part.summary().endswith("; best checkpoint (epoch 2): test success 0.900 on mjx, "
                                   "0.700 on c (--cross-check)")
    assert part.cross_warning() == xcheck.parting_warning(0.9, 0.7, "mjx", "c", 2)
    close = RunResult("r", 3, 300, 12.0, 0.5, cross=dict(cross, cross_success_best=0.85))
    assert close.cross_warning() is None


def test_best_checkpoint_is_played_once_per_new_best_with_one_program(tmp_path, capsys):
    """CrossCheck.columns over a made-up sequence of test successes: the other engine (a
    counting toy env) is built once, its evaluation traced once, and played only when the best
    changes, with the best's parameters; after --resume it reads checkpoints_best/ (~5 s)."""
    env = toy_env.make(**TOY)
    fns = make_train_fns(env, TINY)
    a, b = fns.init(jax.random.PRNGKey(0)), fns.init(jax.random.PRNGKey(1))
    CountingToy.built = CountingToy.traced = 0
    built_cfgs = []

    def make_test_env(cfg):
        built_cfgs.append(cfg)
        return CountingToy(**TOY)

    cross = xcheck.CrossCheck.build(TINY, str(tmp_path / "run"), make_test_env)
    assert [c.physics for c in built_cfgs] == ["mjx"] and built_cfgs[0].buffer_size == 1
    played = []
    evaluate = cross.fns.evaluate
    cross.fns = cross.fns._replace(evaluate=lambda s: played.append(s.agent.actor) or evaluate(s))

    def success(state):
        return float(np.asarray(fns.evaluate(state)["success"]))

    best, rows = -math.inf, []
    for epoch, (state, s) in enumerate([(a, 0.1), (b, 0.3), (a, 0.2), (a, math.nan),
                                        (a, 0.3)], start=1):
        rows.append(cross.columns(state, epoch, s, best))
        best = max(best, s) if not math.isnan(s) else best
    assert [r["test_success_best"] for r in rows] == [0.1, 0.3, 0.3, 0.3, 0.3]
    assert [r["cross_best_epoch"] for r in rows] == [1, 2, 2, 2, 2]
    assert [r["cross_eval_time"] > 0 for r in rows] == [True, True, False, False, False]
    assert len(played) == 2 and tree_equal(played[1], jax.device_get(b.agent.actor))
    # the same env on both sides: the other engine's success is the test success, exactly
    assert rows[0]["cross_success_best"] == success(a)
    assert all(r["cross_success_best"] == success(b) for r in rows[1:])
    assert CountingToy.built == 1 and CountingToy.traced == 1
    # a resumed run: the best checkpoint (epoch 2, b's parameters) read back when first needed
    run = cross.run_dir
    ckpt.save(run, b, 2)
    ckpt.save_best(run, 2)
    resumed = xcheck.CrossCheck(TINY, run, cross.env, cross.fns)
    row = resumed.columns(a, 3, 0.2, 0.3)
    assert row["cross_best_epoch"] == 2 and row["cross_success_best"] == success(b)
    assert len(played) == 3 and tree_equal(played[2], jax.device_get(b.agent.actor))
    assert CountingToy.traced == 1
    # no readable best checkpoint: one warning, NaN columns until the next best
    lost = xcheck.CrossCheck(TINY, str(tmp_path / "empty"), cross.env, cross.fns)
    capsys.readouterr()
    for epoch in (3, 4):
        row = lost.columns(a, epoch, 0.2, 0.3)
        assert math.isnan(row["cross_success_best"]) and row["test_success_best"] == 0.3
    assert capsys.readouterr().err.count("warning: --cross-check") == 1
    assert lost.columns(a, 5, 0.4, 0.3)["cross_best_epoch"] == 5


def _rows(run_dir):
    with open(os.path.join(run_dir, "metrics.csv"), newline="") as f:
        return list(csv.DictReader(f))


def _check_toy_rows(rows):
    """The identical pairing: every row's cross_success_best is, to the digit, the test
    success of the epoch it names, and test_success_best the best test success so far."""
    by_epoch = {r["epoch"]: r for r in rows}
    for i, r in enumerate(rows):
        assert list(r) == list(METRIC_COLUMNS + CROSS_COLUMNS)
        best = max(float(x["test_success_rate"]) for x in rows[:i + 1])
        assert float(r["test_success_best"]) == best
        named = by_epoch[r["cross_best_epoch"]]
        assert r["cross_success_best"] == named["test_success_rate"]
        assert float(named["test_success_rate"]) == best
        assert 0.0 <= float(r["cross_success_best"]) <= 1.0


@pytest.mark.e2e  # whole training runs (toy env), ~40 s on a loaded 2-core CPU
def test_toy_run_writes_both_columns_and_resumes_them(tmp_path):
    """The toy env as both engines: the two columns agree exactly at every epoch, before and
    after --resume; the other env is built and its evaluation traced once per run; the
    trackers get the columns as cross/* and test/success_best."""
    env = toy_env.make(**TOY)
    CountingToy.built = CountingToy.traced = 0

    def make_env(cfg, overrides):
        return CountingToy(**TOY) if cfg.physics == "mjx" else env

    class Rows:
        def __init__(self):
            self.rows = []

        def start(self, *a, **k):
            pass

        def log_row(self, row):
            self.rows.append(row)

        def close(self):
            pass

    seen = Rows()
    run = str(tmp_path / "toy")
    res = train(TINY.replace(n_epochs=3), RunOptions(run, loggers=[seen], make_env=make_env))
    rows = _rows(run)
    _check_toy_rows(rows)
    assert CountingToy.built == 1 and CountingToy.traced == 1
    assert {"test/success_best", "cross/success_best", "cross/best_epoch"} <= set(
        row_scalars(seen.rows[-1]))
    assert res.cross["engine"] == "mjx" and res.cross["physics"] == "c"
    assert res.summary().endswith("(--cross-check)") and res.cross_warning() is None
    assert json.load(open(os.path.join(run, "config.json")))["config"]["cross_check"] == "mjx"
    res = train(TINY.replace(n_epochs=4), RunOptions(run, resume=True, loggers=[],
                                                     make_env=make_env))
    resumed = _rows(run)
    assert resumed[:3] == rows and len(resumed) == 4
    _check_toy_rows(resumed)
    assert CountingToy.built == 2 and CountingToy.traced == 2   # one more run: once more


@pytest.mark.mjx   # one MJX compile (reach, 16 test episodes): ~2 min on a loaded 2-core CPU
def test_reach_run_checks_mjx_where_it_trains_on_c(tmp_path, capsys):
    """daddpg-train --task reach --physics c --cross-check mjx, 2 tiny epochs: both columns
    in [0, 1], and (reach has no contacts) the two engines' success at the best checkpoint
    within the ±0.10 of docs/MJX_VS_C.md; no closing warning then. A goal radius of 0.3 m
    (not 0.02) gives the untrained policy successes to compare (seed 0: 5/16, then 7/16, the
    same on both engines when written)."""
    run = str(tmp_path / "reach")
    sets = ("n_cycles=2", "n_batches=2", "batch_size=32", "buffer_size=10000",
            "n_test_episodes=16", "hidden=64,64")
    argv = ["--task", "reach", "--physics", "c", "--cross-check", "mjx", "--num-envs", "2",
            "--epochs", "2", "--env", "distance_threshold=0.3", "--out", run, "--no-progress",
            "--no-tensorboard"]
    assert call_main(train_cli.main, argv + [x for s in sets for x in ("--set", s)]) == 0
    out, err = capsys.readouterr()
    rows = _rows(run)
    assert len(rows) == 2 and list(rows[0]) == list(METRIC_COLUMNS + CROSS_COLUMNS)
    for r in rows:
        test_best, cross_best = float(r["test_success_best"]), float(r["cross_success_best"])
        assert 0.0 <= test_best <= 1.0 and 0.0 <= cross_best <= 1.0
        assert abs(test_best - cross_best) <= xcheck.PART_TOLERANCE + 1e-6
        assert r["cross_best_epoch"] in ("1", "2")
    assert max(float(r["test_success_best"]) for r in rows) > 0   # not only zeros compared
    assert float(rows[0]["cross_eval_time"]) > 0
    assert "on c, " in out and "on mjx (--cross-check)" in out
    assert "warning: --cross-check" not in err
    assert json.load(open(os.path.join(run, "config.json")))["config"]["cross_check"] == "mjx"
