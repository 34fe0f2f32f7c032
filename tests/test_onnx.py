"""ONNX export of the policy (daddpg_jax/deploy/onnx_policy.py): one graph equal to NumpyPolicy
for every variant and task, the same validation on loading, and daddpg-serve serving it.
Random-weight exports, no training; the whole module takes ~5 s."""

from __future__ import annotations

import json
import os
import types
import urllib.request

import numpy as np
import pytest

onnx = pytest.importorskip("onnx")
ort = pytest.importorskip("onnxruntime")

import mjx_envs  # noqa: E402
from daddpg_jax.algo import normalizer, variants  # noqa: E402
from daddpg_jax.algo.config import TrainConfig  # noqa: E402
from daddpg_jax.cli import export as export_cli  # noqa: E402
from daddpg_jax.deploy import NumpyPolicy, PolicyFormatError  # noqa: E402
from daddpg_jax.deploy.onnx_policy import (  # noqa: E402
    INPUTS,
    OUTPUT,
    OnnxPolicy,
    load_policy,
)
from daddpg_jax.deploy.policy import file_sha256  # noqa: E402
from daddpg_jax.deploy.server import PolicyServer  # noqa: E402
from daddpg_jax.running.export import policy_arrays, write_export  # noqa: E402
from mjx_envs import settings  # noqa: E402

N_INPUTS = 1000


@pytest.fixture(scope="module")
def envs():
    return {t: mjx_envs.make(t, physics="c") for t in settings.TASKS}


def random_state(cfg: TrainConfig, env, seed: int):
    """A TrainState's parts that an export reads (actors, normalizers), drawn at random: the
    trainer's initialization of the kernels (Glorot uniform, networks.MLP), random biases and
    normalizer statistics."""
    rng = np.random.default_rng(seed)
    v = variants.get(cfg.algo)
    sizes = [v.input_dims(env.obs_size, env.goal_size)[0], *cfg.hidden, v.agent_action_dim]
    glorot = lambda a, b: np.sqrt(6.0 / (a + b))  # noqa: E731
    params = {f"Dense_{i}": {
        "kernel": rng.uniform(-glorot(a, b), glorot(a, b), (v.num_agents, a, b))
                     .astype(np.float32),
        "bias": rng.normal(0, 0.1, (v.num_agents, b)).astype(np.float32)}
        for i, (a, b) in enumerate(zip(sizes[:-1], sizes[1:]))}

    def norm(n):
        return normalizer.NormState(count=np.float32(500.0),
                                    mean=rng.normal(0, 0.3, (2, n)).astype(np.float32),
                                    m2=rng.uniform(0.01, 40.0, (2, n)).astype(np.float32))

    return types.SimpleNamespace(agent=types.SimpleNamespace(actor={"params": params}),
                                 obs_norm=norm(env.obs_size), goal_norm=norm(env.goal_size))


