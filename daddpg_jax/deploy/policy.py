"""The exported policy in plain NumPy (no JAX, Flax or MuJoCo): what a robot computer runs.

    from daddpg_jax.deploy import NumpyPolicy
    policy = NumpyPolicy.load("policy.npz")
    action = policy.act(observation, desired_goal)        # [2, 25], [2, 3] -> [8] float32
    per_arm = policy.act_per_arm(observation, desired_goal)  # -> [2, 4] (row 0 = left arm)

Both accept extra leading (batch) axes: [..., 2, obs], [..., 2, 3] -> [..., 8] / [..., 2, 4].
The computation repeats the trainer's ``TrainFns.act`` step for step in float32 (clip, normalize,
build each variant's actor inputs, MLP, tanh), and matches it to 1e-5 on CPU.

What depends on the algorithm variant (number of agents, what each actor sees, the size of
each agent's action slot) is read from the variant's row in ``daddpg_jax.variants``; the
task's settings from ``mjx_envs.settings``. Both are standard library only, so this module
imports NumPy and the standard library only: keep it that way (tests/test_deploy.py checks it
in a subprocess where importing jax or mujoco fails).
"""

from __future__ import annotations

import hashlib
import io
import json
import math
import os
import tempfile
import zipfile
from collections.abc import Mapping
from typing import Any

import numpy as np

from daddpg_jax import variants
from mjx_envs import observation as obs_lib
from mjx_envs import registry, schema
from mjx_envs import settings as task_settings_lib

FORMAT_VERSION = 1
"""Version of the ``.npz`` layout, written by ``daddpg_jax.running.export`` and read here."""


MAX_FILE_BYTES = 512 * 1024 * 1024
"""Largest policy file read (bytes); a bigger one is refused before any member is read."""
MAX_META_BYTES = 1024 * 1024
"""Largest ``meta`` member (its stored ``.npy`` size, bytes)."""
MAX_MEMBERS = 256
"""Most members a policy file may hold."""
MAX_WIDTH = 8192
"""Largest layer width, observation or goal size a policy file may declare."""
MAX_LAYERS = 32
"""Most actor layers a policy file may declare."""
MAX_AGENTS = 8
"""Most agents a policy file may declare."""
NPY_HEADER_BYTES = 4096
"""Room for a member's ``.npy`` header beyond its data: a member is read only up to its
declared shape's bytes plus this."""
MAX_INFLATED_BYTES = 64 * 1024 * 1024
"""Most bytes the arrays of a policy file may take once inflated, checked twice before any array
is read: the values ``meta`` declares (at 4 bytes, as the policy holds them) and the members'
uncompressed sizes in the zip directory. The checked-in test export's arrays take 9.6 kB and
the default network (3 hidden layers of 256, 2 agents, float32) 1.2 MB."""
GOAL_SIZE = 3
"""Length of each arm's desired goal (a position, m)."""


class PolicyFormatError(ValueError):
    """The file is not a policy export this code can read (malformed, truncated, oversized,
    non-finite values, or ``meta`` outside its schema); the message is one line."""


def _fail(msg: str):
    raise PolicyFormatError(msg)


def _int(meta: Mapping, key: str, low: int = 1, high: int = MAX_WIDTH) -> int:
    v = meta.get(key)
    if isinstance(v, bool) or not isinstance(v, int) or not low <= v <= high:
        _fail(f"meta {key!r} must be an integer in [{low}, {high}], got {v!r}")
    return v


def _finite(where: str, v, positive: bool = False, low: float | None = None) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        _fail(f"{where} must be a finite number, got {v!r}")
    if positive and not v > 0:
        _fail(f"{where} must be > 0, got {v!r}")
    if low is not None and v < low:
        _fail(f"{where} must be >= {low}, got {v!r}")
    return float(v)


