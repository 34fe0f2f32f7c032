"""experiments/robustness.py: perturbation grids of several runs summarized per group."""

import json
import math

import pytest

from daddpg_jax.analysis import robustness


def _grid(path, rates, contact=0.0):
    """A perturbation.json over obs_noise x latency with the given success rates (in order)."""
    points = [(n, lat) for n in (0.0, 0.01) for lat in (0, 1)]
    rows = [dict(obs_noise=n, latency=lat, success_rate=r, arm_contact_rate=contact)
            for (n, lat), r in zip(points, rates, strict=True)]
    path.mkdir(parents=True)
    (path / "perturbation.json").write_text(json.dumps(
        dict(grid={"obs_noise": [0.0, 0.01], "latency": [0, 1]}, rows=rows)))
    return str(path)


def test_summary_is_the_mean_and_std_over_each_groups_runs(tmp_path):
    a = [_grid(tmp_path / f"a{i}", r) for i, r in enumerate([[1, .9, .8, .7], [1, .7, .6, .5]])]
    b = [_grid(tmp_path / "b0", [1, 1, 1, .9], contact=0.5)]
    keys, rows = robustness.summarize({"plain": a, "robust": b})
    assert keys == ["obs_noise", "latency"] and len(rows) == 8
    at = robustness.rows_at(rows, {"obs_noise": 0.01, "latency": 1})
    plain, robust = (r for r in at)
    assert plain["group"] == "plain" and plain["runs"] == 2
    assert math.isclose(plain["success_mean"], 0.6) and math.isclose(plain["success_std"], 0.1)
    assert plain["success_min"] == 0.5 and plain["success_per_run"] == "0.70/0.50"
    assert robust["success_mean"] == 0.9 and robust["success_std"] == 0.0
    assert robust["arm_contact_mean"] == 0.5


def test_cli_writes_table_json_and_plot(tmp_path, capsys):
    a = _grid(tmp_path / "a", [1, .9, .8, .7])
    b = _grid(tmp_path / "b", [1, 1, 1, .9])
    out = tmp_path / "out"
    assert robustness.main(["--group", f"plain={a}", "--group", f"robust={b}",
                            "--at", "obs_noise=0.01", "--at", "latency=1",
                            "--out", str(out)]) == 0
    assert "success 0.70" in capsys.readouterr().out
    data = json.loads((out / "robustness.json").read_text())
    assert [r["success_mean"] for r in data["at_rows"]] == [0.7, 0.9]
    assert (out / "robustness.png").stat().st_size > 1000
    header = (out / "robustness.csv").read_text().splitlines()[0]
    assert header.startswith("obs_noise,latency,group")


@pytest.mark.parametrize("argv, message", [
    (["--group", "plain"], "expected NAME=DIR1"),
    (["--group", "plain={a}", "--at", "latency=x"], "expected KEY=NUMBER"),
    (["--group", "plain={a}", "--at", "obs_dropout=0"], "not in the grid"),
    (["--group", "plain={a},{other}"], "grid keys"),
    (["--group", "plain={missing}"], "no perturbation.json"),
])
def test_bad_input_is_one_line_error(tmp_path, capsys, argv, message):
    a = _grid(tmp_path / "a", [1, .9, .8, .7])
    other = tmp_path / "o"
    other.mkdir()
    (other / "perturbation.json").write_text(json.dumps(dict(grid={"latency": [0]}, rows=[
        dict(latency=0, success_rate=1.0, arm_contact_rate=0.0)])))
    argv = [x.format(a=a, other=other, missing=tmp_path / "none") for x in argv]
    assert robustness.main([*argv, "--out", str(tmp_path / "out")]) == 2
    assert message in capsys.readouterr().err
