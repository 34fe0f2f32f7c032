"""The overhead measurements (experiments/overhead): TensorBoard's steps/s figure and the
randomization-cost script on a tiny reach batch (C engine, ~5 s)."""

import json
import math

from experiments.overhead import randomization_cost, tensorboard_overhead


def test_steps_per_second_between_first_and_last_row():
    rows = [{"env_steps": "100", "wall_time": "2.0"}, {"env_steps": "300", "wall_time": "3.0"},
            {"env_steps": "500", "wall_time": "6.0"}]
    assert math.isclose(tensorboard_overhead.steps_per_s(rows), 100.0)


def test_cost_script_measures_off_and_on(tmp_path):
    out = tmp_path / "cost.json"
    randomization_cost.main(["--task", "reach", "--sizes", "2", "--repeats", "1", "--out",
                             str(out)])
    data = json.loads(out.read_text())
    assert [r["randomization"] for r in data["rows"]] == ["off", "on"]
    assert all(r["env_steps_per_s"] > 0 for r in data["rows"])
    assert "object_mass" not in data["fields"] and data["fields"]["base_yaw"] == 2.0
