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
    actor inputs as the variant's row says (daddpg_jax.algo.variants): 'both' = every agent
    sees [o_1, o_2, g_1, g_2] flattened; 'own' = agent i sees [o_i, g_i]
    agent i: tanh(W_L relu(... relu(W_0 x + b_0) ...) + b_L)
    output   actions      float32 [batch, 8] (the agents' action slots in agent order)

Its initializers are the ``.npz`` export's arrays under the same names (``actor/W0``,
``obs_norm/mean``, ...; ``daddpg_jax/running/export.py``; not the normalizers' sample counts,
which acting does not use), and its metadata property ``meta`` holds the same JSON text.
Loading an ``.onnx`` file reads those arrays back and hands them to the ``.npz`` reader
(``NumpyPolicy.load``), so it passes the same validation; then the graph's inputs and outputs
are checked, and ``act`` runs in onnxruntime.

``onnx`` and ``onnxruntime`` are the optional extra ``[onnx]``; they are imported only here,
on use, so the NumPy path keeps working without them.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from typing import Any

import numpy as np

from daddpg_jax.algo import variants
from daddpg_jax.deploy.policy import (
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

    def __init__(self, reference: NumpyPolicy, session, path: str):
        self.reference = reference
        self.session = session
        self.path = path

    def __getattr__(self, name):
        return getattr(self.reference, name)

    @classmethod
    def load(cls, path) -> OnnxPolicy:
        onnx = _onnx()
        try:
            import onnxruntime as ort  # optional extra
        except ImportError:
            raise PolicyFormatError(f"ONNX policies need onnxruntime: {_EXTRA}") from None
        path = os.fspath(path)
        if not os.path.exists(path):
            raise FileNotFoundError(f"policy file {path!r} not found")
        try:
            model = onnx.load(path)
        except Exception as e:  # noqa: BLE001 (protobuf decode errors of any kind)
            raise PolicyFormatError(f"{path!r} is not a readable ONNX file: {e}") from None
        if not model.graph.node:
            raise PolicyFormatError(f"{path!r} is not a readable ONNX file: it holds no graph")
        reference = _validated(_arrays_of(model), path)
        _check_signature(model, reference, path)
        try:
            opts = ort.SessionOptions()
            opts.log_severity_level = 3   # errors only: no notes on stderr at each load
            session = ort.InferenceSession(model.SerializeToString(), opts,
                                           providers=["CPUExecutionProvider"])
        except Exception as e:  # noqa: BLE001 (onnxruntime's load errors)
            raise PolicyFormatError(f"{path!r}: onnxruntime cannot run the graph: {e}") from None
        reference.sha256 = file_sha256(path)   # /info names the file served: the .onnx
        return cls(reference, session, path)

    def act(self, observation, desired_goal) -> np.ndarray:
        """Joint action [..., 8] in [-1, 1], as ``NumpyPolicy.act`` (same input checks)."""
        r = self.reference
        o = _check_input("observation", observation, (r.num_arms, r.obs_size))
        g = _check_input("desired_goal", desired_goal, (r.num_arms, r.goal_size))
        lead = o.shape[:-2]
        if lead != g.shape[:-2]:
            raise ValueError(f"observation and desired_goal have different leading axes: "
                             f"{list(lead)} vs {list(g.shape[:-2])}")
        feeds = {"observation": o.reshape((-1,) + o.shape[-2:]),
                 "desired_goal": g.reshape((-1,) + g.shape[-2:])}
        (a,) = self.session.run([OUTPUT], feeds)
        return np.asarray(a, np.float32).reshape(lead + (r.action_size,))

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


def load_policy(path):
    """A policy file of either format: ``.onnx`` -> OnnxPolicy (onnxruntime), else the
    ``.npz`` reader, NumpyPolicy."""
    if os.fspath(path).lower().endswith(".onnx"):
        return OnnxPolicy.load(path)
    return NumpyPolicy.load(path)
