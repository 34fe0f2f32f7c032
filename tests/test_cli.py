"""daddpg-train's flags and --help, and the field schema they read (no training here)."""

import os
import re
import shutil
import subprocess
import sys

import pytest

from daddpg_jax.algo.config import (
    FOR_C_ENGINE_ENV,
    ROBUST_ENV,
    ROBUST_OBS,
    TrainConfig,
    build_config,
    current_device,
    for_c_engine_tasks,
    preset,
    preset_env,
    robust_env,
)
from daddpg_jax.cli import train as cli
from daddpg_jax.running import checkpoint as ckpt
from mjx_envs import registry, schema, settings


def _help_values(text: str, section: str) -> dict:
    """{field: [value per task]} from one section of --help (wrapped lines re-joined)."""
    body = text.split(section, 1)[1].split("\n\n", 1)[0]
    lines = re.sub(r"\n      ", " ", body).splitlines()[1:]
    out = {}
    for line in lines:
        m = re.match(r"  (\w+) \((.*?)\): ", line)
        if m:
            vals = m.group(2).split(" | ")
            out[m.group(1)] = vals * len(registry.TASKS) if len(vals) == 1 else vals
    return out


@pytest.mark.parametrize("device", ["cpu", "gpu"])
def test_help_prints_the_values_of_the_configs_actually_built(device):
    text = cli.build_parser(device).format_help()
    train = _help_values(text, "training fields for --set")
    env = _help_values(text, "env fields for --env")
    assert set(train) == set(schema.fields(TrainConfig))
    assert set(env) == {f for t in registry.TASKS
                        for f in schema.fields(type(registry.default_config(t)))}
    assert env["goal_rest_fraction"][registry.TASKS.index("push")] == "-"
    for i, task in enumerate(registry.TASKS):
        cfg = build_config(task, device=device)
        for name, vals in train.items():
            assert vals[i] == schema.describe_value(getattr(cfg, name)), (task, name)
        ecfg = registry.task_config(task, **preset_env(task))
        for name, vals in env.items():
            want = schema.describe_value(getattr(ecfg, name)) if hasattr(ecfg, name) else "-"
            assert vals[i] == want, (task, name)
    # the values that a dataclass-default listing used to get wrong
    assert env["cone"][0] == "pyramidal" and env["target_radius"][1] == "0.06,0.08"
    assert train["n_cycles"][0] == str(build_config("reach", device=device).n_cycles)


def test_preset_device_comes_from_jax_and_can_be_overridden():
    assert current_device() == "cpu"
    assert preset("push") == preset("push", device="cpu")
    gpu = build_config("push", device="gpu")
    assert gpu.physics == "mjx" and gpu.num_envs == 4096
    args = cli.build_parser("cpu").parse_args(["--task", "push", "--device", "gpu",
                                                "--physics", "c"])
    cfg, _, _ = cli.resolve(args, None)
    assert cfg == gpu.replace(physics="c")
    # the accelerator preset's MJX at 4096 envs would hang on this CPU: refused
    args = cli.build_parser("cpu").parse_args(["--task", "push", "--device", "gpu"])
    with pytest.raises(schema.ConfigError, match="num_envs=4096.*use --physics c"):
        cli.resolve(args, None)


def _resolve(*argv):
    return cli.resolve(cli.build_parser("cpu").parse_args(list(argv)), None)


def test_flags_set_and_env_reach_the_config(tmp_path):
    cfg, env_over, run_dir = _resolve("--task", "push", "--num-envs", "4", "--algo", "ddpg",
                                      "--set", "gamma=0.9", "--set", "hidden=64,64",
                                      "--env", "arm_contact_penalty=0.1", "--epochs", "3",
                                      "--out", str(tmp_path / "r"))
    assert cfg == build_config("push", 4, device="cpu", algo="ddpg", gamma=0.9,
                               hidden=(64, 64), n_epochs=3)
    assert env_over == {"arm_contact_penalty": 0.1} and run_dir == str(tmp_path / "r")


def test_robust_adds_the_robust_bounds_that_the_task_has(tmp_path):
    """--robust: the ROBUST_ENV bounds of the task's fields on top of the task's env preset;
    --env still overrides single fields; reach has no object fields; a resume refuses it."""
    _, env_over, _ = _resolve("--task", "pickup", "--robust", "--env", "latency=1")
    assert env_over == {**preset_env("pickup"), **ROBUST_ENV, **ROBUST_OBS, "latency": 1}
    _, env_over, _ = _resolve("--task", "reach", "--robust")
    assert env_over == robust_env("reach") == preset_env("reach", robust=True)
    assert "object_mass" not in env_over and env_over["obs_noise"] == ROBUST_ENV["obs_noise"]
    assert set(env_over) == (set(ROBUST_ENV) | set(ROBUST_OBS)) - {
        "object_mass", "object_size", "object_friction", "table_height"}
    # every bound is a training randomization: test episodes stay nominal; the action history
    # is the policy's input: test episodes keep it
    assert set(ROBUST_ENV) <= set(settings.TRAINING_ONLY_FIELDS)
    assert not set(ROBUST_OBS) & set(registry.test_overrides("pickup"))
    for task in registry.TASKS:
        registry.task_config(task, **preset_env(task, robust=True))   # valid everywhere
    # a recorded config keeps its own env fields and gains the bounds
    run = tmp_path / "old"
    ckpt.save_config(str(run), build_config("push", device="cpu"),
                     env_overrides={"team_scale": 0.5})
    _, env_over, _ = _resolve("--config", str(run), "--robust")
    assert env_over == {"team_scale": 0.5, **robust_env("push")}
    with pytest.raises(schema.ConfigError, match="--robust is decided by the run's config"):
        _resolve("--resume", str(run), "--robust")


