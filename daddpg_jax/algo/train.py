"""Training loop: one jitted `train_epoch` (lax.scan over cycles) and a vectorized `evaluate`.

A cycle (all inside one compiled program):
  1. reset every env (vmapped `env.reset`, one key per env) and roll out T steps with lax.scan
     (`daddpg_jax.algo.acting`); each arm's action is its actor's output + N(0, noise_eps),
     clipped to [-1, 1], replaced by a uniform random action with probability random_eps (drawn
     per env, per arm, per step);
  2. insert the num_envs episodes into the ring buffer;
  3. update the normalizers with every new transition once: observations o_t, and the goals
     after the same HER relabelling the learner will see (as the HER baselines do, but with the
     exhaustive set of (episode, t) pairs instead of a random draw);
  4. n_batches updates of all actors and critics (lax.scan), each on a fresh HER minibatch;
  5. one polyak update of the target networks.
Host-side work (logging, checkpoints, evaluation scheduling) happens between epochs only; the
optional host callbacks of `EpochHooks` (progress per cycle, timing marks) run at the cycle
level.

Counters are int32 (`cycles`, `updates`); env steps are cycles * num_envs * T, computed in
Python by `TrainFns.env_steps` so they cannot overflow.

Devices (cfg.num_devices, 0 = all, of every process of a multi-process job): the state lives on
a 1-d device mesh (one device: a mesh of one), its replay storage sharded over the devices.
On several devices the cycle body runs under `shard_map`, data parallel over envs, replay
shards and the update batch, and evaluation plays its episodes spread over the mesh (see
daddpg_jax/algo/sharding.py); on one device the same body runs without `shard_map`, which
would change the last float32 bits of the results (docs/SCALING.md), so single-device results
stay those of the plain program.

`make_train_fns` assembles the pieces built below: `_setup` (static sizes, checks),
`_acting_fns` (act, rollout, rollout_keys), `_normalizer_update`, `_init_fn`, `_updates_fn`
(the n_batches gradient updates), `_cycle_fn` (one cycle), `_sharded_cycle` (the multi-device
wrapper) and `_evaluate_fn` (with `_sharded_evaluate` on several devices).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct
from jax.experimental import io_callback

from daddpg_jax import variants
from daddpg_jax.algo import acting, actors, losses, replay
from daddpg_jax.algo import networks as nets
from daddpg_jax.algo import normalizer as norm
from daddpg_jax.algo import sharding as shd
from daddpg_jax.algo.config import TrainConfig

DEMO_STREAM = 0x64656D6F
"""fold_in constant of the PRNG stream that plays the demonstrations at init."""


@struct.dataclass
class TrainState:
    agent: losses.AgentState
    obs_norm: norm.NormState
    goal_norm: norm.NormState
    buffer: replay.ReplayBuffer
    demos: replay.Episodes  # fixed demonstration episodes [n_demos, ...] (0 when off)
    key: jax.Array          # uint32[2] PRNG key
    cycles: jax.Array       # int32: cycles done
    updates: jax.Array      # int32: gradient updates done


class TrainFns(NamedTuple):
    init: Callable            # init(key=None) -> TrainState
    train_epoch: Callable     # train_epoch(state) -> (state, metrics of per-cycle arrays)
    evaluate: Callable        # evaluate(state, key=None) -> metrics dict
    act: Callable             # act(state, obs [...,2,obs], desired_goal [...,2,3]) -> [..., 8]
    rollout: Callable         # rollout(state, key, n_envs, explore)
    #                           -> (Episodes, per-step dict [T, N, ...])
    env_steps: Callable       # env_steps(state) -> int
    learner: losses.Learner
    config: TrainConfig
    capacity: int             # buffer capacity in episodes (all devices together)
    horizon: int
    num_devices: int = 1      # devices the cycle is spread over
    mesh: Any = None          # jax.sharding.Mesh of the num_devices devices
    state_shardings: Any = None   # TrainState of NamedShardings over the mesh


class _Setup(NamedTuple):
    """Static pieces shared by the builders below."""
    env: Any
    cfg: TrainConfig
    learner: losses.Learner
    horizon: int
    info_keys: tuple
    capacity: int             # episodes, all devices together
    n_dev: int
    mesh: Any                 # the 1-d device mesh (of one device on one)
    n_envs_local: int         # envs per device
    batch_local: int          # replay rows of an update batch per device
    demo_local: int           # demo rows of an update batch per device
    demo_policy: Callable | None


class EpochHooks:
    """What the compiled epoch reports to the host: pass an instance (or any object with some of
    these attributes) as `make_train_fns(hooks=...)`. Each callback is compiled into the epoch
    only when the object has it (`getattr(hooks, name, None)` is not None); every call happens
    at the cycle level, none inside the scan of gradient updates (a cycle's updates are one
    scan: splitting it to report within a cycle would change the rounding of the results).

    - `cycle(metrics)`: once per cycle, with that cycle's metrics as NumPy arrays (unordered:
      a progress bar).
    - `stage(stage)`: when a cycle's rollout is done (ROLLOUT_DONE) and when its updates are done
      (UPDATES_DONE), in program order (on several devices: device 0's), for a split of the
      epoch's time (`StageClock`).
    """

    cycle: Callable | None = None
    stage: Callable | None = None


def make_train_fns(env, cfg: TrainConfig, hooks: Any = None,
                   demo_policy: Callable | None = None, eval_env=None,
                   eval_chunk: int | None = None) -> TrainFns:
    """Builds the jitted functions for `env` (an ENV_CONTRACT env) and `cfg`.

    hooks: host callbacks of the compiled epoch (`EpochHooks`: per cycle, stage marks for
    timing), or None to compile none.
    demo_policy: with cfg.n_demos > 0, the controller that plays the demonstrations, a pure
    function of the env's observation dict -> joint action [..., 8]; default: the task's
    scripted controller (mjx_envs.tasks.scripted) at the env's max_delta.
    eval_env: the env of `evaluate` (default: `env`); e.g. the task without its training-only
    options (mjx_envs.registry.test_overrides), so that test episodes stay the standard task.
    eval_chunk: play the test episodes `evaluate` runs in batches of this many (one device;
    e.g. `mjx_envs.settings.MJX_CPU_CHUNK` for MJX on a CPU); the metrics do not depend on it.
    """
    setup = _setup(env, cfg, demo_policy)
    on_cycle = getattr(hooks, "cycle", None)
    on_stage = getattr(hooks, "stage", None)
    act, rollout, rollout_keys = _acting_fns(setup)
    update_normalizers = _normalizer_update(setup)
    init = _init_fn(setup, update_normalizers)
    cycle = _cycle_fn(setup, rollout, update_normalizers, _updates_fn(setup), on_stage)
    if eval_env is not None and eval_env is not env:
        _, _, eval_rollout_keys = _acting_fns(setup._replace(env=eval_env))
        eval_rollout = _rollout_from(eval_rollout_keys)
    else:
        eval_rollout, eval_rollout_keys = rollout, rollout_keys
    state_shardings = shd.named_shardings(
        setup.mesh, shd.train_state_specs(jax.eval_shape(init, jax.random.PRNGKey(0))))
    if setup.n_dev > 1:
        cycle = _sharded_cycle(setup, cycle, state_shardings)

    def train_cycle(state: TrainState, _):
        state, metrics = cycle(state)
        if on_cycle is not None:
            jax.debug.callback(on_cycle, metrics, ordered=False)
        return state, metrics

    def train_epoch(state: TrainState):
        return jax.lax.scan(train_cycle, state, None, length=cfg.n_cycles)

    replicated = jax.sharding.NamedSharding(setup.mesh, jax.sharding.PartitionSpec())
    epoch_jit = jax.jit(train_epoch, donate_argnums=0, in_shardings=(state_shardings,),
                        out_shardings=(state_shardings, replicated))

    def env_steps(state: TrainState) -> int:
        return int(state.cycles) * cfg.num_envs * setup.horizon

    return TrainFns(init=_init_wrapper(init, cfg, state_shardings), train_epoch=epoch_jit,
                    evaluate=_evaluate_fn(setup, eval_rollout, eval_rollout_keys, eval_chunk),
                    act=jax.jit(act),
                    rollout=jax.jit(rollout, static_argnums=(2, 3)), env_steps=env_steps,
                    learner=setup.learner, config=cfg, capacity=setup.capacity,
                    horizon=setup.horizon, num_devices=setup.n_dev, mesh=setup.mesh,
                    state_shardings=state_shardings)


def _setup(env, cfg: TrainConfig, demo_policy: Callable | None) -> _Setup:
    """Checks env and cfg; sizes of the buffer, the devices and the per-device batches."""
    T = int(env.episode_length)
    if (int(env.num_arms) != variants.NUM_ARMS
            or env.action_size != variants.NUM_ARMS * variants.ARM_ACTION):
        raise ValueError("the trainer expects 2 arms with 4-d actions each")
    learner = losses.make_learner(cfg, env.reward_range)
    capacity = replay.capacity_episodes(cfg.buffer_size, T, cfg.num_envs)
    n_dev = shd.resolve_num_devices(cfg.num_devices)
    shd.check_divisible(cfg.num_envs, cfg.batch_size, n_dev)
    capacity = shd.sharded_capacity(capacity, n_dev)
    if cfg.n_demos > 0:
        if demo_policy is None:
            # lazy: the trainer needs the env package's controllers only for this default
            from mjx_envs.tasks import scripted

            ctrl, max_delta = scripted.get_policy(cfg.task), float(env.config.max_delta)

            def demo_policy(obs):
                return ctrl(obs, max_delta)
        if cfg.demo_batch % n_dev:
            raise ValueError(f"demo_batch ({cfg.demo_batch}) must be a multiple of the number of "
                             f"devices ({n_dev})")
    return _Setup(env=env, cfg=cfg, learner=learner, horizon=T, info_keys=tuple(env.info_keys),
                  capacity=capacity, n_dev=n_dev, mesh=shd.make_mesh(n_dev),
                  n_envs_local=cfg.num_envs // n_dev,
                  batch_local=cfg.batch_size // n_dev, demo_local=cfg.demo_batch // n_dev,
                  demo_policy=demo_policy)


def _normalize_inputs(cfg: TrainConfig, state: TrainState, o, g):
    return actors.normalize_inputs(cfg, actors.of_state(state), o, g)


def _acting_fns(setup: _Setup):
    """(act, rollout, rollout_keys): the deterministic joint action, and episodes of the actors
    (exploring or not) played like `acting.play_episodes` (rollout_keys: from given reset
    keys and scan key)."""
    cfg, learner, env = setup.cfg, setup.learner, setup.env

    def act(state: TrainState, obs, desired_goal):
        """Deterministic joint action [..., 8] for observations [..., 2, obs], goals [..., 2, 3]."""
        return actors.act(cfg, actors.of_state(state), obs, desired_goal)

    def rollout_keys(state: TrainState, reset_keys, k_scan, explore: bool):
        """One episode per reset key; k_scan: the key carried through the steps."""
        def actors(s, keys):
            k_noise, k_coin, k_rand = keys
            o, g = _normalize_inputs(cfg, state, s.obs["observation"], s.obs["desired_goal"])
            pi = losses.policy_actions(learner, state.agent.actor, o, g)   # [A, N, d]
            if explore:
                pi = jnp.clip(pi + cfg.noise_eps * jax.random.normal(k_noise, pi.shape), -1.0, 1.0)
                coin = jax.random.bernoulli(k_coin, cfg.random_eps, pi.shape[:2] + (1,))
                rand = jax.random.uniform(k_rand, pi.shape, minval=-1.0, maxval=1.0)
                pi = jnp.where(coin, rand, pi)
            return nets.joint_action(pi)
        # acting.play_episodes, recording physics_ok as well (for the physics-fault rate)
        s0, tr = acting.rollout(env, actors, reset_keys, key=k_scan,
                                step_keys=acting.TRAIN_STEP_KEYS, record=_record(setup.info_keys))
        return acting.stack_episodes(s0, tr), tr

    return act, _rollout_from(rollout_keys), rollout_keys


def _rollout_from(rollout_keys):
    """rollout(state, key, n_envs, explore): n_envs episodes, the reset keys split from key."""
    def rollout(state: TrainState, key, n_envs: int, explore: bool):
        k_reset, k_scan = jax.random.split(key)
        return rollout_keys(state, jax.random.split(k_reset, n_envs), k_scan, explore)

    return rollout


def _record(info_keys):
    """`acting.transitions` plus the env's per-step `physics_ok` metric when it has one."""
    base = acting.transitions(info_keys)

    def record(s, a, s2):
        out = base(s, a, s2)
        if "physics_ok" in s2.metrics:
            out["physics_ok"] = s2.metrics["physics_ok"]
        return out

    return record


def _normalizer_update(setup: _Setup):
    cfg, T = setup.cfg, setup.horizon

    def update_normalizers(obs_norm, goal_norm, key, episodes, axis=None):
        """Both normalizers updated with every transition of `episodes` once, goals after the
        HER relabelling the learner sees (exhaustive (episode, t) pairs)."""
        n = episodes.num_episodes
        ep = jnp.repeat(jnp.arange(n, dtype=jnp.int32), T)
        t = jnp.tile(jnp.arange(T, dtype=jnp.int32), n)
        nt = replay.her_transitions(key, episodes, ep, t, cfg.her, cfg.future_p,
                                    setup.env.compute_reward)
        return (norm.update(obs_norm, nt["o"], cfg.clip_obs, axis_name=axis),
                norm.update(goal_norm, nt["g"], cfg.clip_obs, axis_name=axis))

    return update_normalizers


def _init_fn(setup: _Setup, update_normalizers):
    cfg, env, T = setup.cfg, setup.env, setup.horizon
    n_arms = variants.NUM_ARMS

    def empty_buffer(capacity):
        return replay.init(capacity, T, env.obs_size, env.goal_size, env.action_size,
                           setup.info_keys, n_arms)

    def init(key=None) -> TrainState:
        if key is None:
            key = jax.random.PRNGKey(cfg.seed)
        k_agent, k_state = jax.random.split(key)
        a_state = losses.init_agent_state(k_agent, setup.learner, cfg.hidden, env.obs_size,
                                             env.goal_size)
        buf = empty_buffer(setup.capacity)
        obs_norm, goal_norm = norm.init((n_arms, env.obs_size)), norm.init((n_arms, env.goal_size))
        if cfg.n_demos > 0:
            # its own stream (fold_in), so the agent's and trainer's keys do not depend on n_demos
            k_play, k_norm = jax.random.split(jax.random.fold_in(key, DEMO_STREAM))
            demos, _ = acting.play_episodes(
                env, lambda s, k: setup.demo_policy(s.obs).astype(jnp.float32), k_play,
                int(cfg.n_demos), setup.info_keys)
            obs_norm, goal_norm = update_normalizers(obs_norm, goal_norm, k_norm, demos)
        else:
            demos = empty_buffer(0).data
        return TrainState(agent=a_state, obs_norm=obs_norm, goal_norm=goal_norm,
                          buffer=buf, demos=demos, key=k_state,
                          cycles=jnp.zeros((), jnp.int32), updates=jnp.zeros((), jnp.int32))

    return init


def _update_batch(setup: _Setup, state: TrainState, key, demo_rows):
    """A normalized update batch: batch_local HER replay rows (+ demo_local demo rows)."""
    cfg, T = setup.cfg, setup.horizon
    n_step = dict(n_step=cfg.n_step, gamma=cfg.gamma)
    b = replay.sample(key, state.buffer, setup.batch_local, cfg.her, cfg.future_p,
                      setup.env.compute_reward, **n_step)
    names = ("o", "o2", "g", "a", "r") + (("discount",) if cfg.n_step > 1 else ())
    b = {name: b[name] for name in names}
    if cfg.n_demos > 0:
        k_idx, k_her = jax.random.split(jax.random.fold_in(key, DEMO_STREAM))
        ep, t = replay.sample_indices(k_idx, int(cfg.n_demos), setup.demo_local, T)
        d = replay.her_transitions(k_her, state.demos, ep, t, cfg.her, cfg.future_p,
                                   setup.env.compute_reward, **n_step)
        b = {name: jnp.concatenate([b[name], d[name]]) for name in b}
    o, g = _normalize_inputs(cfg, state, b["o"], b["g"])
    o2 = norm.normalize(state.obs_norm, b["o2"], **actors.norm_kw(cfg))
    batch = dict(o=o, o2=o2, g=g, a=b["a"],
                 r=losses.agent_rewards(setup.learner.variant, b["r"]))
    if cfg.n_step > 1:
        batch["discount"] = b["discount"]
    if cfg.n_demos > 0:
        batch["demo"] = demo_rows
    return batch


def _updates_fn(setup: _Setup):
    """updates(state, key, axis) -> (agent after n_batches updates and the polyak step, mean
    update metrics). state: the cycle's state after the insert and the normalizer update."""
    cfg = setup.cfg
    # update batch: demo rows last
    demo_rows = jnp.arange(setup.batch_local + setup.demo_local) >= setup.batch_local

    def updates(state: TrainState, key, axis=None):
        def one_update(agent, k):
            batch = _update_batch(setup, state, k, demo_rows)
            return losses.update(agent, batch, setup.learner, axis_name=axis)

        a_state, um = jax.lax.scan(one_update, state.agent,
                                   jax.random.split(key, cfg.n_batches))
        a_state = losses.update_targets(a_state, cfg.polyak)
        return a_state, jax.tree.map(lambda x: jnp.mean(x, 0), um)

    return updates


def _rollout_metrics(episodes, tr):
    """Means over the episodes of a rollout; `physics_fault` (only for an env that reports
    `physics_ok`): the fraction of episodes with a step whose physics_ok is 0."""
    g_last = episodes.g[:, -1]
    dist = jnp.linalg.norm(episodes.ag[:, -1] - g_last, axis=-1)               # [N, 2]
    out = dict(success=jnp.mean(tr["success"][-1]),
               arm_contact=jnp.mean(jnp.max(tr["arm_contact"], axis=0)),
               arm_contact_steps=jnp.mean(tr["arm_contact"]),
               final_distance=jnp.mean(dist, 0),
               episode_return=jnp.mean(jnp.sum(tr["reward"], 0), 0))
    if "physics_ok" in tr:
        faulted = jnp.any(tr["physics_ok"] < 0.5, axis=0)                        # [N]
        out["physics_fault"] = jnp.mean(faulted.astype(jnp.float32))
    return out


ROLLOUT_DONE, UPDATES_DONE = 0, 1
"""stages reported to `EpochHooks.stage`"""


def _mark(on_stage: Callable | None, stage: int, after, then, axis=None):
    """`then` unchanged, released only once the host call `on_stage(stage)` has run, which runs
    once `after` is computed: the call is ordered in the program between what computes `after`
    and what uses `then` (an optimization barrier ties the callback's result to `then`). Under
    shard_map (axis) every device makes the call and device 0's alone reaches `on_stage`."""
    if on_stage is None:
        return then

    def call(_, device):
        if int(device) == 0:
            on_stage(stage)
        return np.zeros((), np.int32)

    device = 0 if axis is None else jax.lax.axis_index(axis)
    done = io_callback(call, jax.ShapeDtypeStruct((), jnp.int32), after, device)
    _, then = jax.lax.optimization_barrier((done, then))
    return then


def _cycle_fn(setup: _Setup, rollout, update_normalizers, updates,
              on_stage: Callable | None = None):
    cfg = setup.cfg

    def cycle_body(state: TrainState, axis=None):
        """One cycle; axis=None: single device; else the body of a shard_map over `axis` (this
        device's envs, replay shard and batch slice; buffer index/size are local values)."""
        key, k_roll, k_norm, k_upd = jax.random.split(state.key, 4)
        if axis is not None:
            dev = jax.lax.axis_index(axis)
            k_roll, k_norm, k_upd = (jax.random.fold_in(k, dev) for k in (k_roll, k_norm, k_upd))
        episodes, tr = rollout(state, k_roll, setup.n_envs_local, explore=True)
        k_upd = _mark(on_stage, ROLLOUT_DONE, episodes.obs[0, -1, 0, 0], k_upd, axis)
        buf = replay.insert(state.buffer, episodes)
        obs_norm, goal_norm = update_normalizers(state.obs_norm, state.goal_norm, k_norm,
                                                 episodes, axis)
        state = state.replace(buffer=buf, obs_norm=obs_norm, goal_norm=goal_norm)
        a_state, um = updates(state, k_upd, axis)
        key = _mark(on_stage, UPDATES_DONE, jax.tree.leaves(a_state.target_critic)[0].ravel()[0],
                    key, axis)
        nonfinite = ~(jnp.all(jnp.isfinite(um["critic_loss"]))
                      & jnp.all(jnp.isfinite(um["actor_loss"])))
        state = state.replace(agent=a_state, key=key, cycles=state.cycles + 1,
                              updates=state.updates + cfg.n_batches)
        r_metrics = _rollout_metrics(episodes, tr)
        if axis is not None:
            r_metrics = jax.lax.pmean(r_metrics, axis)
        metrics = dict(r_metrics, **um, nonfinite=nonfinite,
                       cycle=state.cycles, buffer_episodes=buf.size)
        return state, metrics

    return cycle_body


def _sharded_cycle(setup: _Setup, cycle_body, state_shardings):
    """The cycle over the device mesh: `cycle_body` under shard_map, each device on its envs,
    its replay shard and its slice of the batch."""
    n_dev = setup.n_dev
    state_specs = jax.tree.map(lambda sh: sh.spec, state_shardings)

    def local_cycle(state: TrainState):
        # global ring index/size -> this device's (every device inserts n_envs_local)
        b = state.buffer
        state = state.replace(buffer=b.replace(insert_idx=b.insert_idx // n_dev,
                                               size=b.size // n_dev))
        state, metrics = cycle_body(state, shd.AXIS)
        b = state.buffer
        state = state.replace(buffer=b.replace(insert_idx=b.insert_idx * n_dev,
                                               size=b.size * n_dev))
        metrics["buffer_episodes"] = state.buffer.size
        return state, metrics

    # check_vma=False: env code (not written for shard_map) may start a scan carry from
    # device-invariant values that the varying actions then make device-varying; the
    # replicated outputs are made identical on every device by pmean/psum above.
    cycle = shd.shard_map(local_cycle, setup.mesh, in_specs=(state_specs,),
                          out_specs=(state_specs, jax.sharding.PartitionSpec()),
                          check_vma=False)
    return cycle


def _evaluate_fn(setup: _Setup, rollout, rollout_keys, chunk: int | None = None):
    cfg = setup.cfg
    if chunk is not None and setup.n_dev == 1 and cfg.n_test_episodes > chunk:
        return _chunked_evaluate(setup, rollout_keys, chunk)

    def evaluate_impl(state: TrainState, key):
        episodes, tr = rollout(state, key, cfg.n_test_episodes, explore=False)
        return _rollout_metrics(episodes, tr)

    impl = evaluate_impl if setup.n_dev == 1 else _sharded_evaluate(setup, rollout_keys)
    evaluate_jit = jax.jit(impl)

    def evaluate(state: TrainState, key=None):
        """Deterministic actors on n_test_episodes episodes from fixed seeds (cfg.eval_seed)."""
        if key is None:
            key = jax.random.PRNGKey(cfg.eval_seed)
        return evaluate_jit(state, key)

    return evaluate


def _chunked_evaluate(setup: _Setup, rollout_keys, chunk: int):
    """evaluate in batches of `chunk` test episodes (MJX on a CPU hangs at large batches): the
    same n_test_episodes reset keys as in one batch (the last batch padded with copies of the
    last key), the episodes gathered on the host before the means, so the metrics do not
    depend on `chunk`. One compiled batch shape; Python loops over the batches."""
    n = setup.cfg.n_test_episodes
    play = jax.jit(lambda state, keys, k_scan: rollout_keys(state, keys, k_scan, False))
    metrics = jax.jit(_rollout_metrics)

    def evaluate(state: TrainState, key=None):
        """Deterministic actors on n_test_episodes episodes from fixed seeds (cfg.eval_seed),
        `chunk` at a time."""
        if key is None:
            key = jax.random.PRNGKey(setup.cfg.eval_seed)
        k_reset, k_scan = jax.random.split(key)
        keys = jax.random.split(k_reset, n)
        keys = jnp.concatenate([keys, jnp.repeat(keys[-1:], -n % chunk, axis=0)])
        parts = [play(state, keys[i:i + chunk], k_scan) for i in range(0, n, chunk)]
        episodes = jax.tree.map(lambda *x: jnp.concatenate(x, 0)[:n], *[p[0] for p in parts])
        tr = jax.tree.map(lambda *x: jnp.concatenate(x, 1)[:, :n], *[p[1] for p in parts])
        return metrics(episodes, tr)

    return evaluate


def _sharded_evaluate(setup: _Setup, rollout_keys):
    """evaluate_impl spread over the mesh: the same n_test_episodes reset keys as on one
    device (padded with copies of the last one to a multiple of the devices), each device
    playing its share; the episodes are gathered and the padding dropped before the means."""
    n, n_dev = setup.cfg.n_test_episodes, setup.n_dev
    n_pad = -(-n // n_dev) * n_dev
    P = jax.sharding.PartitionSpec

    def local(policy, reset_keys, k_scan):
        agent, obs_norm, goal_norm = policy
        state = TrainState(agent=agent, obs_norm=obs_norm, goal_norm=goal_norm, buffer=None,
                           demos=None, key=k_scan, cycles=None, updates=None)
        return rollout_keys(state, reset_keys, k_scan, False)

    played = shd.shard_map(local, setup.mesh, in_specs=(P(), P(shd.AXIS), P()),
                           out_specs=(P(shd.AXIS), P(None, shd.AXIS)), check_vma=False)

    def evaluate_impl(state: TrainState, key):
        k_reset, k_scan = jax.random.split(key)
        keys = jax.random.split(k_reset, n)
        keys = jnp.concatenate([keys, jnp.repeat(keys[-1:], n_pad - n, axis=0)])
        episodes, tr = played((state.agent, state.obs_norm, state.goal_norm), keys, k_scan)
        episodes = jax.tree.map(lambda x: x[:n], episodes)
        tr = jax.tree.map(lambda x: x[:, :n], tr)
        return _rollout_metrics(episodes, tr)

    return evaluate_impl


def _init_wrapper(init_fn, cfg, shardings):
    init_jit = jax.jit(init_fn, out_shardings=shardings)

    def init(key=None):
        if key is None:
            key = jax.random.PRNGKey(cfg.seed)
        return init_jit(key)
    return init


class StageClock:
    """`EpochHooks.stage` as a host clock: splits each epoch's time into rollout time (from the
    previous mark, or `start()`, to a cycle's rollout done: the envs' reset and steps and the
    actors) and update time (buffer insert, normalizer update and the gradient updates: rollout
    done to updates done). The marks are host calls ordered inside the compiled cycle, so the
    sums are wall seconds of the compiled work, measured on the host."""

    def __init__(self):
        self.start()

    def start(self):
        """Call right before `train_epoch`; resets the sums."""
        self.last = time.perf_counter()
        self.rollout_s = 0.0
        self.update_s = 0.0

    def stage(self, stage: int):
        """`EpochHooks.stage`: the time since the previous mark goes to `stage`'s sum."""
        now = time.perf_counter()
        if int(stage) == ROLLOUT_DONE:
            self.rollout_s += now - self.last
        else:
            self.update_s += now - self.last
        self.last = now
