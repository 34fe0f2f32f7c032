"""Evaluate a trained run from its checkpoint: success rate with a confidence interval, arm
contact, final goal distances, and an optional video.

    from daddpg_jax.analysis import evaluation
    policy = evaluation.load_policy("runs/reach_s0")          # latest checkpoint
    policy = evaluation.load_policy("runs/reach_s0", best=True)   # best test success
    result, traj = evaluation.evaluate(policy, episodes=200, seed=0)
    evaluation.write_video(policy, traj, "reach.mp4", n_episodes=3)

`load_policy` is ``daddpg_jax.running.checkpoint_policy.load_run_policy``, the loader export
uses too: the env is rebuilt from the run's ``config.json`` (task, physics, env overrides; the
training-only task options, ``mjx_envs.settings.TRAINING_ONLY_FIELDS``, are switched off with
``mjx_envs.registry.test_overrides``, as in the trainer's test episodes), and the actors and
normalizers alone are restored from ``RUN_DIR/checkpoints/{step}`` (``best=True``: the checkpoint
with the best test success, ``RUN_DIR/checkpoints_best/``) into a target from the networks' and
normalizers' own init functions (no training step, replay buffer or optimizer state is built).
N episodes run at once with deterministic actors (one vmapped, jitted rollout). Episode i's
reset key is ``split(split(PRNGKey(seed))[0], N)[i]``, the same derivation as the trainer's
per-epoch evaluation, so ``seed = eval_seed`` (the default) and ``N = n_test_episodes``
reproduce the ``test_success_rate`` that ``metrics.csv`` logged for that epoch.

Per episode: success = every arm within the threshold at the last step (as in training),
arm contact = the arms' link capsules came within ``arm_clearance`` at any step, final goal
distance per arm at the last step, physics fault = the engine froze or diverged at some step
(``metrics["physics_ok"]`` 0; the trainer logs the same rate as ``test_physics_fault_rate``).

Chunks and the watchdog: the N episodes may run in chunks of ``chunk`` episodes (one compiled
program of that batch; the last chunk is padded with repeats of its last key and the extras
dropped). Every episode keeps its own reset key (the slice of the N keys above), so the results
do not depend on the chunk size. MJX on a CPU runs in chunks of ``MJX_CPU_CHUNK`` by default:
its contact scenes hang intermittently at larger batches (every thread asleep in
``device_get``). With a watchdog, each chunk's execution (after compilation) runs in a worker
thread; a chunk that has not finished after ``watchdog`` seconds is started again once, and a
second miss raises `EngineHang` (``daddpg-evaluate`` then stops with one line, exit code 3).
"""

from __future__ import annotations

import contextlib
import csv
import importlib.util
import math
import os
import sys
import threading
import time
import weakref

import numpy as np

from daddpg_jax.running import checkpoint_policy
from mjx_envs import observation as obs_lib
from mjx_envs import registry
from mjx_envs.settings import MJX_CPU_CHUNK  # noqa: F401 (part of this module's interface)

# MuJoCo picks its OpenGL backend when it is first imported: headless EGL unless told otherwise
os.environ.setdefault("MUJOCO_GL", "egl")

Z95 = 1.959963984540054  # standard normal quantile 0.975

WATCHDOG_SECONDS = 120.0
"""default watchdog of a chunked MJX evaluation on a CPU: seconds one chunk may take (after
compilation) before it is started again once"""


def wilson_interval(successes: int, n: int, z: float = Z95) -> tuple[float, float]:
    """Wilson score interval for a binomial proportion (default 95%).

    centre = (p + z²/2n) / (1 + z²/n),  half width = z / (1 + z²/n) · sqrt(p(1-p)/n + z²/4n²).
    Unlike the normal approximation it stays inside [0, 1] and is not empty at p = 0 or 1.
    """
    if n <= 0:
        return (math.nan, math.nan)
    if not 0 <= successes <= n:
        raise ValueError(f"successes must be in [0, {n}], got {successes}")
    p = successes / n
    z2 = z * z
    denom = 1.0 + z2 / n
    centre = (p + z2 / (2 * n)) / denom
    half = z / denom * math.sqrt(p * (1 - p) / n + z2 / (4 * n * n))
    lo = 0.0 if successes == 0 else max(0.0, centre - half)   # exact ends (no rounding residue)
    hi = 1.0 if successes == n else min(1.0, centre + half)
    return (lo, hi)