def test_for_c_engine_sets_the_measured_recipe_for_mjx_training_only(tmp_path):
    """--for-c-engine: FOR_C_ENGINE_ENV on top of the task's env preset for pickup and pot with
    MJX physics (--env still overrides single fields); refused for other tasks, for a run on
    the C engine (explicit or --physics auto on this CPU) and for a resume."""
    _, env_over, _ = _resolve("--task", "pot", "--physics", "mjx", "--for-c-engine",
                              "--env", "finger_force=0.2")
    assert env_over == {**preset_env("pot"), **FOR_C_ENGINE_ENV, "finger_force": 0.2}
    # randomizations are training's only; the physics version is the run's, test included
    assert set(FOR_C_ENGINE_ENV) - {"physics_version"} <= set(settings.TRAINING_ONLY_FIELDS)
    assert "physics_version" not in settings.TRAINING_ONLY_FIELDS
    assert for_c_engine_tasks() == ("pickup", "pot")   # the tasks' modules say so
    for task in for_c_engine_tasks():
        cfg, env_over, _ = _resolve("--task", task, "--physics", "mjx", "--for-c-engine")
        assert cfg.physics == "mjx" and env_over == {**preset_env(task), **FOR_C_ENGINE_ENV}
        registry.task_config(task, **env_over)   # valid
    with pytest.raises(schema.ConfigError, match="--for-c-engine: measured for pickup and pot"):
        _resolve("--task", "push", "--physics", "mjx", "--for-c-engine")
    for physics in (["--physics", "c"], []):   # auto: the C engine on this CPU
        with pytest.raises(schema.ConfigError, match="recipe for MJX training.*--physics mjx"):
            _resolve("--task", "pickup", *physics, "--for-c-engine")
    run = tmp_path / "old"
    ckpt.save_config(str(run), build_config("pot", device="cpu", physics="mjx"),
                     env_overrides=dict(FOR_C_ENGINE_ENV))
    with pytest.raises(schema.ConfigError, match="--for-c-engine is decided by the run's"):
        _resolve("--resume", str(run), "--for-c-engine")
    _, env_over, _ = _resolve("--resume", str(run))   # the recorded recipe is kept
    assert env_over == FOR_C_ENGINE_ENV


def test_config_file_reruns_a_recorded_configuration(tmp_path):
    rec = build_config("push", 4, device="cpu", algo="maddpg", gamma=0.9, seed=7)
    run = tmp_path / "old"
    ckpt.save_config(str(run), rec, env_overrides={"team_scale": 0.5})
    for where in (str(run / "config.json"), str(run)):
        cfg, env_over, _ = _resolve("--config", where, "--out", str(tmp_path / "new"))
        assert cfg == rec and env_over == {"team_scale": 0.5}
    # flags after it override fields
    cfg, env_over, _ = _resolve("--config", str(run / "config.json"), "--seed", "8",
                                "--set", "polyak=0.9", "--env", "max_delta=0.04")
    assert cfg == rec.replace(seed=8, polyak=0.9)
    assert env_over == {"team_scale": 0.5, "max_delta": 0.04}
    # a new size: the preset's size-dependent fields follow, the recorded ones stay
    cfg, _, _ = _resolve("--config", str(run), "--num-envs", "32")
    assert cfg == rec.replace(**preset("push", 32, device="cpu"))