def check_meta(meta) -> None:
    """Raises PolicyFormatError unless ``meta`` (a policy export's decoded ``meta``) follows the
    schema that ``daddpg_jax.running.export.policy_arrays`` writes: the types and ranges of the
    sizes, the layer list, the normalizer clips (finite, > 0), the action scaling (finite) and
    the env's control period (``dt`` finite, in (0, 1] s, equal to ``timestep * n_substeps``
    when those are saved)."""
    if not isinstance(meta, dict):
        _fail(f"meta must be a JSON object, got {type(meta).__name__}")
    version = meta.get("format_version")
    if version != FORMAT_VERSION or isinstance(version, bool):
        _fail(f"format version {version}; this code reads version {FORMAT_VERSION}")
    for key in ("task", "algo"):
        if not isinstance(meta.get(key), str) or not 0 < len(meta[key]) <= 64:
            _fail(f"meta {key!r} must be a short string, got {meta.get(key)!r}")
    for key in ("obs_size", "goal_size", "action_size", "arm_action", "actor_input_dim"):
        _int(meta, key)
    if "num_arms" in meta:
        _int(meta, "num_arms", high=MAX_AGENTS)
    if "num_agents" in meta:
        _int(meta, "num_agents", high=MAX_AGENTS)
    if "physics_version" in meta:   # absent in files written before it was recorded: 1
        _int(meta, "physics_version", high=1000)
    layers = meta.get("layer_sizes")
    if (not isinstance(layers, list) or not 0 < len(layers) <= MAX_LAYERS or any(
            not isinstance(ls, list) or len(ls) != 2
            or any(isinstance(x, bool) or not isinstance(x, int) or not 1 <= x <= MAX_WIDTH
                   for x in ls) for ls in layers)):
        _fail(f"meta 'layer_sizes' must be a list of at most {MAX_LAYERS} [in, out] pairs of "
              f"integers in [1, {MAX_WIDTH}]")
    n = meta.get("normalizer")
    if not isinstance(n, dict):
        _fail("meta 'normalizer' must be an object with clip_obs and norm_clip")
    for key in ("clip_obs", "norm_clip"):
        _finite(f"normalizer {key}", n.get(key), positive=True)
    a = meta.get("action")
    if not isinstance(a, dict):
        _fail("meta 'action' must be an object")
    for key in ("low", "high", "max_delta", "finger_stroke", "locked_opening"):
        if key in a:
            _finite(f"action {key}", a[key])
    if "max_delta" in a:
        _finite("action max_delta", a["max_delta"], positive=True)
    layout = meta.get("obs_layout")
    if not isinstance(layout, dict) or any(
            not isinstance(v, list) or len(v) != 2
            or any(isinstance(x, bool) or not isinstance(x, int) for x in v)
            or not 0 <= v[0] <= v[1] <= meta["obs_size"] for v in layout.values()):
        _fail("meta 'obs_layout' must map names to [start, stop] inside the observation")
    env = meta.get("env")
    if env is not None:
        check_env(env)


def check_env(env) -> None:
    """Raises PolicyFormatError unless a policy export's env settings hold a finite control
    period ``dt`` in (0, 1] s (equal to ``timestep * n_substeps`` when both are saved) and
    finite, positive ``max_delta`` when saved."""
    if not isinstance(env, dict):
        _fail(f"meta 'env' must be an object, got {type(env).__name__}")
    if "dt" in env:
        dt = _finite("env dt", env["dt"], positive=True)
        if dt > 1.0:
            _fail(f"env dt must be in (0, 1] s, got {dt!r}")
        if "timestep" in env and "n_substeps" in env:
            ts = _finite("env timestep", env["timestep"], positive=True)
            ns = env["n_substeps"]
            if isinstance(ns, bool) or not isinstance(ns, int) or ns < 1:
                _fail(f"env n_substeps must be a positive integer, got {ns!r}")
            if abs(ts * ns - dt) > 1e-6 * max(dt, 1e-3):
                _fail(f"env dt {dt!r} is not timestep * n_substeps = {ts * ns!r}")
    if "max_delta" in env:
        _finite("env max_delta", env["max_delta"], positive=True)


def _member(zf: zipfile.ZipFile, infos: Mapping, name: str, limit: int) -> np.ndarray:
    """Array ``name`` of the npz, read only when its stored size is at most ``limit`` bytes."""
    info = _info(infos, name, limit)
    with zf.open(info) as f:
        raw = f.read(limit + 1)
    if len(raw) > limit:
        _fail(f"array {name!r} is larger than its declared shape allows")
    return np.lib.format.read_array(io.BytesIO(raw), allow_pickle=False)


