"""The exported policy as one ONNX graph: normalizers, the actors and the output squashing.

    daddpg-export RUN --format onnx --out policy.onnx
    from daddpg_jax.deploy.onnx_policy import OnnxPolicy, load_policy
    policy = OnnxPolicy.load("policy.onnx")        # onnxruntime; NumpyPolicy's interface:
    action = policy.act(observation, desired_goal)  # [..., 2, 25], [..., 2, 3] -> [..., 8]
    policy = load_policy("policy.onnx")            # either format, by the file's extension

The graph (opset ``OPSET``) repeats ``NumpyPolicy.act`` step for step in float32:

    inputs   observation  float32 [batch, 2, obs_size]
             desired_goal float32 [batch, 2, goal_size]
    o = clip((clip(observation, ±clip_obs) - obs_mean) / obs_std, ±norm_clip)   (goal likewise)
    actor inputs as the variant's row says (daddpg_jax.variants): 'both' = every agent
    sees [o_1, o_2, g_1, g_2] flattened; 'own' = agent i sees [o_i, g_i]
    agent i: tanh(W_L relu(... relu(W_0 x + b_0) ...) + b_L)
    output   actions      float32 [batch, 8] (the agents' action slots in agent order)

Its initializers are the ``.npz`` export's arrays under the same names (``actor/W0``,
``obs_norm/mean``, ...; ``daddpg_jax/running/export.py``; not the normalizers' sample counts,
which acting does not use), and its metadata property ``meta`` holds the same JSON text.

Loading an ``.onnx`` file (``OnnxPolicy.load``) refuses, with one line (PolicyFormatError):
a file over ``MAX_FILE_BYTES``; data outside the file (external tensors are never read); any
operator outside ``ALLOWED_OPS`` (the ones ``build_model`` writes: no ``Loop``, ``Scan``,
``If``), an operator or opset of a domain other than the default one, local functions,
subgraph or tensor attributes, more than ``MAX_NODES`` nodes; arrays that the ``.npz`` reader
refuses (the arrays are handed to ``NumpyPolicy.load``: the same validation); inputs and output
not named and shaped as written here; a value whose shape is not static at batch 1, or larger
than ``MAX_VALUE_ELEMENTS`` (``MAX_GRAPH_ELEMENTS`` all together), or growing faster than the
batch; and a graph whose answers on ``PROBE_ROWS`` fixed probe inputs (`probe_inputs`: zeros,
the normalizer means, values far beyond the clips and random ones) differ by more than
``PROBE_ATOL`` from the NumPy policy of its own checked weights. ``act`` runs in onnxruntime
on one thread, each call stopped (``ComputeTimeout``) when it runs past ``max_run_s``
(onnxruntime's ``RunOptions.terminate``, set by a watchdog thread and checked between nodes;
the static bounds above keep each node short).

``onnx`` and ``onnxruntime`` are the optional extra ``[onnx]``; they are imported only here,
on use, so the NumPy path keeps working without them.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
import threading
import time
from typing import Any

import numpy as np

from daddpg_jax import variants
from daddpg_jax.deploy.policy import (
    MAX_INFLATED_BYTES,
    MAX_META_BYTES,
    NumpyPolicy,
    PolicyFormatError,
    _check_input,
    file_sha256,
    write_policy_file,
)

OPSET = 17
INPUTS = ("observation", "desired_goal")
OUTPUT = "actions"
_EXTRA = "pip install 'daddpg-jax[onnx]'"

ALLOWED_OPS = frozenset({"Add", "Clip", "Concat", "Div", "MatMul", "Relu", "Reshape", "Sub",
                         "Tanh", "Transpose", "Unsqueeze"})
"""The operators a policy graph may use: those ``build_model`` writes (default domain)."""
MAX_FILE_BYTES = MAX_INFLATED_BYTES + MAX_META_BYTES + 1024 * 1024
"""Largest ``.onnx`` file read (bytes): the arrays, ``meta`` and room for the graph."""
MAX_NODES = 1024
"""Most nodes a policy graph may hold (``build_model`` writes 4 per layer and ~15 more)."""
MAX_VALUE_ELEMENTS = 1 << 20
"""Most elements of one value the graph computes, at batch 1."""
MAX_GRAPH_ELEMENTS = 1 << 24
"""Most elements of all the values the graph computes together, at batch 1."""
PROBE_ROWS = 16
PROBE_SEED = 20_515
PROBE_ATOL = 1e-5
"""The graph must answer `probe_inputs` as the NumPy policy does, to this (max abs diff)."""
MAX_RUN_S = 0.5
"""Default cap on one ``act`` call's compute in onnxruntime, seconds."""
_ATTRIBUTE_TYPES = frozenset({1, 2, 6, 7})  # AttributeProto FLOAT, INT, FLOATS, INTS