@pytest.mark.parametrize("argv, message", [
    (["--set", "gama=0.9"], "unknown --set field 'gama'"),
    (["--set", "batch_size=0"], "batch_size must be >= 1"),
    (["--set", "gamma=2"], "gamma must be < 1.0"),
    (["--set", "n_cycles=0"], "n_cycles must be >= 1"),
    (["--set", "hidden="], "hidden must not be empty"),
    (["--set", "q_filter=maybe"], "q_filter expects true or false"),
    (["--set", "gamma"], "--set expects KEY=VALUE"),
    (["--env", "max_delta=-1"], "max_delta must be > 0.0"),
    (["--env", "target_radius=0.1,0.2"], "unknown --env field 'target_radius'"),
    (["--task", "push", "--env", "target_radius=0.2,0.1"], "target_radius must be (min, max)"),
    (["--epochs", "0"], "n_epochs must be >= 1"),
    (["--num-envs", "0"], "num_envs must be >= 1"),
    (["--num-envs", "-3"], "num_envs must be >= 1"),
    (["--resume", "/nonexistent/run"], "no config.json there"),
    (["--config", "/nonexistent/run/config.json"], "no config.json there"),
    (["--resume", "/nonexistent/run", "--force"], "--resume and --force exclude each other"),
    (["--physics", "mjx", "--num-envs", "256"], "num_envs=256: MJX at 256 or more envs"),
])
def test_bad_input_is_one_line_error(argv, message, capsys, tmp_path):
    with pytest.raises(SystemExit) as e:
        cli.main(argv + ["--out", str(tmp_path / "x")])
    err = capsys.readouterr().err
    assert e.value.code == 2 and message in err, err
    assert "Traceback" not in err
    assert not (tmp_path / "x").exists()


def test_out_must_be_new_empty_or_forced(tmp_path, capsys):
    """A new run never writes into a used directory: one-line errors, nothing touched."""
    afile = tmp_path / "file"
    afile.write_text("x")
    other = tmp_path / "other"
    other.mkdir()
    (other / "notes.txt").write_text("keep")
    run = tmp_path / "run"
    ckpt.save_config(str(run), build_config("reach", device="cpu"))
    cases = [(["--out", str(afile)], "is a file, not a directory"),
             (["--out", str(afile / "x")], f"{afile} is a file, not a directory"),
             (["--out", str(other)], "not empty (it holds other files)"),
             (["--out", str(other), "--force"], "--force replaces only a run"),
             (["--out", str(run)], f"not empty (it holds a run); continue a run with --resume "
                                   f"{run}, replace it with --force"),
             (["--force"], "--force needs --out"),
             (["--resume", str(run), "--out", str(other)], "drop --out")]
    for argv, message in cases:
        with pytest.raises(SystemExit) as e:
            cli.main(argv)
        err = capsys.readouterr().err
        assert e.value.code == 2 and message in err and "Traceback" not in err, (argv, err)
        assert len([ln for ln in err.splitlines() if "error:" in ln]) == 1
    assert (other / "notes.txt").read_text() == "keep" and afile.read_text() == "x"
    assert sorted(os.listdir(run)) == ["config.json"]
    # accepted (resolving deletes nothing: the runner does, before anything compiles)
    for argv in (["--out", str(run), "--force"], ["--out", str(tmp_path / "empty")],
                 ["--resume", str(run)], ["--resume", str(run / "config.json")]):
        _, _, run_dir = _resolve(*argv)
        assert os.path.abspath(run_dir) in (str(run), str(tmp_path / "empty"))
    assert sorted(os.listdir(run)) == ["config.json"]


def test_schema_parse_round_trips_every_field():
    for cls, obj in ((TrainConfig, build_config("push", device="cpu")),
                     (type(registry.default_config("push")), registry.default_config("push")),
                     (type(registry.default_config("reach")), registry.default_config("reach"))):
        for name in schema.fields(cls):
            v = getattr(obj, name)
            assert schema.parse(cls, name, schema.describe_value(v)) == v, name
    assert schema.parse(TrainConfig, "buffer_size", "1e6") == 1_000_000
    with pytest.raises(schema.ConfigError):
        schema.parse(TrainConfig, "buffer_size", "1.5")


def test_config_json_lists_become_tuples_and_validate():
    d = TrainConfig().to_dict()
    assert d["hidden"] == [256, 256, 256]
    assert TrainConfig.from_dict({**d, "future_field": 1}) == TrainConfig()
    push = registry.default_config("push")
    env = schema.from_dict(type(push), schema.to_dict(push))
    assert env == registry.default_config("push")
    with pytest.raises(schema.ConfigError, match="polyak must be <= 1.0"):
        TrainConfig.from_dict({**d, "polyak": 1.5})


def test_console_script_is_installed():
    exe = shutil.which("daddpg-train", path=os.path.dirname(sys.executable))
    assert exe, "pip install -e . creates the console scripts"
    out = subprocess.run([exe, "--help"], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and "training fields for --set" in out.stdout


def test_unexpected_errors_are_one_line_unless_debug(tmp_path, capsys, monkeypatch):
    from daddpg_jax.running import runner

    def broken(*a, **k):
        raise RuntimeError("disk on fire")

    monkeypatch.setattr(runner, "train", broken)
    argv = ["--task", "reach", "--no-progress", "--out", str(tmp_path / "r")]
    assert cli.main(argv) == 1
    err = capsys.readouterr().err
    assert "error: RuntimeError: disk on fire" in err and len(err.strip().splitlines()) == 1
    with pytest.raises(RuntimeError, match="disk on fire"):
        cli.main(argv + ["--debug"])
