"""Training loop: one jitted `train_epoch` (lax.scan over cycles) and a vectorized `evaluate`.

A cycle (all inside one compiled program):
  1. reset every env (vmapped `env.reset`, one key per env) and roll out T steps with lax.scan;
     each arm's action is its actor's output + N(0, noise_eps), clipped to [-1, 1], replaced by a
     uniform random action with probability random_eps (drawn per env, per arm, per step);
  2. insert the num_envs episodes into the ring buffer;
  3. update the normalizers with every new transition once: observations o_t, and the goals
     after the same HER relabelling the learner will see (as the HER baselines do, but with the
     exhaustive set of (episode, t) pairs instead of a random draw);
  4. n_batches updates of all actors and critics (lax.scan), each on a fresh HER minibatch;
  5. one polyak update of the target networks.
Host-side work (logging, checkpoints, evaluation scheduling) happens between epochs only; an
optional progress callback runs once per cycle through `jax.debug.callback`.

Counters are int32 (`cycles`, `updates`); env steps are cycles * num_envs * T, computed in
Python by `TrainFns.env_steps` so they cannot overflow.

Several local devices (cfg.num_devices, 0 = all): the cycle body runs under `shard_map` over a
1-d device mesh, data parallel over envs, replay shards and the update batch (see
daddpg_jax/algo/sharding.py). One device: the code path below without any mesh.
"""

from __future__ import annotations

from typing import Callable, NamedTuple, Optional

import jax
import jax.numpy as jnp
from flax import struct

from daddpg_jax.algo import losses as agent_lib
from daddpg_jax.algo import networks as nets
from daddpg_jax.algo import normalizer as norm
from daddpg_jax.algo import replay
from daddpg_jax.algo import sharding as shd
from daddpg_jax.algo.config import TrainConfig


@struct.dataclass
class TrainState:
    agent: agent_lib.AgentState
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
    rollout: Callable         # rollout(state, key, n_envs, explore) -> (Episodes, per-step dict [T, N, ...])
    env_steps: Callable       # env_steps(state) -> int
    learner: agent_lib.Learner
    config: TrainConfig
    capacity: int             # buffer capacity in episodes (all devices together)
    horizon: int
    num_devices: int = 1      # devices the cycle is spread over
    mesh: Optional[object] = None   # jax.sharding.Mesh when num_devices > 1
    state_shardings: Optional[object] = None   # TrainState of NamedShardings when num_devices > 1