def _info(infos: Mapping, name: str, limit: int) -> zipfile.ZipInfo:
    """The zip directory's entry of array ``name``, refused when its uncompressed size (which
    bounds what reading it inflates) is over ``limit`` bytes."""
    info = infos.get(name + ".npy")
    if info is None:
        _fail(f"misses array {name!r}")
    if info.file_size > limit:
        _fail(f"array {name!r} takes {info.file_size} bytes, more than its declared shape "
              f"allows ({limit})")
    return info


def _limit(shape: tuple[int, ...]) -> int:
    """Most bytes the ``.npy`` member of a float array of ``shape`` may take."""
    return int(np.prod(shape, dtype=np.int64)) * 8 + NPY_HEADER_BYTES


def array_plan(meta: Mapping) -> list[tuple[str, tuple[int, ...]]]:
    """The arrays a policy file with this (``check_meta``-checked) ``meta`` holds, with their
    shapes, after checking what ``meta`` declares against what the code allows, from ``meta``
    alone: the algo is a known variant whose agent count, action slots and actor input size
    ``meta`` repeats (``daddpg_jax.variants``), 2 arms of 4 action entries, an observation
    of the length the observation code builds (``mjx_envs.observation.obs_size`` of the env's
    ``action_history``), a 3-d goal, a chain of actor layers from the actor input to the action
    slot, and all the values at most ``MAX_INFLATED_BYTES`` (as float32). PolicyFormatError
    (one line) otherwise."""
    algo = meta["algo"]
    if algo not in variants.VARIANTS:
        _fail(f"unknown algo {algo!r} in policy file; this code reads "
              f"{', '.join(variants.ALGOS)}")
    v = variants.get(algo)
    agents = meta.get("num_agents", v.num_agents)
    if agents != v.num_agents:
        _fail(f"{agents} agents for algo {algo} (expected {v.num_agents})")
    arms, arm_action = meta.get("num_arms", variants.NUM_ARMS), meta["arm_action"]
    if (arms, arm_action) != (variants.NUM_ARMS, variants.ARM_ACTION):
        _fail(f"{arms} arms with {arm_action} action entries each; this code drives "
              f"{variants.NUM_ARMS} arms with {variants.ARM_ACTION}")
    if meta["action_size"] != arms * arm_action:
        _fail(f"action size {meta['action_size']}, expected {arms * arm_action}")
    history = (meta.get("env") or {}).get("action_history", 0)
    if isinstance(history, bool) or not isinstance(history, int) or not 0 <= history <= 64:
        _fail(f"env action_history must be an integer in [0, 64], got {history!r}")
    obs, goal = meta["obs_size"], meta["goal_size"]
    if obs != obs_lib.obs_size(history):
        _fail(f"obs_size {obs}, but the observation has {obs_lib.obs_size(history)} values "
              f"per arm (action_history {history})")
    if goal != GOAL_SIZE:
        _fail(f"goal_size {goal}, expected {GOAL_SIZE}")
    a_in = v.input_dims(obs, goal)[0]
    if meta["actor_input_dim"] != a_in:
        _fail(f"actor input size {meta['actor_input_dim']}, expected {a_in} for algo {algo}")
    plan, prev = [], a_in
    for i, (n_in, n_out) in enumerate(meta["layer_sizes"]):
        if n_in != prev:
            _fail(f"actor layer {i} takes {n_in} inputs, the layer before gives {prev}")
        plan += [(f"actor/W{i}", (agents, n_in, n_out)), (f"actor/b{i}", (agents, n_out))]
        prev = n_out
    if prev != v.agent_action_dim:
        _fail(f"actor output size {prev}, expected {v.agent_action_dim}")
    plan += [(f"{k}_norm/{s}", (arms, meta[f"{k}_size"]))
             for k in ("obs", "goal") for s in ("mean", "std")]
    values = sum(int(np.prod(shape, dtype=np.int64)) for _, shape in plan)
    if values * 4 > MAX_INFLATED_BYTES:
        _fail(f"meta declares arrays of {values} values ({values * 4} bytes as float32), more "
              f"than the limit of {MAX_INFLATED_BYTES} bytes")
    return plan