class ComputeTimeout(RuntimeError):
    """A graph run was stopped because it ran past its compute-time cap."""


def _onnx():
    try:
        import onnx  # optional extra [onnx]
    except ImportError:
        raise PolicyFormatError(f"ONNX policies need the onnx package: {_EXTRA}") from None
    return onnx


def build_model(arrays: dict[str, Any]):
    """The ONNX model (``onnx.ModelProto``) of an export's arrays (`policy_arrays`: actor
    weights, normalizer statistics, ``meta``)."""
    onnx = _onnx()
    from onnx import TensorProto, helper, numpy_helper  # optional extra [onnx]

    meta = json.loads(str(arrays["meta"]))
    variant = variants.get(meta["algo"])
    n_arms, obs, goal = int(meta["num_arms"]), int(meta["obs_size"]), int(meta["goal_size"])
    n_layers = len(meta["layer_sizes"])
    norm = meta["normalizer"]
    inits, nodes = [], []

    def const(name, value):
        inits.append(numpy_helper.from_array(np.asarray(value), name))
        return name

    def node(op, ins, out, **kw):
        nodes.append(helper.make_node(op, ins, [out], name=out, **kw))
        return out

    for k in ("obs_norm/mean", "obs_norm/std", "goal_norm/mean", "goal_norm/std"):
        const(k, np.asarray(arrays[k], np.float32))
    const("clip_obs_lo", np.float32(-norm["clip_obs"]))
    const("clip_obs_hi", np.float32(norm["clip_obs"]))
    const("norm_clip_lo", np.float32(-norm["norm_clip"]))
    const("norm_clip_hi", np.float32(norm["norm_clip"]))
    normed = {}
    for x, key in (("observation", "obs_norm"), ("desired_goal", "goal_norm")):
        c = node("Clip", [x, "clip_obs_lo", "clip_obs_hi"], f"{x}/clipped")
        z = node("Div", [node("Sub", [c, f"{key}/mean"], f"{x}/centred"), f"{key}/std"],
                 f"{x}/scaled")
        normed[x] = node("Clip", [z, "norm_clip_lo", "norm_clip_hi"], f"{x}/normalized")
    o, g = normed["observation"], normed["desired_goal"]
    # x [A or 1, batch, in]: the actors' inputs with the agent axis first (NumpyPolicy's)
    if variant.actor_sees == variants.BOTH:
        flat = const("shape_flat", np.array([0, -1], np.int64))
        both = node("Concat", [node("Reshape", [o, flat], "o_flat"),
                               node("Reshape", [g, flat], "g_flat")], "actor_in", axis=-1)
        x = node("Unsqueeze", [both, const("axis_0", np.array([0], np.int64))], "x0")
    else:
        x = node("Transpose", [node("Concat", [o, g], "og", axis=-1)], "x0", perm=[1, 0, 2])
    axis_1 = const("axis_1", np.array([1], np.int64))
    for layer in range(n_layers):
        w = const(f"actor/W{layer}", np.asarray(arrays[f"actor/W{layer}"], np.float32))
        b = const(f"actor/b{layer}", np.asarray(arrays[f"actor/b{layer}"], np.float32))
        b = node("Unsqueeze", [b, axis_1], f"b{layer}_agents")       # [A, 1, out]
        x = node("Add", [node("MatMul", [x, w], f"mm{layer}"), b], f"pre{layer}")
        x = node("Relu" if layer < n_layers - 1 else "Tanh", [x], f"act{layer}")
    # [A, batch, d] -> [batch, A * d]: the agents' action slots in agent order
    x = node("Transpose", [x], "per_agent", perm=[1, 0, 2])
    node("Reshape", [x, const("shape_actions", np.array([0, -1], np.int64))], OUTPUT)
    graph = helper.make_graph(
        nodes, "daddpg_policy",
        [helper.make_tensor_value_info("observation", TensorProto.FLOAT, ["batch", n_arms, obs]),
         helper.make_tensor_value_info("desired_goal", TensorProto.FLOAT,
                                       ["batch", n_arms, goal])],
        [helper.make_tensor_value_info(OUTPUT, TensorProto.FLOAT,
                                       ["batch", int(meta["action_size"])])],
        initializer=inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)],
                              producer_name="daddpg-jax")
    model.ir_version = min(model.ir_version, 9)   # readable by older onnxruntime releases
    helper.set_model_props(model, {"meta": str(arrays["meta"])})
    onnx.checker.check_model(model)
    return model