NoCheckpointError = checkpoint_policy.RunPolicyError
"""RUN_DIR has no config.json or no (such, readable) checkpoint (the loader's error)."""

Policy = checkpoint_policy.RunPolicy
"""A run's policy and env (``checkpoint_policy.RunPolicy``): ``act(params, obs, goal)`` plays
the episodes; `train_video` makes one of the trainer's own ``act`` and TrainState."""


def standard_env_overrides(task: str, env_overrides: dict | None) -> dict:
    """A run's env overrides for test (evaluation) episodes: the standard task, i.e. the
    training-only task options switched off (``mjx_envs.registry.test_overrides``)."""
    return {**(env_overrides or {}), **registry.test_overrides(task)}


def load_policy(run_dir: str, step: int | None = None, physics: str | None = None,
                best: bool = False, physics_version: int | None = None,
                robot_limits: tuple | None = None) -> Policy:
    """Rebuilds the run's env and restores checkpoint ``step`` (default: latest), or with
    ``best`` the run's best checkpoint (the epoch of its best test success), without building
    the training step (``checkpoint_policy.load_run_policy``). The env simulates
    the physics version the run was trained on, or ``physics_version`` (one warning line when
    that acts unlike the run's). ``robot_limits``: the env setting of a robot limits file
    (`daddpg_jax.algo.resolve.limits_values`), applied to every action instead of the run's
    own (None: the run's; ``()``: none). NoCheckpointError when it cannot be loaded."""
    return checkpoint_policy.load_run_policy(run_dir, step, best=best, physics=physics,
                                             physics_version=physics_version,
                                             robot_limits=robot_limits)


class EngineHang(RuntimeError):
    """A chunk of episodes made no progress within the watchdog's time, twice."""


def run_watched(fn, timeout: float | None, what: str = "chunk", retries: int = 1):
    """``fn()``, with ``timeout``: run in a daemon thread; if it has not returned after
    ``timeout`` seconds it is started again (``retries`` times, one line on stderr each), then
    `EngineHang` is raised. A thread that hangs inside the engine cannot be stopped: it is left
    behind (daemon), and a caller that gives up should end the process (``os._exit``)."""
    if timeout is None:
        return fn()
    for attempt in range(retries + 1):
        box: dict = {}

        def work(box=box):
            try:
                box["value"] = fn()
            except BaseException as e:  # noqa: BLE001 (re-raised in the caller's thread)
                box["error"] = e

        t = threading.Thread(target=work, name=f"watched {what}", daemon=True)
        t.start()
        t.join(timeout)
        if "error" in box:
            raise box["error"]
        if "value" in box:
            return box["value"]
        if attempt < retries:
            print(f"warning: {what} made no progress in {timeout:g} s; starting it again",
                  file=sys.stderr, flush=True)
    raise EngineHang(f"{what} made no progress in {timeout:g} s, twice (the engine hangs)")


class IdentityCache:
    """Values cached per *object identity* (plus a hashable key): ``get(objs, key, build)``
    returns ``build()``'s value for the same live objects and key. The entry holds weak
    references to its objects and is dropped when one of them is collected, so a new object
    that reuses a dead one's ``id()`` never receives the dead one's value (a perturbation grid
    builds one env per grid point and drops it: keyed on bare ids, a later point could get an
    earlier point's compiled rollout)."""

    def __init__(self):
        self._entries: dict = {}

    def __len__(self) -> int:
        return len(self._entries)

    def get(self, objs: tuple, key, build):
        k = (tuple(id(o) for o in objs), key)
        hit = self._entries.get(k)
        if hit is not None and all(r() is o for r, o in zip(hit[0], objs, strict=True)):
            return hit[1]
        value = build()
        refs = tuple(weakref.ref(o) for o in objs)
        self._entries[k] = (refs, value)
        for o in objs:
            weakref.finalize(o, self._drop, k, refs)
        return value

    def _drop(self, k, refs) -> None:
        hit = self._entries.get(k)
        if hit is not None and hit[0] is refs:  # not an entry built later under the same ids
            del self._entries[k]


_ROLLOUTS = IdentityCache()
"""compiled rollouts per (env, act) object and batch shape"""


