"""ONNX export of the policy (daddpg_jax/deploy/onnx_policy.py): one graph equal to NumpyPolicy
for every variant and task, the same validation on loading, and daddpg-serve serving it; graphs
that must not load (operators outside the allow-list, subgraphs, other domains, external data,
unbounded values, a graph not computing the policy of its own weights) and the compute-time cap
of each call. Random-weight exports, no training; the whole module takes ~8 s."""

from __future__ import annotations

import json
import os
import time
import types
import urllib.request

import numpy as np
import pytest

onnx = pytest.importorskip("onnx")
ort = pytest.importorskip("onnxruntime")

import mjx_envs  # noqa: E402
from daddpg_jax import variants  # noqa: E402
from daddpg_jax.algo import normalizer  # noqa: E402
from daddpg_jax.algo.config import TrainConfig  # noqa: E402
from daddpg_jax.cli import export as export_cli  # noqa: E402
from daddpg_jax.deploy import NumpyPolicy, PolicyFormatError  # noqa: E402
from daddpg_jax.deploy.onnx_policy import (  # noqa: E402
    INPUTS,
    OPSET,
    OUTPUT,
    OnnxPolicy,
    load_policy,
)
from daddpg_jax.deploy.policy import file_sha256  # noqa: E402
from daddpg_jax.deploy.server import PolicyServer  # noqa: E402
from daddpg_jax.running.export import policy_arrays, write_export  # noqa: E402
from mjx_envs import registry  # noqa: E402

N_INPUTS = 1000


@pytest.fixture(scope="module")
def envs():
    return {t: mjx_envs.make(t, physics="c") for t in registry.TASKS}


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


@pytest.mark.parametrize("task", registry.TASKS)
@pytest.mark.parametrize("algo", variants.ALGOS)
def test_onnxruntime_equals_numpy_policy(tmp_path, envs, task, algo):
    seed = 10 * registry.TASKS.index(task) + variants.ALGOS.index(algo)
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


# -- graphs that must not load, and the compute-time cap ---------------------------------------

def _mutated(path, out, change):
    """The export at ``path`` with ``change(model)`` applied, saved to ``out``."""
    model = onnx.load(path)
    change(model)
    onnx.save(model, out)
    return out


def _one_line_refusal_of(load) -> str:
    with pytest.raises(PolicyFormatError) as e:
        load()
    msg = str(e.value)
    assert msg and "\n" not in msg, msg
    return msg


def _one_line_refusal(path) -> str:
    return _one_line_refusal_of(lambda: OnnxPolicy.load(path))


def _add_loop(model):
    """A Loop of 2^62 steps (its body passes its value on), as a core-pinning graph would."""
    from onnx import TensorProto, helper, numpy_helper

    body = helper.make_graph(
        [helper.make_node("Identity", ["c"], ["c_out"]),
         helper.make_node("Identity", ["x"], ["x_out"])], "body",
        [helper.make_tensor_value_info("i", TensorProto.INT64, []),
         helper.make_tensor_value_info("c", TensorProto.BOOL, []),
         helper.make_tensor_value_info("x", TensorProto.FLOAT, None)],
        [helper.make_tensor_value_info("c_out", TensorProto.BOOL, []),
         helper.make_tensor_value_info("x_out", TensorProto.FLOAT, None)])
    model.graph.initializer.extend([numpy_helper.from_array(np.array(2 ** 62, np.int64), "n"),
                                    numpy_helper.from_array(np.array(True), "go")])
    model.graph.node.append(helper.make_node("Loop", ["n", "go", "actions"], ["looped"],
                                             body=body))


def _with_graph_attribute(op_type):
    def change(model):
        from onnx import helper

        empty = helper.make_graph([], "g", [], [])
        kw = ({"then_branch": empty, "else_branch": empty} if op_type == "If"
              else {"body": empty, "num_scan_inputs": 1})
        inputs = ["go"] if op_type == "If" else ["actions"]
        model.graph.node.append(helper.make_node(op_type, inputs, [f"{op_type}_out"], **kw))
    return change


def _relu_with_subgraph(model):
    from onnx import helper

    node = next(n for n in model.graph.node if n.op_type == "Relu")
    node.attribute.append(helper.make_attribute("body", helper.make_graph([], "g", [], [])))


def _custom_domain(model):
    next(n for n in model.graph.node if n.op_type == "Relu").domain = "com.example"


def _custom_opset(model):
    from onnx import helper

    model.opset_import.append(helper.make_opsetid("com.example", 1))