def make_train_fns(env, cfg: TrainConfig, progress: Optional[Callable] = None,
                   update_progress: Optional[Callable] = None, update_tick: int = 0,
                   demo_policy: Optional[Callable] = None) -> TrainFns:
    """Builds the jitted functions for `env` (an ENV_CONTRACT env) and `cfg`.

    progress: optional host function `progress(metrics)` called once per cycle (unordered)
    with that cycle's metrics as NumPy arrays (for a progress bar); None compiles no callback.
    update_progress: optional host function `update_progress(n)` called after every
    `update_tick` gradient updates inside a cycle with n = updates done in that cycle, so a
    progress bar moves during long cycles (large num_envs on a CPU); 0 or None compiles none.
    demo_policy: with cfg.n_demos > 0, the controller that plays the demonstrations, a pure
    function of the env's observation dict -> joint action [..., 8]; default: the task's
    scripted controller (mjx_envs.tasks.scripted) at the env's max_delta.
    """
    T = int(env.episode_length)
    n_arms = int(env.num_arms)
    if n_arms != 2 or env.action_size != 2 * nets.ARM_ACTION:
        raise ValueError("the trainer expects 2 arms with 4-d actions each")
    learner = agent_lib.make_learner(cfg, env.reward_range)
    algo, n_agents = cfg.algo, cfg.num_agents
    info_keys = tuple(env.info_keys)
    capacity = replay.capacity_episodes(cfg.buffer_size, T, cfg.num_envs)
    n_dev = shd.resolve_num_devices(cfg.num_devices)
    mesh = None
    if n_dev > 1:
        shd.check_divisible(cfg.num_envs, cfg.batch_size, n_dev)
        capacity = shd.sharded_capacity(capacity, n_dev)
        mesh = shd.make_mesh(n_dev)
    n_envs_local, batch_local = cfg.num_envs // n_dev, cfg.batch_size // n_dev
    future_p = cfg.future_p
    n_demos = int(cfg.n_demos)
    if n_demos > 0:
        if demo_policy is None:
            from mjx_envs.tasks import scripted

            ctrl, max_delta = scripted.get_policy(cfg.task), float(env.config.max_delta)
            demo_policy = lambda obs: ctrl(obs, max_delta)   # noqa: E731
        if cfg.demo_batch % n_dev:
            raise ValueError(f"demo_batch ({cfg.demo_batch}) must be a multiple of the number of "
                             f"devices ({n_dev})")
    demo_local = cfg.demo_batch // n_dev
    demo_rows = jnp.arange(batch_local + demo_local) >= batch_local   # update batch: demo rows last
    norm_kw = dict(eps=cfg.norm_eps, clip=cfg.norm_clip, clip_obs=cfg.clip_obs)

    def update_normalizers(obs_norm, goal_norm, key, episodes, axis=None):
        """Both normalizers updated with every transition of `episodes` once, goals after the
        HER relabelling the learner sees (exhaustive (episode, t) pairs)."""
        n = episodes.num_episodes
        ep = jnp.repeat(jnp.arange(n, dtype=jnp.int32), T)
        t = jnp.tile(jnp.arange(T, dtype=jnp.int32), n)
        nt = replay.her_transitions(key, episodes, ep, t, cfg.her, future_p, env.compute_reward)
        return (norm.update(obs_norm, nt["o"], cfg.clip_obs, axis_name=axis),
                norm.update(goal_norm, nt["g"], cfg.clip_obs, axis_name=axis))

    def normalize_inputs(state, o, g):
        return norm.normalize(state.obs_norm, o, **norm_kw), norm.normalize(state.goal_norm, g, **norm_kw)

    def act(state: TrainState, obs, desired_goal):
        """Deterministic joint action [..., 8] for observations [..., 2, obs], goals [..., 2, 3]."""
        lead = obs.shape[:-2]
        o = obs.reshape((-1,) + obs.shape[-2:])
        g = desired_goal.reshape((-1,) + desired_goal.shape[-2:])
        o, g = normalize_inputs(state, o, g)
        pi = agent_lib.policy_actions(learner, state.agent.actor, o, g)
        return nets.joint_action(algo, pi).reshape(lead + (env.action_size,))

    def rollout(state: TrainState, key, n_envs: int, explore: bool):
        def actors(s, keys):
            k_noise, k_coin, k_rand = keys
            o, g = normalize_inputs(state, s.obs["observation"], s.obs["desired_goal"])
            pi = agent_lib.policy_actions(learner, state.agent.actor, o, g)   # [A, N, d]
            if explore:
                pi = jnp.clip(pi + cfg.noise_eps * jax.random.normal(k_noise, pi.shape), -1.0, 1.0)
                coin = jax.random.bernoulli(k_coin, cfg.random_eps, pi.shape[:2] + (1,))
                pi = jnp.where(coin, jax.random.uniform(k_rand, pi.shape, minval=-1.0, maxval=1.0), pi)
            return nets.joint_action(algo, pi)
        return play(actors, key, n_envs)

    def play(policy, key, n_envs: int):
        """Episodes of `policy(env_state, keys) -> joint action [N, 8]` in n_envs fresh envs
        (keys: three fresh PRNG keys per step)."""
        k_reset, k_scan = jax.random.split(key)
        s0 = jax.vmap(env.reset)(jax.random.split(k_reset, n_envs))

        def step(carry, _):
            s, k = carry
            k, *keys = jax.random.split(k, 4)
            a = policy(s, keys)
            s2 = jax.vmap(env.step)(s, a)
            out = dict(obs=s2.obs["observation"], ag=s2.obs["achieved_goal"],
                       g=s.obs["desired_goal"], a=a,
                       info={k_: s2.info[k_] for k_ in info_keys},
                       reward=s2.reward, success=s2.metrics["success"],
                       arm_contact=s2.metrics["arm_contact"])
            return (s2, k), out

        (_, _), tr = jax.lax.scan(step, (s0, k_scan), None, length=T)
        bt = lambda x: jnp.swapaxes(x, 0, 1)   # [T, N, ...] -> [N, T, ...]
        episodes = replay.Episodes(
            obs=jnp.concatenate([s0.obs["observation"][:, None], bt(tr["obs"])], 1),
            ag=jnp.concatenate([s0.obs["achieved_goal"][:, None], bt(tr["ag"])], 1),
            g=bt(tr["g"]), actions=bt(tr["a"]), info=jax.tree.map(bt, tr["info"]))
        return episodes, tr

    def rollout_metrics(episodes, tr):
        g_last = episodes.g[:, -1]
        dist = jnp.linalg.norm(episodes.ag[:, -1] - g_last, axis=-1)               # [N, 2]
        return dict(success=jnp.mean(tr["success"][-1]),
                    arm_contact=jnp.mean(jnp.max(tr["arm_contact"], axis=0)),
                    arm_contact_steps=jnp.mean(tr["arm_contact"]),
                    final_distance=jnp.mean(dist, 0),
                    episode_return=jnp.mean(jnp.sum(tr["reward"], 0), 0))

    def init(key=None) -> TrainState:
        if key is None:
            key = jax.random.PRNGKey(cfg.seed)
        k_agent, k_state = jax.random.split(key)
        a_state = agent_lib.init_agent_state(k_agent, learner, cfg.hidden, env.obs_size, env.goal_size)
        buf = replay.init(capacity, T, env.obs_size, env.goal_size, env.action_size, info_keys, n_arms)
        obs_norm, goal_norm = norm.init((n_arms, env.obs_size)), norm.init((n_arms, env.goal_size))
        if n_demos > 0:
            # its own stream (fold_in), so the agent's and trainer's keys do not depend on n_demos
            k_play, k_norm = jax.random.split(jax.random.fold_in(key, DEMO_STREAM))
            demos, _ = play(lambda s, k: demo_policy(s.obs).astype(jnp.float32), k_play, n_demos)
            obs_norm, goal_norm = update_normalizers(obs_norm, goal_norm, k_norm, demos)
        else:
            demos = replay.init(0, T, env.obs_size, env.goal_size, env.action_size, info_keys,
                                n_arms).data
        return TrainState(agent=a_state, obs_norm=obs_norm, goal_norm=goal_norm,
                          buffer=buf, demos=demos, key=k_state,
                          cycles=jnp.zeros((), jnp.int32), updates=jnp.zeros((), jnp.int32))

    def cycle_body(state: TrainState, axis=None):
        """One cycle; axis=None: single device; else the body of a shard_map over `axis` (this
        device's envs, replay shard and batch slice; buffer index/size are local values)."""
        key, k_roll, k_norm, k_upd = jax.random.split(state.key, 4)
        if axis is not None:
            dev = jax.lax.axis_index(axis)
            k_roll, k_norm, k_upd = (jax.random.fold_in(k, dev) for k in (k_roll, k_norm, k_upd))
        episodes, tr = rollout(state, k_roll, n_envs_local, explore=True)
        buf = replay.insert(state.buffer, episodes)

        obs_norm, goal_norm = update_normalizers(state.obs_norm, state.goal_norm, k_norm,
                                                 episodes, axis)
        state = state.replace(buffer=buf, obs_norm=obs_norm, goal_norm=goal_norm)

        def one_update(agent, xs):
            k, i = xs
            b = replay.sample(k, buf, batch_local, cfg.her, future_p, env.compute_reward)
            b = {name: b[name] for name in ("o", "o2", "g", "a", "r")}
            if n_demos > 0:
                k_idx, k_her = jax.random.split(jax.random.fold_in(k, DEMO_STREAM))
                ep, t = replay.sample_indices(k_idx, n_demos, demo_local, T)
                d = replay.her_transitions(k_her, state.demos, ep, t, cfg.her, future_p,
                                           env.compute_reward)
                b = {name: jnp.concatenate([b[name], d[name]]) for name in b}
            o, g = normalize_inputs(state, b["o"], b["g"])
            o2 = norm.normalize(obs_norm, b["o2"], **norm_kw)
            batch = dict(o=o, o2=o2, g=g, a=b["a"], r=agent_lib.agent_rewards(algo, b["r"]))
            if n_demos > 0:
                batch["demo"] = demo_rows
            out = agent_lib.update(agent, batch, learner, axis_name=axis)
            if update_progress is not None and update_tick:
                tick = (i + 1) % update_tick == 0
                if axis is not None:
                    tick = tick & (jax.lax.axis_index(axis) == 0)
                jax.lax.cond(tick,
                             lambda: jax.debug.callback(update_progress, i + 1, ordered=False),
                             lambda: None)
            return out

        a_state, um = jax.lax.scan(
            one_update, state.agent,
            (jax.random.split(k_upd, cfg.n_batches), jnp.arange(cfg.n_batches, dtype=jnp.int32)))
        a_state = agent_lib.update_targets(a_state, cfg.polyak)
        um = jax.tree.map(lambda x: jnp.mean(x, 0), um)
        nonfinite = ~(jnp.all(jnp.isfinite(um["critic_loss"])) & jnp.all(jnp.isfinite(um["actor_loss"])))
        state = state.replace(agent=a_state, key=key, cycles=state.cycles + 1,
                              updates=state.updates + cfg.n_batches)
        r_metrics = rollout_metrics(episodes, tr)
        if axis is not None:
            r_metrics = jax.lax.pmean(r_metrics, axis)
        metrics = dict(r_metrics, **um, nonfinite=nonfinite,
                       cycle=state.cycles, buffer_episodes=buf.size)
        return state, metrics

    def train_cycle(state: TrainState, _):
        state, metrics = cycle_body(state)
        if progress is not None:
            jax.debug.callback(progress, metrics, ordered=False)
        return state, metrics

    state_specs = state_shardings = None
    if mesh is not None:
        state_specs = shd.train_state_specs(jax.eval_shape(init, jax.random.PRNGKey(0)))
        state_shardings = shd.named_shardings(mesh, state_specs)

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
        sharded_cycle = shd.shard_map(local_cycle, mesh, in_specs=(state_specs,),
                                      out_specs=(state_specs, jax.sharding.PartitionSpec()),
                                      check_vma=False)

        def train_cycle(state: TrainState, _):  # noqa: F811 (multi-device variant)
            state, metrics = sharded_cycle(state)
            if progress is not None:
                jax.debug.callback(progress, metrics, ordered=False)
            return state, metrics

    def train_epoch(state: TrainState):
        return jax.lax.scan(train_cycle, state, None, length=cfg.n_cycles)

    def evaluate_impl(state: TrainState, key):
        episodes, tr = rollout(state, key, cfg.n_test_episodes, explore=False)
        return rollout_metrics(episodes, tr)

    evaluate_jit = jax.jit(evaluate_impl)

    def evaluate(state: TrainState, key=None):
        """Deterministic actors on n_test_episodes episodes from fixed seeds (cfg.eval_seed)."""
        if key is None:
            key = jax.random.PRNGKey(cfg.eval_seed)
        return evaluate_jit(state, key)

    def env_steps(state: TrainState) -> int:
        return int(state.cycles) * cfg.num_envs * T

    if mesh is None:
        epoch_jit = jax.jit(train_epoch, donate_argnums=0)
    else:
        rep_sh = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec())
        epoch_jit = jax.jit(train_epoch, donate_argnums=0, in_shardings=(state_shardings,),
                            out_shardings=(state_shardings, rep_sh))
    return TrainFns(init=_init_wrapper(init, cfg, state_shardings),
                    train_epoch=epoch_jit,
                    evaluate=evaluate, act=jax.jit(act),
                    rollout=jax.jit(rollout, static_argnums=(2, 3)), env_steps=env_steps,
                    learner=learner, config=cfg, capacity=capacity, horizon=T,
                    num_devices=n_dev, mesh=mesh, state_shardings=state_shardings)


DEMO_STREAM = 0x64656D6F
"""fold_in constant of the PRNG stream that plays the demonstrations at init."""


def _init_wrapper(init_fn, cfg, shardings=None):
    init_jit = jax.jit(init_fn) if shardings is None else jax.jit(init_fn, out_shardings=shardings)

    def init(key=None):
        if key is None:
            key = jax.random.PRNGKey(cfg.seed)
        return init_jit(key)
    return init