def _rollout_fn(policy: Policy, n: int, key_shape=(2,), key_dtype=np.uint32):
    """The compiled rollout of ``n`` episodes: (state, reset keys [n, *key_shape]) -> (per-step
    records [T, n, ...], first states, desired goals [n, 2, 3]); cached per env and act object
    (`IdentityCache`)."""
    import jax  # lazy: JAX loads only when episodes run (daddpg-evaluate --help stays JAX-free)

    def build():  # compiled before any watchdog runs
        keys = jax.ShapeDtypeStruct((n, *key_shape), key_dtype)
        return jax.jit(_rollout_program(policy)).lower(policy.params, keys).compile()

    return _ROLLOUTS.get((policy.env, policy.act),
                         (n, tuple(key_shape), np.dtype(key_dtype).str), build)


def _rollout_program(policy: Policy):
    """(params, reset keys [n, 2]) -> (per-step records [T, n, ...], first states, desired goals
    [n, 2, 3]): the function that ``_rollout_fn`` compiles."""
    # lazy: JAX loads only when episodes run (daddpg-evaluate --help stays JAX-free)
    import jax

    from daddpg_jax.algo import acting

    env, act = policy.env, policy.act

    def positions(data):   # true object centre [N, 3] and grip points [N, 2, 3]
        sens = env.backend.sensordata(data)
        obj = obs_lib.read_object_sensors(jax.numpy, env.sensors, sens, sens.shape[:-1])
        return obj["pos"], obs_lib.read_arm_sensors(jax.numpy, env.sensors, sens)["grip_pos"]

    def record(s, a, s2):
        ok = s2.metrics.get("physics_ok", jax.numpy.ones_like(s2.metrics["success"]))
        obj, grip = positions(s2.data)
        return dict(success=s2.metrics["success"], arm_contact=s2.metrics["arm_contact"],
                    ag=s2.obs["achieved_goal"], qpos=env.backend.qpos(s2.data),
                    mocap=env.backend.mocap_pos(s2.data)[:, :2], physics_ok=ok,
                    object=obj, grip=grip)

    def run(params, keys):
        def actors(s, _):
            return act(params, s.obs["observation"], s.obs["desired_goal"])

        s0, tr = acting.rollout(env, actors, keys, record=record)
        obj, grip = positions(s0.data)
        first = dict(qpos=env.backend.qpos(s0.data), mocap=env.backend.mocap_pos(s0.data)[:, :2],
                     object=obj, grip=grip)
        return tr, first, s0.obs["desired_goal"]

    return run


def run_episodes(policy: Policy, keys, chunk: int | None = None,
                 watchdog: float | None = None):
    """Rolls out one episode per reset key (``keys`` [N, 2]) in chunks of ``chunk`` (None: all
    at once). Returns NumPy (records [T, N, ...], first states [N, ...], goals [N, 2, 3])."""
    import jax  # lazy: JAX loads only when episodes run (daddpg-evaluate --help stays JAX-free)

    keys = np.asarray(keys)
    n = len(keys)
    size = n if chunk is None else max(1, min(int(chunk), n))
    fn = _rollout_fn(policy, size, keys.shape[1:], keys.dtype)
    parts = []
    for i, lo in enumerate(range(0, n, size)):
        part = keys[lo:lo + size]
        pad = size - len(part)
        if pad:   # one program for every chunk: repeat the last key, drop its results
            part = np.concatenate([part, np.repeat(part[-1:], pad, 0)])
        what = f"chunk {i + 1}/{-(-n // size)} ({size} episodes, physics {policy.env.physics})"
        out = run_watched(lambda part=part: jax.device_get(fn(policy.params, part)), watchdog,
                          what)
        parts.append(_trim(out, size - pad))
    tr = {k: np.concatenate([p[0][k] for p in parts], 1) for k in parts[0][0]}
    first = {k: np.concatenate([p[1][k] for p in parts], 0) for k in parts[0][1]}
    goal = np.concatenate([p[2] for p in parts], 0)
    return tr, first, goal


def _trim(out, m: int):
    tr, first, goal = out
    return ({k: np.asarray(v)[:, :m] for k, v in tr.items()},
            {k: np.asarray(v)[:m] for k, v in first.items()}, np.asarray(goal)[:m])