def write_onnx(arrays: dict[str, Any], out) -> str:
    """Writes the export as ONNX, atomically (a new temporary file of an unpredictable name,
    then a rename). Returns the path."""
    out = os.fspath(out)
    if not out.endswith(".onnx"):
        raise ValueError(f"output file must end in .onnx, got {out!r}")
    data = build_model(arrays).SerializeToString()
    return write_policy_file(out, lambda f: f.write(data))


def _arrays_of(model) -> dict[str, Any]:
    """The export's arrays (the initializers named as in the .npz) and ``meta`` of a model."""
    from onnx import numpy_helper  # optional extra [onnx]

    props = {p.key: p.value for p in model.metadata_props}
    out: dict[str, Any] = {i.name: numpy_helper.to_array(i) for i in model.graph.initializer
                           if "/" in i.name}
    if "meta" in props:
        out["meta"] = np.array(props["meta"])
    return out


class OnnxPolicy:
    """An ``.onnx`` export run by onnxruntime; everything but ``act`` (metadata, ``info()``,
    ``env``, sizes) is the validated ``NumpyPolicy`` of the same arrays (``self.reference``)."""

    def __init__(self, reference: NumpyPolicy, session, path: str,
                 max_run_s: float = MAX_RUN_S):
        self.reference = reference
        self.session = session
        self.path = path
        self.max_run_s = float(max_run_s)

    def __getattr__(self, name):
        return getattr(self.reference, name)

    @classmethod
    def load(cls, path, max_run_s: float = MAX_RUN_S) -> OnnxPolicy:
        """The policy in the ``.onnx`` file at ``path``, checked as the module's docstring
        says; FileNotFoundError when it does not exist, PolicyFormatError (one line) for
        anything else. ``max_run_s``: the cap on each ``act`` call's compute (and on the probe
        run here), seconds."""
        onnx = _onnx()
        try:
            import onnxruntime as ort  # optional extra
        except ImportError:
            raise PolicyFormatError(f"ONNX policies need onnxruntime: {_EXTRA}") from None
        path = os.fspath(path)
        if not os.path.exists(path):
            raise FileNotFoundError(f"policy file {path!r} not found")
        max_run_s = float(max_run_s)
        if not 0 < max_run_s <= 60:
            raise ValueError(f"max_run_s must be in (0, 60] s, got {max_run_s!r}")
        size = os.path.getsize(path)
        if size > MAX_FILE_BYTES:
            raise PolicyFormatError(f"{path!r}: file of {size} bytes exceeds the limit of "
                                    f"{MAX_FILE_BYTES}")
        try:
            model = onnx.load(path, load_external_data=False)   # never a file the model names
        except Exception as e:  # noqa: BLE001 (protobuf decode errors of any kind)
            text = " ".join(str(e).split())[:200]
            raise PolicyFormatError(f"{path!r} is not a readable ONNX file: {text}") from None
        if not model.graph.node:
            raise PolicyFormatError(f"{path!r} is not a readable ONNX file: it holds no graph")
        _check_graph(model, path)
        try:
            arrays = _arrays_of(model)
        except Exception as e:  # noqa: BLE001 (malformed tensors: onnx's and NumPy's errors)
            text = " ".join(str(e).split())[:200]
            raise PolicyFormatError(f"{path!r}: unreadable initializer: {text}") from None
        reference = _validated(arrays, path)
        _check_signature(model, reference, path)
        _check_shapes(model, path)
        try:
            opts = ort.SessionOptions()
            opts.log_severity_level = 3   # errors only: no notes on stderr at each load
            opts.intra_op_num_threads = 1   # one request uses one core
            opts.inter_op_num_threads = 1
            opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
            session = ort.InferenceSession(model.SerializeToString(), opts,
                                           providers=["CPUExecutionProvider"])
        except Exception as e:  # noqa: BLE001 (onnxruntime's load errors)
            text = " ".join(str(e).split())[:200]
            raise PolicyFormatError(f"{path!r}: onnxruntime cannot run the graph: {text}") \
                from None
        policy = cls(reference, session, path, max_run_s)
        policy._check_probes()
        reference.sha256 = file_sha256(path)   # /info names the file served: the .onnx
        return policy

    def _run(self, o: np.ndarray, g: np.ndarray) -> np.ndarray:
        """The graph on float32 [B, 2, obs], [B, 2, goal]; ComputeTimeout past ``max_run_s``."""
        import onnxruntime as ort  # optional extra: present once a session exists

        opts = ort.RunOptions()
        key = _WATCHDOG.watch(opts, self.max_run_s)
        try:
            (a,) = self.session.run([OUTPUT], {"observation": o, "desired_goal": g}, opts)
        except Exception:
            if opts.terminate:
                raise ComputeTimeout(f"the ONNX graph ran past its compute cap of "
                                     f"{self.max_run_s:g} s and was stopped") from None
            raise
        finally:
            _WATCHDOG.done(key)
        return np.asarray(a, np.float32)

    def _check_probes(self) -> None:
        """Refuses a graph that does not compute the NumPy policy of its own checked weights:
        both run on `probe_inputs`, max abs difference at most PROBE_ATOL."""
        r = self.reference
        o, g = probe_inputs(r)
        want = r.act(o, g)
        try:
            got = self._run(o, g)
        except ComputeTimeout as e:
            raise PolicyFormatError(f"{self.path!r}: on the probe inputs, {e}") from None
        except Exception as e:  # noqa: BLE001 (onnxruntime's run errors)
            text = " ".join(str(e).split())[:200]
            raise PolicyFormatError(f"{self.path!r}: the graph fails on the probe inputs: "
                                    f"{text}") from None
        if got.shape != want.shape or not np.all(np.isfinite(got)):
            raise PolicyFormatError(f"{self.path!r}: the graph answers the probe inputs with "
                                    f"shape {list(got.shape)} or non-finite values, expected "
                                    f"{list(want.shape)} finite")
        diff = float(np.max(np.abs(got - want)))
        if not diff <= PROBE_ATOL:
            raise PolicyFormatError(f"{self.path!r}: the graph does not compute the policy of "
                                    f"its own weights: max difference {diff:.3g} on the probe "
                                    f"inputs (allowed {PROBE_ATOL:g})")

    def act(self, observation, desired_goal) -> np.ndarray:
        """Joint action [..., 8] in [-1, 1], as ``NumpyPolicy.act`` (same input checks);
        ComputeTimeout when the graph runs past ``max_run_s``."""
        r = self.reference
        o = _check_input("observation", observation, (r.num_arms, r.obs_size))
        g = _check_input("desired_goal", desired_goal, (r.num_arms, r.goal_size))
        lead = o.shape[:-2]
        if lead != g.shape[:-2]:
            raise ValueError(f"observation and desired_goal have different leading axes: "
                             f"{list(lead)} vs {list(g.shape[:-2])}")
        a = self._run(o.reshape((-1,) + o.shape[-2:]), g.reshape((-1,) + g.shape[-2:]))
        return a.reshape(lead + (r.action_size,))

    def act_per_arm(self, observation, desired_goal) -> np.ndarray:
        a = self.act(observation, desired_goal)
        return a.reshape(a.shape[:-1] + (self.reference.num_arms, self.reference.arm_action))

    __call__ = act