def _float_array(zf, info: zipfile.ZipInfo, name: str, shape: tuple[int, ...]) -> np.ndarray:
    """Array ``name``: its ``.npy`` header is read and checked (a float dtype, ``shape``) before
    its data is inflated, then exactly the data that header declares."""
    with zf.open(info) as f:
        version = np.lib.format.read_magic(f)
        if version == (1, 0):
            got, fortran, dtype = np.lib.format.read_array_header_1_0(f)
        elif version == (2, 0):
            got, fortran, dtype = np.lib.format.read_array_header_2_0(f)
        else:
            _fail(f"array {name!r} has .npy format version {version}, expected 1.0 or 2.0")
        if dtype.kind != "f" or dtype.itemsize > 8:   # float16, 32 or 64, either byte order
            _fail(f"array {name!r} has dtype {dtype}, expected floats")
        if tuple(got) != shape:
            _fail(f"array {name!r} has shape {list(got)}, expected {list(shape)}")
        n = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
        raw = f.read(n + 1)
    if len(raw) != n:
        _fail(f"array {name!r} holds {len(raw)}{'+' if len(raw) > n else ''} bytes of data, "
              f"its header declares {n}")
    arr = np.frombuffer(bytearray(raw), dtype).reshape(shape, order="F" if fortran else "C")
    if not np.all(np.isfinite(arr)):
        _fail(f"array {name!r} contains NaN or infinite values")
    return arr


def write_policy_file(out: str, write) -> str:
    """Writes a policy file atomically: ``write(f)`` fills a new temporary file of an
    unpredictable name beside ``out`` (O_EXCL: nothing planted there is written through), which
    is then renamed to ``out``. Returns ``out``."""
    d = os.path.dirname(os.path.abspath(out))
    os.makedirs(d, exist_ok=True)
    suffix = os.path.splitext(out)[1]
    fd, tmp = tempfile.mkstemp(prefix=f".tmp-{os.path.basename(out)}-", suffix=suffix, dir=d)
    try:
        with os.fdopen(fd, "wb") as f:
            write(f)
        os.chmod(tmp, 0o644)
        os.replace(tmp, out)
    finally:
        if os.path.lexists(tmp):
            os.remove(tmp)
    return out