def check_episodes_fit(policy: Policy, episodes: int) -> None:
    """ConfigError (one line) when the outputs of `episodes` episodes (kept on the host, every
    chunk's) and their env states cannot fit in memory, sized from shapes (nothing is
    allocated or compiled): call before making the episodes' keys."""
    # lazy: resources imports JAX (daddpg-evaluate --help stays JAX-free)
    import jax

    from daddpg_jax.running import resources

    key = jax.ShapeDtypeStruct((2,), np.uint32)
    out = jax.eval_shape(_rollout_program(policy), policy.params,
                         jax.ShapeDtypeStruct((1, 2), np.uint32))
    one = jax.eval_shape(policy.env.reset, key)
    nbytes = episodes * (resources.tree_bytes(out) + 2 * resources.tree_bytes(one) + 8)
    resources.check_fits(f"evaluating {episodes:,} episodes", nbytes, "lower --episodes")


def _metrics_row(run_dir: str, epoch: int) -> dict | None:
    path = os.path.join(run_dir, "metrics.csv")
    if not os.path.exists(path):
        return None
    with open(path, newline="") as f:
        for r in csv.DictReader(f):
            if int(r["epoch"]) == int(epoch):
                return r
    return None


def chunk_options(chunk: int | None, watchdog: float | None) -> dict:
    """`evaluate`'s ``chunk`` and ``watchdog`` from daddpg-evaluate's flags: None (not given)
    is "auto", a watchdog of 0 is none."""
    return dict(chunk="auto" if chunk is None else chunk,
                watchdog="auto" if watchdog is None else (watchdog or None))


def evaluate(policy: Policy, episodes: int = 100, seed: int | None = None,
             chunk: int | str | None = "auto", watchdog: float | str | None = "auto"):
    """Runs ``episodes`` deterministic episodes, in chunks of ``chunk`` episodes ("auto":
    `mjx_envs.physics.backends.default_chunk`; None: all at once) under a watchdog of
    ``watchdog`` seconds per chunk
    ("auto": ``WATCHDOG_SECONDS`` for MJX on a CPU, else none; None: none). Returns
    (summary dict, trajectory) where the trajectory holds NumPy arrays for rendering and
    comparison: ``qpos`` [N, T+1, nq], ``mocap`` [N, T+1, 2, 3], ``object`` [N, T+1, 3] (object
    centre; zeros without an object), ``grip`` [N, T+1, 2, 3], ``goal`` [N, 2, 3],
    ``success`` [N], ``arm_contact`` [N], ``physics_fault`` [N], ``final_distance`` [N, 2]."""
    # lazy: JAX loads only when episodes run (daddpg-evaluate --help stays JAX-free)
    import jax

    from daddpg_jax.algo import acting
    from mjx_envs.physics import backends

    if episodes < 1:
        raise ValueError("episodes must be >= 1")
    seed = int(policy.cfg.eval_seed if seed is None else seed)
    physics = getattr(policy.env, "physics", policy.cfg.physics)
    if chunk == "auto":
        chunk = backends.default_chunk(physics)
    if chunk is not None and (int(chunk) != chunk or chunk < 1):
        raise ValueError(f"chunk must be an integer >= 1, 'auto' or None, got {chunk!r}")
    if watchdog == "auto":
        watchdog = WATCHDOG_SECONDS if backends.default_chunk(physics) is not None else None
    if watchdog is not None and not watchdog > 0:
        raise ValueError(f"watchdog must be > 0 seconds, 'auto' or None, got {watchdog!r}")
    check_episodes_fit(policy, int(episodes))
    t0 = time.perf_counter()
    # the trainer's evaluation episodes: the same reset keys, whatever the chunk size
    keys = np.asarray(acting.episode_keys(jax.random.PRNGKey(seed), int(episodes)))
    tr, first, goal = run_episodes(policy, keys, chunk, watchdog)
    elapsed = time.perf_counter() - t0
    success = np.asarray(tr["success"][-1]) > 0.5                       # [N]
    contact = np.max(np.asarray(tr["arm_contact"]), axis=0) > 0.5        # [N]
    fault = np.min(np.asarray(tr["physics_ok"]), axis=0) < 0.5          # [N]
    dist = np.linalg.norm(np.asarray(tr["ag"][-1]) - np.asarray(goal), axis=-1)  # [N, 2]
    n, k, c = int(episodes), int(success.sum()), int(contact.sum())
    row = _metrics_row(policy.run_dir, policy.step)
    cfg = policy.cfg
    summary = {
        "run_dir": os.path.abspath(policy.run_dir),
        "checkpoint": policy.step, "best": policy.best,
        "env_steps": int(row["env_steps"]) if row else None,
        "task": cfg.task, "algo": cfg.algo, "physics": physics,
        "physics_version": int(policy.env.config.physics_version),
        "episodes": n, "seed": seed,
        "success_rate": k / n, "successes": k, "success_ci95": list(wilson_interval(k, n)),
        "arm_contact_rate": c / n, "arm_contact_episodes": c,
        "arm_contact_ci95": list(wilson_interval(c, n)),
        "final_distance_mean": {"left": float(dist[:, 0].mean()),
                                "right": float(dist[:, 1].mean())},
        "final_distance_median": {"left": float(np.median(dist[:, 0])),
                                  "right": float(np.median(dist[:, 1]))},
        "distance_threshold": float(policy.env.config.distance_threshold),
        "physics_fault_rate": int(fault.sum()) / n, "physics_fault_episodes": int(fault.sum()),
        "eval_seconds": round(elapsed, 3),
    }

    def with_first(k):   # [N, T+1, ...]
        return np.swapaxes(np.concatenate([first[k][None], tr[k]], 0), 0, 1)

    traj = dict(qpos=with_first("qpos"), mocap=with_first("mocap"),
                object=with_first("object"), grip=with_first("grip"), goal=np.asarray(goal),
                success=success, arm_contact=contact, physics_fault=fault,
                final_distance=dist)
    return summary, traj