def _validated(arrays: dict[str, Any], path: str) -> NumpyPolicy:
    """The NumpyPolicy of an ONNX file's arrays, read by ``NumpyPolicy.load`` itself (written to
    a private temporary .npz): the same checks as an .npz export, errors naming `path`."""
    d = tempfile.mkdtemp(prefix="daddpg-onnx-")
    tmp = os.path.join(d, "policy.npz")
    try:
        np.savez(tmp, **arrays)
        try:
            return NumpyPolicy.load(tmp)
        except PolicyFormatError as e:
            msg = str(e).replace(repr(tmp), repr(path)).replace(tmp, path)
            raise PolicyFormatError(msg if path in msg else f"{path!r}: {msg}") from None
        except (KeyError, TypeError, ValueError) as e:
            raise PolicyFormatError(f"{path!r}: not a policy export ({e})") from None
    finally:
        shutil.rmtree(d, ignore_errors=True)


def _check_signature(model, ref: NumpyPolicy, path: str) -> None:
    """The graph's inputs and output are named and shaped as this module writes them."""
    def dims(v):
        return [d.dim_value if d.HasField("dim_value") else d.dim_param
                for d in v.type.tensor_type.shape.dim]

    want_in = {"observation": [ref.num_arms, ref.obs_size],
               "desired_goal": [ref.num_arms, ref.goal_size]}
    got_in = {v.name: dims(v) for v in model.graph.input}
    if set(got_in) != set(want_in) or any(got_in[k][1:] != want_in[k] for k in want_in):
        raise PolicyFormatError(f"{path!r}: graph inputs {got_in}, expected observation "
                                f"[batch, {ref.num_arms}, {ref.obs_size}] and desired_goal "
                                f"[batch, {ref.num_arms}, {ref.goal_size}]")
    outs = {v.name: dims(v) for v in model.graph.output}
    if outs.keys() != {OUTPUT} or outs[OUTPUT][1:] != [ref.action_size]:
        raise PolicyFormatError(f"{path!r}: graph outputs {outs}, expected {OUTPUT} "
                                f"[batch, {ref.action_size}]")