def random_inputs(n: int, seed: int, obs_size: int, goal_size: int):
    rng = np.random.default_rng(seed)
    o = rng.normal(0.0, 1.0, (n, 2, obs_size)).astype(np.float32)
    o[: n // 10] *= 300.0  # some beyond clip_obs and the normalizer clip
    g = rng.uniform(-0.5, 0.8, (n, 2, goal_size)).astype(np.float32)
    return o, g


def _export(tmp_path, envs, task, algo, seed=0, fmt="onnx"):
    env = envs[task]
    cfg = TrainConfig(task=task, algo=algo, hidden=(32, 24))
    arrays = policy_arrays(random_state(cfg, env, seed), cfg, env, {"checkpoint_step": 3})
    return write_export(arrays, str(tmp_path / f"{task}_{algo}.{fmt}")), arrays


@pytest.mark.parametrize("task", settings.TASKS)
@pytest.mark.parametrize("algo", variants.ALGOS)
def test_onnxruntime_equals_numpy_policy(tmp_path, envs, task, algo):
    seed = 10 * settings.TASKS.index(task) + variants.ALGOS.index(algo)
    path, arrays = _export(tmp_path, envs, task, algo, seed=seed)
    npz = write_export(arrays, str(tmp_path / "p.npz"))
    ref, pol = NumpyPolicy.load(npz), OnnxPolicy.load(path)
    o, g = random_inputs(N_INPUTS, 1, ref.obs_size, ref.goal_size)
    a_ref, a = ref.act(o, g), pol.act(o, g)
    assert a.shape == (N_INPUTS, 8) and a.dtype == np.float32
    np.testing.assert_allclose(a, a_ref, rtol=0, atol=1e-5)
    assert np.abs(a).max() > 0.5          # not all squashed to 0: the test can fail
    # the graph itself, with onnxruntime alone: names and shapes as documented
    sess = ort.InferenceSession(path, providers=["CPUExecutionProvider"])
    assert [i.name for i in sess.get_inputs()] == list(INPUTS)
    assert [i.shape for i in sess.get_inputs()] == [["batch", 2, ref.obs_size],
                                                    ["batch", 2, ref.goal_size]]
    assert [(x.name, x.shape) for x in sess.get_outputs()] == [(OUTPUT, ["batch", 8])]
    (raw,) = sess.run(None, {"observation": o[:7], "desired_goal": g[:7]})
    np.testing.assert_allclose(raw, a_ref[:7], rtol=0, atol=1e-5)
    # the same metadata as the .npz, and leading axes as NumpyPolicy takes them
    assert sess.get_modelmeta().custom_metadata_map["meta"] == str(arrays["meta"])
    info, want = pol.info(), ref.info()
    assert info.pop("policy_sha256") == file_sha256(path) != want.pop("policy_sha256")
    assert info == want
    np.testing.assert_allclose(pol.act(o[0], g[0]), a_ref[0], atol=1e-5)
    assert pol.act_per_arm(o[:3], g[:3]).shape == (3, 2, 4)


def _rewrite_meta(path, out, **changes):
    model = onnx.load(path)
    for p in model.metadata_props:
        if p.key == "meta":
            meta = json.loads(p.value)
            meta.update(changes)
            p.value = json.dumps(meta)
    onnx.save(model, out)
    return out


def test_onnx_loading_is_validated_like_npz(tmp_path, envs):
    path, _ = _export(tmp_path, envs, "push", "maddpg")
    bad = str(tmp_path / "bad.onnx")
    cases = {
        "format version": dict(format_version=99),
        "unknown algo": dict(algo="nope"),
        "actor input size": dict(actor_input_dim=7),
    }
    for what, change in cases.items():
        with pytest.raises(PolicyFormatError, match=what) as e:
            OnnxPolicy.load(_rewrite_meta(path, bad, **change))
        assert "bad.onnx" in str(e.value) and "daddpg-onnx-" not in str(e.value)
    # NaN weights: the .npz reader's check, on the arrays of the graph
    model = onnx.load(path)
    w = next(i for i in model.graph.initializer if i.name == "actor/W0")
    arr = onnx.numpy_helper.to_array(w).copy()
    arr[0, 0, 0] = np.nan
    w.CopyFrom(onnx.numpy_helper.from_array(arr, "actor/W0"))
    onnx.save(model, bad)
    with pytest.raises(PolicyFormatError, match="NaN"):
        OnnxPolicy.load(bad)
    with open(bad, "wb") as f:
        f.write(b"not a model")
    with pytest.raises(PolicyFormatError, match="not a readable ONNX file"):
        load_policy(bad)
    with pytest.raises(FileNotFoundError):
        load_policy(str(tmp_path / "missing.onnx"))
    # bad inputs: NumpyPolicy's errors
    pol = load_policy(path)
    with pytest.raises(ValueError, match="shape"):
        pol.act(np.zeros((2, 24), np.float32), np.zeros((2, 3), np.float32))
    with pytest.raises(ValueError, match="NaN"):
        pol.act(np.full((2, 25), np.nan, np.float32), np.zeros((2, 3), np.float32))


def test_serve_either_format(tmp_path, envs):
    path, arrays = _export(tmp_path, envs, "reach", "daddpg")
    npz = write_export(arrays, str(tmp_path / "p.npz"))
    o, g = random_inputs(1, 5, 25, 3)
    body = json.dumps({"observation": o[0].tolist(), "desired_goal": g[0].tolist()}).encode()
    answers = {}
    for f in (path, npz):
        pol = load_policy(f)
        assert isinstance(pol, OnnxPolicy if f.endswith(".onnx") else NumpyPolicy)
        server = PolicyServer(pol, port=0).start()
        try:
            req = urllib.request.Request(server.url + "/act", data=body,
                                         headers={"Content-Type": "application/json"})
            with urllib.request.urlopen(req, timeout=10) as r:
                answers[f] = json.loads(r.read())["action"]
        finally:
            server.stop()
    np.testing.assert_allclose(answers[path], answers[npz], atol=1e-5)


def test_export_cli_format_must_match_the_name(tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        export_cli.main([str(tmp_path), "--format", "onnx", "--out", str(tmp_path / "p.npz")])
    assert e.value.code == 2
    assert "--format onnx needs an --out name ending in .onnx" in capsys.readouterr().err
    assert not os.listdir(tmp_path)
