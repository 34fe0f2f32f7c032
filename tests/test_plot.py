"""Multi-run plots (daddpg_jax/analysis/plotting.py, experiments/plot.py) from fake metrics.csv
files."""

import csv
import json
import os

import numpy as np
import pytest

from daddpg_jax.analysis import plotting
from daddpg_jax.cli import plot as plot_cli
from daddpg_jax.running.metric_columns import METRIC_COLUMNS
from tests.conftest import call_main

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _fake_run(path, success, wall_per_epoch, algo="daddpg", seed=0, n_demos=0):
    os.makedirs(path, exist_ok=True)
    with open(os.path.join(path, "metrics.csv"), "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=METRIC_COLUMNS)
        w.writeheader()
        for i, s in enumerate(success):
            row = {k: 0.0 for k in METRIC_COLUMNS}
            row.update(epoch=i + 1, env_steps=2000 * (i + 1), wall_time=wall_per_epoch * (i + 1),
                       test_success_rate=s, test_arm_contact_rate=0.1 + 0.05 * i)
            w.writerow(row)
    with open(os.path.join(path, "config.json"), "w") as f:
        json.dump({"config": {"task": "reach", "algo": algo, "num_envs": 2, "seed": seed,
                              "n_demos": n_demos}}, f)
    return str(path)


def _check_png(path):
    import matplotlib.image as mpimg

    assert os.path.getsize(path) > 20_000
    img = mpimg.imread(path)
    assert img.shape[0] > 300 and img.shape[1] > 3 * img.shape[0] // 2   # three panels side by side
    rgb = img[..., :3]
    assert (rgb.std(axis=-1) > 0.1).mean() > 0.002     # coloured curves and bands, not just axes


def test_aggregate_mean_and_band(tmp_path):
    a = plotting.read_metrics(_fake_run(tmp_path / "a", [0.0, 0.5, 0.9], 10.0))
    b = plotting.read_metrics(_fake_run(tmp_path / "b", [0.2, 0.7], 12.0, seed=1))
    agg = plotting.aggregate([a, b])
    np.testing.assert_allclose(agg["test_success_rate"]["mean"], [0.1, 0.6, 0.9])
    np.testing.assert_allclose(agg["test_success_rate"]["lo"], [0.0, 0.5, 0.9])
    np.testing.assert_allclose(agg["test_success_rate"]["hi"], [0.2, 0.7, 0.9])
    np.testing.assert_allclose(agg["wall_time"], [11.0, 22.0, 30.0])
    np.testing.assert_array_equal(agg["n"], [2, 2, 1])
    sd = plotting.aggregate([a, b], band="std")
    np.testing.assert_allclose(sd["test_success_rate"]["hi"], [0.2, 0.7, 0.9])
    # seeds of one configuration share a default label
    assert plotting.run_label(str(tmp_path / "a")) == plotting.run_label(str(tmp_path / "b")) \
        == "reach/daddpg"
    d = _fake_run(tmp_path / "d", [0.5], 10.0, n_demos=100)
    assert plotting.run_label(d) == "reach/daddpg+100 demos"


def test_cli_two_runs_png(tmp_path, capsys):
    a = _fake_run(tmp_path / "a", [0.0, 0.4, 0.8, 1.0], 10.0)
    b = _fake_run(tmp_path / "b", [0.1, 0.6, 0.9, 1.0], 11.0, seed=1)
    c = _fake_run(tmp_path / "c", [0.0, 0.1, 0.3, 0.5], 8.0, algo="single")
    out = str(tmp_path / "cmp.png")
    code = call_main(plot_cli.main, [a, b, c, "--out", out, "--title", "fake"])
    r = capsys.readouterr()
    assert code == 0, r.err[-2000:]
    assert "reach/daddpg: 2 run(s)" in r.out and "reach/single: 1 run(s)" in r.out
    _check_png(out)
    assert call_main(plot_cli.main, [a, b, "--labels", "x", "--out", out]) != 0
    assert "--labels" in capsys.readouterr().err


def test_plot_runs_with_labels_and_single_run_curve(tmp_path):
    a = plotting.read_metrics(_fake_run(tmp_path / "a", [0.0, 0.5], 10.0))
    b = plotting.read_metrics(_fake_run(tmp_path / "b", [0.3, 0.6], 10.0))
    out = plotting.plot_runs({"x": [a, b]}, str(tmp_path / "p.png"), band="std")
    _check_png(out)
    assert os.path.exists(plotting.plot_learning_curve(a, str(tmp_path / "one.png")))
    with pytest.raises(FileNotFoundError):
        plotting.read_metrics(str(tmp_path / "missing"))


def test_truncate_to_a_budget():
    rows = [dict(epoch=i + 1, env_steps=2000 * (i + 1), wall_time=10.0 * (i + 1)) for i in range(5)]
    assert [r["epoch"] for r in plotting.truncate(rows, max_wall=30.0)] == [1, 2, 3]
    assert [r["epoch"] for r in plotting.truncate(rows, max_env_steps=4000)] == [1, 2]
    assert [r["epoch"] for r in plotting.truncate(rows, 45.0, 8000)] == [1, 2, 3, 4]
    assert plotting.truncate(rows) == rows
    assert plotting.truncate(rows, max_wall=5.0) == []


def test_cli_budget_cut_and_table(tmp_path, capsys):
    a = _fake_run(tmp_path / "a", [0.0, 0.6, 0.95, 0.2], 10.0)
    b = _fake_run(tmp_path / "b", [0.1, 0.3, 0.4, 0.9, 1.0], 8.0, algo="single")
    out, table = str(tmp_path / "cut.png"), str(tmp_path / "cut.csv")
    code = call_main(plot_cli.main, [a, b, "--max-wall", "32", "--table", table, "--out", out])
    assert code == 0, capsys.readouterr().err[-2000:]
    _check_png(out)
    with open(table, newline="") as f:
        got = list(csv.DictReader(f))
    assert [g["label"] for g in got] == ["reach/daddpg", "reach/single"]
    # a: epochs at 10, 20, 30 s kept (the 40 s epoch is cut); b: 8, 16, 24, 32 s kept
    assert got[0]["epochs"] == "3" and float(got[0]["final_test_success"]) == pytest.approx(0.95)
    assert float(got[0]["env_steps_to_0.5"]) == 4000 and float(got[0]["wall_time_to_0.9"]) == 30.0
    assert got[1]["epochs"] == "4" and float(got[1]["best_test_success"]) == pytest.approx(0.9)
    assert float(got[1]["wall_time_to_0.9"]) == 32.0 and got[1]["algo"] == "single"
    assert got[1]["run"] == b
    capsys.readouterr()
    assert call_main(plot_cli.main, [a, "--max-wall", "5", "--out", out]) == 2
    assert "budget" in capsys.readouterr().err
    assert call_main(plot_cli.main, [a, "--max-wall", "0", "--out", out]) == 2
    assert "--max-wall must be > 0" in capsys.readouterr().err


def test_group_summary_mean_std_and_levels(tmp_path):
    # contact rates of _fake_run: 0.1 + 0.05 * epoch index
    a = plotting.read_metrics(_fake_run(tmp_path / "a", [0.0, 0.5, 0.9, 0.8, 1.0, 0.7], 10.0))
    b = plotting.read_metrics(_fake_run(tmp_path / "b", [0.1, 0.2, 0.3, 0.4, 0.6, 0.5], 10.0))
    c = plotting.read_metrics(_fake_run(tmp_path / "c", [0.2, 0.3], 10.0))
    fa = plotting.run_figures(a, last=5)
    assert fa["final_test_success"] == pytest.approx(0.7)
    assert fa["last_test_success"] == pytest.approx(np.mean([0.5, 0.9, 0.8, 1.0, 0.7]))
    assert fa["best_test_success"] == pytest.approx(1.0)
    assert fa["env_steps_to_0.5"] == 4000 and fa["env_steps_to_0.9"] == 6000
    assert fa["last_arm_contact_rate"] == pytest.approx(0.1 + 0.05 * 3)    # epochs 1..5
    assert fa["mean_arm_contact_rate"] == pytest.approx(0.1 + 0.05 * 2.5)
    assert plotting.run_figures(c, last=5)["last_test_success"] == pytest.approx(0.25)
    rows = plotting.group_summary({"x": [a, b], "y": [c]})
    x, y = rows
    assert (x["label"], x["runs"], y["runs"]) == ("x", 2, 1)
    fb = plotting.run_figures(b)
    for m in plotting.SUMMARY_METRICS[:3]:
        v = [fa[m], fb[m]]
        assert x[f"{m}_mean"] == pytest.approx(np.mean(v))
        assert x[f"{m}_std"] == pytest.approx(np.std(v, ddof=1))
    # env steps to a level: over the runs that reached it, counted
    assert x["reached_0.5"] == 2 and x["reached_0.9"] == 1
    assert x["env_steps_to_0.5_mean"] == pytest.approx((4000 + 10000) / 2)
    assert x["env_steps_to_0.9_mean"] == 6000 and np.isnan(x["env_steps_to_0.9_std"])
    assert np.isnan(y["final_test_success_std"]) and y["reached_0.5"] == 0
    assert np.isnan(y["env_steps_to_0.5_mean"])
    assert set(x) == set(plotting.summary_columns())
    with pytest.raises(ValueError):
        plotting.run_figures([])


def test_cli_summary_csv(tmp_path, capsys):
    a = _fake_run(tmp_path / "a", [0.0, 0.4, 0.8], 10.0)
    b = _fake_run(tmp_path / "b", [0.1, 0.6, 0.6], 11.0, seed=1)
    c = _fake_run(tmp_path / "c", [0.0, 0.1, 0.3], 8.0, algo="ddpg")
    out, summ = str(tmp_path / "cmp.png"), str(tmp_path / "summary.csv")
    code = call_main(plot_cli.main, [a, b, c, "--max-env-steps", "4000", "--summary", summ,
                                     "--out", out])
    r = capsys.readouterr()
    assert code == 0, r.err[-2000:]
    with open(summ) as f:
        rows = {row["label"]: row for row in csv.DictReader(f)}
    assert set(rows) == {"reach/daddpg", "reach/ddpg"}
    d = rows["reach/daddpg"]
    assert d["runs"] == "2"
    # cut at 4000 env steps: epochs 1-2 only
    assert float(d["final_test_success_mean"]) == pytest.approx(0.5)
    assert float(d["final_test_success_std"]) == pytest.approx(np.std([0.4, 0.6], ddof=1))
    assert d["reached_0.5"] == "1"
    assert "reach/daddpg: last-5 test success 0.28 ± 0.11" in r.out


def test_learning_curve_has_success_and_loss_panels_two_x_axes_and_a_title(tmp_path):
    """in-process, < 1 s: the runner's learning_curve.png."""
    run = _fake_run(tmp_path / "a", [0.0, 0.4, 0.8, 1.0], 10.0)
    rows = plotting.read_metrics(run)
    fig = plotting.learning_curve_figure(rows, "reach / daddpg / 2 envs / seed 3")
    top, bottom, q = fig.axes[:3]
    assert "rate" in top.get_ylabel() and "loss" in bottom.get_ylabel()
    assert q.get_ylabel() == "mean Q" and bottom.get_xlabel() == "env steps"
    labels = [t.get_text() for t in top.get_legend().get_texts()]
    assert labels[0] == "test success rate" and "arm-contact rate (test)" in labels
    secondary = [a for a in top.child_axes if a.get_xlabel() == "wall clock (s)"]
    assert len(secondary) == 1
    assert fig._suptitle.get_text() == "reach / daddpg / 2 envs / seed 3"
    out = plotting.plot_learning_curve(rows, str(tmp_path / "lc.png"), "t")
    assert os.path.getsize(out) > 10_000


def test_plot_warns_about_repeated_seeds_and_fewer_runs(tmp_path, capsys):
    """in-process, ~1 s: two runs of one group with seed 0, one of them shorter."""

    a = _fake_run(tmp_path / "a", [0.0, 0.4, 0.8, 1.0], 10.0, seed=0)
    b = _fake_run(tmp_path / "b", [0.1, 0.6], 11.0, seed=0)
    assert plot_cli.main([a, b, "--out", str(tmp_path / "x.png")]) == 0
    err = capsys.readouterr().err
    assert "group 'reach/daddpg' has 2 runs with seed 0" in err
    assert "runs have 2, 4 epochs; after epoch 2 its mean is over fewer runs" in err
    agg = plotting.aggregate([plotting.read_metrics(a), plotting.read_metrics(b)])
    assert list(agg["n"]) == [2, 2, 1, 1]


def test_perturbation_plot_units_integer_ticks_and_error_bars():
    """in-process, < 1 s"""
    from daddpg_jax.analysis import perturbation

    grid = {"obs_noise": [0.0, 0.01], "latency": [0, 1, 2]}
    rows = [dict(obs_noise=n, latency=k, success_rate=0.5, success_ci95_low=0.4,
                 success_ci95_high=0.6) for n in grid["obs_noise"] for k in grid["latency"]]
    fig = perturbation.perturbation_figure(rows, grid, "push / run")
    noise, latency = fig.axes
    assert noise.get_xlabel() == "observation noise std (m)"
    assert latency.get_xlabel() == "action latency (control steps)"
    fig.canvas.draw()
    ticks = [t for t in latency.get_xticks() if 0 <= t <= 2]
    assert ticks and all(float(t).is_integer() for t in ticks)
    assert "95% Wilson interval" in fig._suptitle.get_text()
    assert noise.get_ylabel() == "test success rate"