def probe_inputs(ref: NumpyPolicy) -> tuple[np.ndarray, np.ndarray]:
    """The fixed probe inputs a graph is checked on (``PROBE_ROWS`` rows, float32, the same for
    every load of the same policy): zeros, the normalizer means (normalized to 0), values far
    beyond ``clip_obs`` of either sign, and random ones from ``PROBE_SEED`` at scales from
    0.01 to beyond ``clip_obs``."""
    rng = np.random.default_rng(PROBE_SEED)
    shape_o, shape_g = (PROBE_ROWS, ref.num_arms, ref.obs_size), (PROBE_ROWS, ref.num_arms,
                                                                  ref.goal_size)
    big = 3.0 * float(ref.clip_obs)
    scale = np.geomspace(0.01, big, PROBE_ROWS - 4)[:, None, None]
    o = np.concatenate([np.zeros((1,) + shape_o[1:]), ref.obs_mean[None],
                        np.full((1,) + shape_o[1:], big), np.full((1,) + shape_o[1:], -big),
                        rng.normal(0.0, 1.0, (PROBE_ROWS - 4,) + shape_o[1:]) * scale])
    g = np.concatenate([np.zeros((1,) + shape_g[1:]), ref.goal_mean[None],
                        np.full((1,) + shape_g[1:], -big), np.full((1,) + shape_g[1:], big),
                        rng.normal(0.0, 1.0, (PROBE_ROWS - 4,) + shape_g[1:]) * scale])
    return o.astype(np.float32), g.astype(np.float32)


def _check_graph(model, path: str) -> None:
    """Refuses anything but a flat graph of ``ALLOWED_OPS`` of the default domain, with numeric
    attributes only and every tensor inside the file."""
    from onnx import TensorProto  # optional extra [onnx]

    def fail(msg):
        raise PolicyFormatError(f"{path!r}: {msg}")

    default = ("", "ai.onnx")
    for op in model.opset_import:
        if op.domain not in default:
            fail(f"opset of domain {op.domain[:40]!r}; a policy graph uses the default one")
    if model.functions:
        fail("the model defines functions; a policy graph holds none")
    if model.training_info:
        fail("the model holds training graphs; a policy graph holds none")
    g = model.graph
    if len(g.node) > MAX_NODES:
        fail(f"{len(g.node)} nodes, more than {MAX_NODES}")
    if g.sparse_initializer:
        fail("sparse initializers; a policy graph holds none")
    names = [t.name for t in g.initializer]
    if len(set(names)) != len(names):
        fail("two initializers of the same name")
    if any(t.data_location == TensorProto.EXTERNAL or t.external_data for t in g.initializer):
        fail("tensor data outside the file; a policy file holds all of its data")
    for node in g.node:
        name = node.name[:40] or node.op_type[:40]
        if node.domain not in default:
            fail(f"node {name!r} is of domain {node.domain[:40]!r}; a policy graph uses the "
                 f"default one")
        if node.op_type not in ALLOWED_OPS:
            fail(f"operator {node.op_type[:40]!r} (node {name!r}) is not allowed; a policy "
                 f"graph uses only {', '.join(sorted(ALLOWED_OPS))}")
        for a in node.attribute:
            if (a.type not in _ATTRIBUTE_TYPES or a.ref_attr_name or a.graphs or a.tensors
                    or a.sparse_tensors or a.type_protos or a.strings
                    or any(a.HasField(f) for f in ("g", "t", "sparse_tensor", "tp", "s"))):
                fail(f"node {name!r} has attribute {a.name[:40]!r} of a kind a policy graph "
                     f"does not use (subgraphs and tensors are refused)")