def format_summary(s: dict) -> str:
    lo, hi = s["success_ci95"]
    clo, chi = s["arm_contact_ci95"]
    steps = f", {s['env_steps']:,} env steps" if s.get("env_steps") is not None else ""
    fd, fm = s["final_distance_mean"], s["final_distance_median"]
    faults = [] if "physics_fault_rate" not in s else [
        f"physics faults    {s['physics_fault_rate']:.3f}  ({s['physics_fault_episodes']}/"
        f"{s['episodes']} episodes in which the engine froze or diverged)"]
    return "\n".join([
        f"run {s['run_dir']}",
        f"checkpoint {s['checkpoint']}{steps}; task {s['task']}, algo {s['algo']}, "
        f"physics {s['physics']}",
        f"{s['episodes']} episodes, seed {s['seed']}, deterministic actors",
        f"success rate      {s['success_rate']:.3f}  ({s['successes']}/{s['episodes']}; "
        f"95% Wilson interval {lo:.3f}-{hi:.3f})",
        f"arm-contact rate  {s['arm_contact_rate']:.3f}  ({s['arm_contact_episodes']}/"
        f"{s['episodes']}; 95% Wilson interval {clo:.3f}-{chi:.3f})",
        f"final goal distance, m (threshold {s['distance_threshold']:g}): "
        f"left mean {fd['left']:.4f} median {fm['left']:.4f}; "
        f"right mean {fd['right']:.4f} median {fm['right']:.4f}",
        *faults,
    ])


class RenderUnavailable(RuntimeError):
    """No OpenGL context (set MUJOCO_GL=egl and install libegl1 libegl-mesa0 libgl1-mesa-dri)."""


def _border(frame: np.ndarray, ok: bool, width: int = 6) -> np.ndarray:
    f = frame.copy()
    color = np.array([40, 180, 60] if ok else [200, 50, 40], np.uint8)
    f[:width], f[-width:], f[:, :width], f[:, -width:] = color, color, color, color
    return f


def render_frames(policy: Policy, traj: dict, n_episodes: int = 3, width: int = 480,
                  height: int = 360, hold: int = 12) -> list:
    """RGB frames of the first ``n_episodes`` episodes one after another; each episode ends
    with ``hold`` copies of its last frame framed green (success) or red (failure)."""
    os.environ.setdefault("MUJOCO_GL", "egl")
    try:
        from mjx_envs.render import Renderer  # lazy: MuJoCo's renderer, only for a video

        r = Renderer(policy.env, width=width, height=height)
    except Exception as e:  # noqa: BLE001 (no EGL, no GL context, ...)
        raise RenderUnavailable(
            f"rendering failed ({type(e).__name__}: {e}); set MUJOCO_GL=egl before MuJoCo is "
            "imported and install libegl1 libegl-mesa0 libgl1-mesa-dri") from e
    frames = []
    try:
        for e in range(min(n_episodes, len(traj["goal"]))):
            for t in range(traj["qpos"].shape[1]):
                frames.append(r.frame(traj["qpos"][e, t], traj["goal"][e], traj["mocap"][e, t]))
            frames += [_border(frames[-1], bool(traj["success"][e]))] * hold
    finally:
        r.close()
    return frames