def file_sha256(path) -> str:
    """SHA-256 of a file's bytes, in hex (what ``sha256sum`` prints)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def task_settings(task: str, saved: Mapping[str, Any] | None = None):
    """The task's settings (a ``mjx_envs.settings.TaskConfig``) holding the values in ``saved``
    (a policy export's ``env``; keys that are not fields, such as ``dt``, are ignored). Fields
    that ``saved`` lacks (an export written before the field existed) keep the values of
    ``mjx_envs.registry.default_config(task)``. Raises ValueError for an unknown task or a value
    outside its field's range."""
    return registry.saved_config(task, saved or {})


def env_settings(task: str, saved: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """A policy export's env settings, JSON-ready: every field of ``task_settings(task,
    saved)``, ``dt`` (the control period, ``timestep * n_substeps`` unless saved) and any other
    key ``saved`` holds. A task that ``mjx_envs.settings`` does not know keeps ``saved`` as is."""
    out = dict(saved or {})
    if task in registry.TASK_SETTINGS:
        out.update(schema.to_dict(task_settings(task, saved)))
    if "dt" not in out and "timestep" in out and "n_substeps" in out:
        out["dt"] = float(out["timestep"]) * int(out["n_substeps"])
    return out


def _no_constant(name):
    raise ValueError(f"{name} is not valid JSON")


def _check_input(name: str, x, tail: tuple[int, ...]) -> np.ndarray:
    try:
        arr = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{name} must be an array of numbers: {e}") from None
    if arr.ndim < len(tail) or tuple(arr.shape[arr.ndim - len(tail):]) != tail:
        want = "[..., " + ", ".join(map(str, tail)) + "]"
        raise ValueError(f"{name} must have shape {want}, got {list(arr.shape)}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains NaN or infinite values")
    return arr.astype(np.float32)


class NumpyPolicy:
    """Deterministic actors of an exported run (format: ``daddpg_jax/running/export.py``)."""

    def __init__(self, weights: list[np.ndarray], biases: list[np.ndarray],
                 obs_mean, obs_std, goal_mean, goal_std, meta: dict[str, Any]):
        check_meta(meta)
        self.meta = meta
        self.sha256: str | None = None  # of the file's bytes; set by `load`
        self.algo = str(meta["algo"])
        if self.algo not in variants.VARIANTS:
            raise PolicyFormatError(f"unknown algo {self.algo!r} in policy file; this code "
                                    f"reads {', '.join(variants.ALGOS)}")
        self.variant = variants.get(self.algo)
        self.task = str(meta["task"])
        self.obs_size = int(meta["obs_size"])
        self.goal_size = int(meta["goal_size"])
        self.num_arms = int(meta.get("num_arms", 2))
        self.action_size = int(meta["action_size"])
        self.arm_action = int(meta["arm_action"])
        n = meta["normalizer"]
        self.clip_obs = np.float32(n["clip_obs"])
        self.norm_clip = np.float32(n["norm_clip"])
        with np.errstate(over="ignore"):  # float64 beyond float32 -> inf, refused below
            self.weights = [np.ascontiguousarray(w, np.float32) for w in weights]
            self.biases = [np.ascontiguousarray(b, np.float32) for b in biases]
            self.obs_mean = np.asarray(obs_mean, np.float32)
            self.obs_std = np.asarray(obs_std, np.float32)
            self.goal_mean = np.asarray(goal_mean, np.float32)
            self.goal_std = np.asarray(goal_std, np.float32)
        self.num_agents = int(self.weights[0].shape[0])
        try:
            # the physics it was trained on: the env's own record, else the file's (absent: 1)
            saved = {"physics_version": task_settings_lib.recorded_physics_version(
                meta.get("physics_version")), **(meta.get("env") or {})}
            self._env = env_settings(self.task, saved)
        except ValueError as e:
            raise PolicyFormatError(f"env settings of the policy file: {e}") from None
        check_env(self._env)
        self._validate()

    # -- loading ------------------------------------------------------------------------------

    @classmethod
    def load(cls, path) -> NumpyPolicy:
        """The policy in the ``.npz`` at ``path``. Raises FileNotFoundError when it does not
        exist and PolicyFormatError (one line) for anything else that is wrong with it:
        not a zip, truncated, ``meta`` outside its schema (``check_meta``) or declaring sizes,
        agents or layers that this code does not run (``array_plan``, checked before any array
        is read), arrays over ``MAX_INFLATED_BYTES`` in all (from ``meta`` and from the zip
        directory, before any is inflated), a missing array, an array larger than its declared
        shape, wrong shapes or dtypes (from each member's ``.npy`` header, before its data is
        inflated), NaN/inf values, std <= 0. ``sha256`` holds the SHA-256 of the file's bytes."""
        path = os.fspath(path)
        if not os.path.exists(path):
            raise FileNotFoundError(f"policy file {path!r} not found")
        try:
            policy = cls._read(path)
            policy.sha256 = file_sha256(path)
        except PolicyFormatError as e:
            raise PolicyFormatError(f"{path!r}: {e}") from None
        except Exception as e:  # noqa: BLE001 - any other failure of a malformed file
            text = " ".join(str(e).split())[:200]
            raise PolicyFormatError(f"{path!r} is not a readable .npz policy file: "
                                    f"{type(e).__name__}: {text}") from None
        return policy

    @classmethod
    def _read(cls, path: str) -> NumpyPolicy:
        size = os.path.getsize(path)
        if size > MAX_FILE_BYTES:
            _fail(f"file of {size} bytes exceeds the limit of {MAX_FILE_BYTES}")
        with zipfile.ZipFile(path) as zf:
            members = zf.infolist()
            if len(members) > MAX_MEMBERS:
                _fail(f"{len(members)} members, more than {MAX_MEMBERS}")
            infos = {i.filename: i for i in members}
            if "meta.npy" not in infos:
                _fail("no 'meta' entry: not a policy export")
            raw = _member(zf, infos, "meta", MAX_META_BYTES)
            if raw.dtype.kind != "U" or raw.shape != ():
                _fail("'meta' must be a JSON string")
            meta = json.loads(str(raw), parse_constant=_no_constant)
            check_meta(meta)
            plan = array_plan(meta)   # from meta alone: nothing else is read before it passes
            members = [_info(infos, name, _limit(shape)) for name, shape in plan]
            total = sum(i.file_size for i in members)
            if total > MAX_INFLATED_BYTES:
                _fail(f"arrays of {total} bytes once inflated (zip directory), more than the "
                      f"limit of {MAX_INFLATED_BYTES}")
            arrays = {name: _float_array(zf, info, name, shape)
                      for (name, shape), info in zip(plan, members, strict=True)}
        n = len(meta["layer_sizes"])
        return cls([arrays[f"actor/W{i}"] for i in range(n)],
                   [arrays[f"actor/b{i}"] for i in range(n)],
                   *(arrays[f"{k}_norm/{s}"] for k in ("obs", "goal") for s in ("mean", "std")),
                   meta=meta)

    def _validate(self):
        v = self.variant
        if (self.num_arms, self.arm_action) != (variants.NUM_ARMS, variants.ARM_ACTION):
            raise PolicyFormatError(f"{self.num_arms} arms with {self.arm_action} action "
                                    f"entries each; this code drives {variants.NUM_ARMS} arms "
                                    f"with {variants.ARM_ACTION}")
        if self.action_size != self.num_arms * self.arm_action:
            raise PolicyFormatError(f"action size {self.action_size}, expected "
                                    f"{self.num_arms * self.arm_action}")
        if self.num_agents != v.num_agents:
            raise PolicyFormatError(f"{self.num_agents} agents for algo {self.algo} "
                                    f"(expected {v.num_agents})")
        a_in = v.input_dims(self.obs_size, self.goal_size)[0]
        if int(self.meta["actor_input_dim"]) != a_in:
            raise PolicyFormatError(f"actor input size {self.meta['actor_input_dim']}, expected "
                                    f"{a_in} for algo {self.algo}")
        prev = a_in
        for i, (w, b) in enumerate(zip(self.weights, self.biases, strict=True)):
            if w.ndim != 3 or w.shape[0] != self.num_agents or w.shape[1] != prev:
                raise PolicyFormatError(f"actor layer {i} weights have shape {w.shape}")
            if b.shape != (self.num_agents, w.shape[2]):
                raise PolicyFormatError(f"actor layer {i} biases have shape {b.shape}")
            prev = w.shape[2]
        if prev != v.agent_action_dim:
            raise PolicyFormatError(f"actor output size {prev}, expected {v.agent_action_dim}")
        for name, arr, size in (("obs", self.obs_mean, self.obs_size),
                                ("obs", self.obs_std, self.obs_size),
                                ("goal", self.goal_mean, self.goal_size),
                                ("goal", self.goal_std, self.goal_size)):
            if arr.shape != (self.num_arms, size):
                raise PolicyFormatError(f"{name} normalizer has shape {arr.shape}")
        if not all(np.all(np.isfinite(x)) for x in self.weights + self.biases):
            raise PolicyFormatError("actor weights contain NaN or infinite values")
        if not all(np.all(np.isfinite(x)) for x in (self.obs_mean, self.obs_std,
                                                      self.goal_mean, self.goal_std)):
            raise PolicyFormatError("normalizer contains NaN or infinite values")
        if np.any(self.obs_std <= 0) or np.any(self.goal_std <= 0):
            raise PolicyFormatError("normalizer std must be positive")
        if not (np.isfinite(self.clip_obs) and np.isfinite(self.norm_clip)
                and self.clip_obs > 0 and self.norm_clip > 0):
            raise PolicyFormatError("normalizer clips must be finite and positive")

    # -- properties the robot side uses -------------------------------------------------------

    @property
    def env(self) -> dict[str, Any]:
        """Env settings of the run (dt, max_delta, workspace boxes, ...): the values saved with
        the policy, and ``mjx_envs.registry.default_config(task)``'s for fields the file lacks
        (see `env_settings`). A copy: changing it changes nothing in the policy."""
        return json.loads(json.dumps(self._env))

    @property
    def obs_layout(self) -> dict[str, tuple[int, int]]:
        return {k: (int(v[0]), int(v[1])) for k, v in self.meta["obs_layout"].items()}

    def info(self) -> dict[str, Any]:
        """A JSON-ready summary (what the policy service's GET /info returns)."""
        m = self.meta
        return dict(format_version=m["format_version"], task=self.task, algo=self.algo,
                    num_agents=self.num_agents, obs_size=self.obs_size, goal_size=self.goal_size,
                    action_size=self.action_size, num_arms=self.num_arms,
                    arm_action=self.arm_action, obs_layout=m["obs_layout"],
                    obs_fields=m.get("obs_fields"), layer_sizes=m["layer_sizes"],
                    action=m["action"], env=self.env,
                    checkpoint_step=(m.get("source") or {}).get("checkpoint_step")
                    if isinstance(m.get("source") or {}, dict) else None,
                    policy_sha256=self.sha256,
                    physics_version=m.get("physics_version", 1),
                    trained_limits=m.get("trained_limits"))

    # -- inference ----------------------------------------------------------------------------

    def _normalize(self, x, mean, std):
        x = np.clip(x, -self.clip_obs, self.clip_obs)
        return np.clip((x - mean) / std, -self.norm_clip, self.norm_clip)

    def _actor_inputs(self, o, g):
        """o [B, 2, obs], g [B, 2, 3] (normalized) -> [A, B, in], as the variant's row says
        (``networks.actor_inputs``): 'both' = every agent sees the flattened (o_1, o_2, g_1,
        g_2); 'own' = agent i sees its arm's (o_i, g_i)."""
        if self.variant.actor_sees == variants.BOTH:
            b = o.shape[0]
            x = np.concatenate([o.reshape(b, -1), g.reshape(b, -1)], -1)
            return np.broadcast_to(x, (self.num_agents,) + x.shape)
        return np.moveaxis(np.concatenate([o, g], -1), -2, 0)

    def _forward(self, x):
        """x [A, B, in] -> [A, B, out]."""
        n = len(self.weights)
        for i, (w, b) in enumerate(zip(self.weights, self.biases, strict=True)):
            x = np.matmul(x, w) + b[:, None, :]
            x = np.maximum(x, np.float32(0.0)) if i < n - 1 else np.tanh(x)
        return x

    def act(self, observation, desired_goal) -> np.ndarray:
        """Joint action [..., 8] in [-1, 1] (arm 0's [dx, dy, dz, finger], then arm 1's)."""
        o = _check_input("observation", observation, (self.num_arms, self.obs_size))
        g = _check_input("desired_goal", desired_goal, (self.num_arms, self.goal_size))
        lead_o, lead_g = o.shape[:-2], g.shape[:-2]
        if lead_o != lead_g:
            raise ValueError(f"observation and desired_goal have different leading axes: "
                             f"{list(lead_o)} vs {list(lead_g)}")
        o = o.reshape((-1,) + o.shape[-2:])
        g = g.reshape((-1,) + g.shape[-2:])
        o = self._normalize(o, self.obs_mean, self.obs_std)
        g = self._normalize(g, self.goal_mean, self.goal_std)
        pi = self._forward(self._actor_inputs(o, g))
        a = np.concatenate(list(pi), -1)  # the agents' action slots in agent order
        return a.reshape(lead_o + (self.action_size,)).astype(np.float32)

    def act_per_arm(self, observation, desired_goal) -> np.ndarray:
        """Actions [..., 2, 4]: row i is arm i's [dx, dy, dz, finger]."""
        a = self.act(observation, desired_goal)
        return a.reshape(a.shape[:-1] + (self.num_arms, self.arm_action))

    __call__ = act