def _check_shapes(model, path: str) -> None:
    """Every value the graph computes has a static shape at batch 1 (shape inference, strict),
    at most MAX_VALUE_ELEMENTS elements (MAX_GRAPH_ELEMENTS in all), and at batch 2 at most
    twice its size at batch 1 (no value grows faster than the batch)."""
    from onnx import shape_inference  # optional extra [onnx]

    sizes = []
    for batch in (1, 2):
        m = type(model)()
        m.CopyFrom(model)
        for v in list(m.graph.input) + list(m.graph.output):   # named and shaped as written
            v.type.tensor_type.shape.dim[0].dim_value = batch
        try:
            m = shape_inference.infer_shapes(m, check_type=True, strict_mode=True)
        except Exception as e:  # noqa: BLE001 (onnx's inference errors)
            text = " ".join(str(e).split())[:200]
            raise PolicyFormatError(f"{path!r}: shape inference fails on the graph: "
                                    f"{text}") from None
        known = {v.name: v for v in list(m.graph.value_info) + list(m.graph.output)}
        size = {}
        for node in m.graph.node:
            for out in node.output:
                tt = known[out].type.tensor_type if out in known else None
                if (tt is None or not tt.HasField("shape")
                        or any(not d.HasField("dim_value") for d in tt.shape.dim)):
                    raise PolicyFormatError(f"{path!r}: value {out[:40]!r} has no static "
                                            f"shape")
                n = int(np.prod([max(d.dim_value, 0) for d in tt.shape.dim], dtype=np.float64))
                if batch == 1 and n > MAX_VALUE_ELEMENTS:
                    raise PolicyFormatError(f"{path!r}: value {out[:40]!r} has {n} elements, "
                                            f"more than {MAX_VALUE_ELEMENTS}")
                size[out] = n
        sizes.append(size)
    total = sum(sizes[0].values())
    if total > MAX_GRAPH_ELEMENTS:
        raise PolicyFormatError(f"{path!r}: the graph's values hold {total} elements, more "
                                f"than {MAX_GRAPH_ELEMENTS}")
    for k, n in sizes[1].items():
        if n > 2 * sizes[0].get(k, 0):
            raise PolicyFormatError(f"{path!r}: value {k[:40]!r} grows faster than the batch")


class _Watchdog:
    """One daemon thread that sets ``terminate`` on the RunOptions of each onnxruntime run still
    going at its deadline (onnxruntime checks the flag between nodes). It polls every ``TICK``
    seconds while runs are going and sleeps while none is."""

    TICK = 0.01

    def __init__(self):
        self._cond = threading.Condition()
        self._runs: dict[int, tuple[float, Any]] = {}
        self._next = 0
        self._thread: threading.Thread | None = None

    def watch(self, opts, seconds: float) -> int:
        with self._cond:
            if self._thread is None or not self._thread.is_alive():
                self._thread = threading.Thread(target=self._loop, name="onnx-watchdog",
                                                daemon=True)
                self._thread.start()
            key, self._next = self._next, self._next + 1
            was_idle = not self._runs
            self._runs[key] = (time.monotonic() + seconds, opts)
            if was_idle:
                self._cond.notify()
        return key

    def done(self, key: int) -> None:
        with self._cond:
            self._runs.pop(key, None)

    def _loop(self):
        with self._cond:
            while True:
                if not self._runs:
                    self._cond.wait()
                    continue
                now = time.monotonic()
                for key, (deadline, opts) in list(self._runs.items()):
                    if deadline <= now:
                        opts.terminate = True
                        del self._runs[key]
                self._cond.wait(self.TICK)


_WATCHDOG = _Watchdog()


def load_policy(path):
    """A policy file of either format: ``.onnx`` -> OnnxPolicy (onnxruntime), else the
    ``.npz`` reader, NumpyPolicy."""
    if os.fspath(path).lower().endswith(".onnx"):
        return OnnxPolicy.load(path)
    return NumpyPolicy.load(path)