def _local_function(model):
    from onnx import helper

    model.functions.append(helper.make_function("com.example", "F", ["x"], ["y"],
                                                [helper.make_node("Relu", ["x"], ["y"])],
                                                [helper.make_opsetid("", OPSET)]))


def _external_weights(model):
    from onnx import TensorProto

    w = next(i for i in model.graph.initializer if i.name == "actor/W0")
    w.ClearField("raw_data")
    w.ClearField("float_data")
    w.data_location = TensorProto.EXTERNAL
    entry = w.external_data.add()
    entry.key, entry.value = "location", "secret.bin"


def _many_nodes(model):
    from onnx import helper

    prev = "actions"
    for i in range(1100):
        model.graph.node.append(helper.make_node("Relu", [prev], [f"r{i}"]))
        prev = f"r{i}"


@pytest.mark.parametrize("change,words", [
    (_add_loop, "operator 'Loop'"),
    (_with_graph_attribute("Scan"), "operator 'Scan'"),
    (_with_graph_attribute("If"), "operator 'If'"),
    (_relu_with_subgraph, "subgraphs and tensors are refused"),
    (_custom_domain, "of domain 'com.example'"),
    (_custom_opset, "opset of domain 'com.example'"),
    (_local_function, "defines functions"),
    (_external_weights, "tensor data outside the file"),
    (_many_nodes, "more than 1024"),
], ids=["loop", "scan", "if", "subgraph", "domain", "opset", "function", "external", "nodes"])
def test_graphs_outside_the_allow_list_are_refused(tmp_path, envs, change, words):
    """A graph with a 2^62-step Loop loaded and pinned a core per request; now any operator but
    those the exporter writes (no Loop, Scan, If), subgraph or tensor attributes, other domains,
    functions, data outside the file (never read: the named file exists here) and more than
    MAX_NODES nodes are refused at once, with one line; the export itself loads (positive
    control); ~0.1 s each."""
    path, _ = _export(tmp_path, envs, "push", "maddpg")
    OnnxPolicy.load(path)
    (tmp_path / "secret.bin").write_bytes(b"\0" * 4096)
    t0 = time.perf_counter()
    msg = _one_line_refusal(_mutated(path, str(tmp_path / "bad.onnx"), change))
    assert words in msg and "bad.onnx" in msg, msg
    assert time.perf_counter() - t0 < 5.0


def _rewire(model, node_name, index, new_input, value=None):
    """Node ``node_name``'s input ``index`` read from ``new_input`` (a new initializer holding
    ``value`` when given)."""
    from onnx import numpy_helper

    if value is not None:
        model.graph.initializer.append(numpy_helper.from_array(value, new_input))
    node = next(n for n in model.graph.node if n.name == node_name)
    node.input[index] = new_input


def _initializer(model, name):
    return onnx.numpy_helper.to_array(next(i for i in model.graph.initializer
                                           if i.name == name))


def test_graph_must_compute_the_policy_of_its_own_weights(tmp_path, envs):
    """A graph not tied to its checked weights loaded: one computing with other weights than
    those it carries (and that were checked), one ignoring the observation, one serving a
    constant action. Now the graph's answers on the fixed probe inputs must equal the NumPy
    policy of its own weights to 1e-5; a graph with an extra node that changes nothing loads
    (positive control), one whose weights differ by 1e-3 does not; ~0.5 s."""
    from onnx import helper

    path, _ = _export(tmp_path, envs, "reach", "daddpg")
    model = onnx.load(path)
    w0 = _initializer(model, "actor/W0")
    zero = np.float32(0.0)

    def same_function(m):   # + 0 after the first layer: another graph, the same policy
        _rewire(m, "pre0", 0, "mm0_plus0")
        after = [n.name for n in m.graph.node].index("mm0") + 1
        m.graph.node.insert(after, helper.make_node("Add", ["mm0", "zero"], ["mm0_plus0"],
                                                    name="plus0"))
        m.graph.initializer.append(onnx.numpy_helper.from_array(np.zeros(1, np.float32),
                                                                "zero"))
    def constant(m):   # the last layer's input replaced by (x - x) + 0.3: ignores everything
        _rewire(m, "act2", 0, "fixed")
        after = [n.name for n in m.graph.node].index("pre2") + 1
        m.graph.node.insert(after, helper.make_node("Add", ["nothing", "c03"], ["fixed"]))
        m.graph.node.insert(after, helper.make_node("Sub", ["pre2", "pre2"], ["nothing"]))
        m.graph.initializer.append(onnx.numpy_helper.from_array(np.float32(0.3), "c03"))

    ok = _mutated(path, str(tmp_path / "ok.onnx"), same_function)
    o, g = random_inputs(50, 2, 25, 3)
    np.testing.assert_allclose(OnnxPolicy.load(ok).act(o, g), OnnxPolicy.load(path).act(o, g),
                               atol=1e-6)
    cases = {
        "other weights": lambda m: _rewire(m, "mm0", 1, "W0_other", np.zeros_like(w0)),
        "slightly other": lambda m: _rewire(m, "mm0", 1, "W0_near", w0 + np.float32(1e-3)),
        "no observation": lambda m: (_rewire(m, "observation/clipped", 1, "lo0", zero),
                                     _rewire(m, "observation/clipped", 2, "hi0", zero)),
        "constant": constant,
    }
    for what, change in cases.items():
        msg = _one_line_refusal(_mutated(path, str(tmp_path / "bad.onnx"), change))
        assert "does not compute the policy of its own weights" in msg, (what, msg)
        assert "probe inputs" in msg and "bad.onnx" in msg, (what, msg)