def write_video(policy: Policy, traj: dict, path: str, n_episodes: int = 3, width: int = 480,
                height: int = 360) -> str:
    """Writes the frames of ``render_frames`` as an mp4 (imageio + imageio-ffmpeg). Without an
    mp4 writer it writes a GIF next to ``path`` instead. Returns the path written."""
    frames = render_frames(policy, traj, n_episodes, width, height)
    return write_frames(path, frames, int(round(1.0 / policy.env.dt)))


def add_video(summary: dict, policy: Policy, traj: dict, path: str, n_episodes: int = 3,
              width: int = 480, height: int = 360) -> str | None:
    """`write_video`, its path recorded in summary["video"]; returns a note when a GIF was
    written instead of the mp4 asked for (no mp4 writer), else None."""
    written = write_video(policy, traj, path, n_episodes, width, height)
    summary["video"] = os.path.abspath(written)
    if written != path:
        return f"note: no mp4 writer (pip install imageio-ffmpeg); wrote a GIF: {written}"
    return None


def write_frames(path: str, frames: list, fps: int) -> str:
    """Writes RGB frames as an mp4 (imageio + imageio-ffmpeg), or a GIF when `path` ends in
    .gif or no mp4 writer is installed (beside `path`). Returns the path written."""
    import imageio.v2 as imageio  # optional extra [video]

    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    if path.lower().endswith(".gif"):
        imageio.mimsave(path, frames, duration=1000.0 / fps, loop=0)
        return path
    try:
        with _no_fork_hooks():
            imageio.mimsave(path, frames, fps=fps, macro_block_size=8)
        return path
    except Exception:  # noqa: BLE001 (no ffmpeg backend)
        alt = os.path.splitext(path)[0] + ".gif"
        imageio.mimsave(alt, frames, duration=1000.0 / fps, loop=0)
        return alt


@contextlib.contextmanager
def _no_fork_hooks():
    """imageio-ffmpeg starts ffmpeg with a ``preexec_fn`` (to keep Ctrl-C from it), which makes
    Python run its fork hooks, and JAX's hook warns that os.fork() and its threads deadlock.
    ffmpeg is exec'd at once, and without the preexec_fn (IMAGEIO_FFMPEG_NO_PREVENT_SIGINT)
    the child is started without running any hook: no warning, nothing to hide."""
    old = os.environ.get("IMAGEIO_FFMPEG_NO_PREVENT_SIGINT")
    os.environ["IMAGEIO_FFMPEG_NO_PREVENT_SIGINT"] = "1"
    try:
        yield
    finally:
        if old is None:
            os.environ.pop("IMAGEIO_FFMPEG_NO_PREVENT_SIGINT", None)
        else:
            os.environ["IMAGEIO_FFMPEG_NO_PREVENT_SIGINT"] = old


VIDEO_EPISODES = 2
"""test episodes in each --video-every video"""


def train_video(env, fns, state, path: str):
    """`epoch_video` of a run's current training state (``runner.RunOptions.video``): the
    trainer's own ``act`` on its TrainState."""
    return epoch_video(Policy("", int(state.cycles), fns.config, {}, env, fns.act, state), path)


def epoch_video(policy: Policy, path: str, n_episodes: int = VIDEO_EPISODES,
                width: int = 320, height: int = 240):
    """The first `n_episodes` test episodes of the run's evaluation seed, rendered to `path`
    (`write_frames`). Returns (path written, frames, fps); RenderUnavailable without a
    renderer or without imageio."""
    if importlib.util.find_spec("imageio") is None:
        raise RenderUnavailable("imageio is not installed (pip install 'daddpg-jax[video]')")
    _, traj = evaluate(policy, n_episodes)
    frames = render_frames(policy, traj, n_episodes, width, height)
    fps = int(round(1.0 / policy.env.dt))
    return write_frames(path, frames, fps), frames, fps