def test_graph_values_have_static_bounded_shapes(tmp_path, envs):
    """Allowed operators can still build large values: a chain of Concats doubling a value
    (2^21 x its size at batch 1) and a broadcast of a column by a row (batch^2 elements) are
    refused from shape inference, before onnxruntime runs anything; ~0.2 s."""
    from onnx import helper, numpy_helper

    path, _ = _export(tmp_path, envs, "reach", "daddpg")

    def doubling(m):
        prev = "actor_in"
        for i in range(21):
            m.graph.node.append(helper.make_node("Concat", [prev, prev], [f"c{i}"], axis=-1))
            prev = f"c{i}"

    def square(m):
        m.graph.initializer.extend([numpy_helper.from_array(np.array([-1, 1]), "col"),
                                    numpy_helper.from_array(np.array([1, -1]), "row")])
        m.graph.node.extend([helper.make_node("Reshape", ["observation", "col"], ["o_col"]),
                             helper.make_node("Reshape", ["observation", "row"], ["o_row"]),
                             helper.make_node("Add", ["o_col", "o_row"], ["o_square"])])

    msg = _one_line_refusal(_mutated(path, str(tmp_path / "bad.onnx"), doubling))
    assert "elements, more than" in msg, msg
    msg = _one_line_refusal(_mutated(path, str(tmp_path / "bad.onnx"), square))
    assert "'o_square' grows faster than the batch" in msg, msg


def test_each_call_is_stopped_at_its_compute_cap(tmp_path, envs, monkeypatch):
    """A slow but allowed run (8 layers of 128 on 40000 rows, ~0.4 s) completes under a cap of
    10 s (positive control) and is stopped under a cap of 10 ms: ComputeTimeout, in under half
    the time of the whole run (onnxruntime's terminate flag, checked between nodes). A load
    whose probe run passes its cap (here: 20000 probe rows, 10 ms) is refused. ~1.5 s."""
    from daddpg_jax.deploy.onnx_policy import ComputeTimeout

    env = envs["reach"]
    cfg = TrainConfig(task="reach", algo="daddpg", hidden=(128,) * 8)
    arrays = policy_arrays(random_state(cfg, env, 4), cfg, env, {"checkpoint_step": 3})
    path = write_export(arrays, str(tmp_path / "deep.onnx"))
    o, g = random_inputs(40_000, 3, 25, 3)
    pol = OnnxPolicy.load(path, max_run_s=10.0)
    t0 = time.perf_counter()
    a = pol.act(o, g)
    full = time.perf_counter() - t0
    ref = NumpyPolicy.load(write_export(arrays, str(tmp_path / "d.npz")))
    np.testing.assert_allclose(a[:500], ref.act(o[:500], g[:500]), atol=1e-5)
    pol.max_run_s = 0.01
    t0 = time.perf_counter()
    with pytest.raises(ComputeTimeout, match="compute cap of 0.01 s"):
        pol.act(o, g)
    cut = time.perf_counter() - t0
    assert cut < 0.5 * full, (cut, full)
    pol.max_run_s = 10.0
    assert np.array_equal(pol.act(o[:5], g[:5]), a[:5])   # the session still runs
    with pytest.raises(ValueError, match="max_run_s"):
        OnnxPolicy.load(path, max_run_s=0)
    monkeypatch.setattr("daddpg_jax.deploy.onnx_policy.PROBE_ROWS", 20_000)
    msg = _one_line_refusal_of(lambda: OnnxPolicy.load(path, max_run_s=0.01))
    assert "on the probe inputs, the ONNX graph ran past its compute cap" in msg, msg
