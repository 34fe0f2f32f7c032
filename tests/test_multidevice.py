"""Multi-device training on 2 forced host CPU devices (daddpg_jax/algo/sharding.py).

XLA reads --xla_force_host_platform_device_count only before JAX starts, so every check runs
in a fresh Python process with XLA_FLAGS set and prints one JSON line that the test reads.
"""

import json
import os
import subprocess
import sys
import textwrap

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

PRELUDE = """
import json, os, sys
import jax, jax.numpy as jnp, numpy as np
from tests.conftest import LEARN, LEARN_ENV, TINY, random_batch, tree_equal  # + CPU, jit cache
assert len(jax.local_devices()) == 2, jax.local_devices()
"""


def run_2dev(body: str, timeout: int = 240) -> dict:
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=2",
               JAX_PLATFORMS="cpu", PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))
    code = PRELUDE + textwrap.dedent(body)
    p = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True,
                       text=True, timeout=timeout)
    if p.returncode != 0:
        raise AssertionError(f"2-device script failed (rc {p.returncode}):\n{p.stdout[-3000:]}\n"
                             f"{p.stderr[-6000:]}")
    return json.loads(p.stdout.strip().splitlines()[-1])


@pytest.mark.e2e
def test_sharded_update_equals_unsharded_update():
    """What the trainer runs on each device: `losses.update(..., axis_name=AXIS)` on the
    device's slice of the batch under `sharding.shard_map` (agent replicated), and the
    normalizer update with its cross-device merge, equal the one-device computations."""
    out = run_2dev("""
    from daddpg_jax.algo import losses as agent_lib
    from daddpg_jax.algo import normalizer as norm
    from daddpg_jax.algo import sharding as shd
    from daddpg_jax import variants
    from jax.sharding import PartitionSpec as P
    OBS, B = 25, 64
    mesh = shd.make_mesh(2)
    res = {}
    for algo in ("daddpg", "single"):
        cfg = TINY.replace(algo=algo)
        learner = agent_lib.make_learner(cfg, (-1.05, 0.0))
        st = agent_lib.init_agent_state(jax.random.PRNGKey(0), learner, cfg.hidden, OBS)
        batch = random_batch(jax.random.PRNGKey(1), variants.get(algo).num_agents, B)
        # the batch split over the devices on its batch axis (r [A, B]: axis 1)
        specs = {k: (P(None, shd.AXIS) if k == "r" else P(shd.AXIS)) for k in batch}
        local = lambda agent, b: agent_lib.update(agent, b, learner, axis_name=shd.AXIS)
        upd = jax.jit(shd.shard_map(local, mesh, in_specs=(P(), specs), out_specs=(P(), P())))
        ref = jax.jit(agent_lib.update, static_argnums=2)
        ref_st, ref_m = ref(st, batch, learner)
        sh_st, sh_m = upd(st, batch)
        # two more steps so that Adam's moments matter
        ref2, sh2 = ref_st, sh_st
        for _ in range(2):
            ref2, _ = ref(ref2, batch, learner)
            sh2, _ = upd(sh2, batch)
        diff = lambda a, b: max(float(np.max(np.abs(np.asarray(x) - np.asarray(y))))
                                for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)))
        res[algo] = dict(state=diff(ref_st, sh_st), metrics=diff(ref_m, sh_m),
                         state3=diff(ref2, sh2), moved=diff(st.critic, ref_st.critic),
                         replicated=all(x.sharding.is_fully_replicated
                                        for x in jax.tree.leaves(sh_st)))
    # normalizer: per-device moments merged across devices == moments of the whole batch
    x = jax.random.normal(jax.random.PRNGKey(3), (40, 2, 25)) * 3 + 1
    s0 = norm.update(norm.init((2, 25)), x[:8] * 0.5)
    ref = norm.update(s0, x)
    f = shd.shard_map(lambda s, xl: norm.update(s, xl, axis_name=shd.AXIS), mesh,
                      in_specs=(P(), P(shd.AXIS)), out_specs=P())
    got = jax.jit(f)(s0, x)
    res["norm"] = max(float(np.max(np.abs(np.asarray(a) - np.asarray(b))
                                   / (1 + np.abs(np.asarray(a)))))
                      for a, b in zip(jax.tree.leaves(ref), jax.tree.leaves(got)))
    print(json.dumps(res))
    """)
    for algo in ("daddpg", "single"):
        r = out[algo]
        assert r["moved"] > 1e-4, r          # the update did something
        assert r["state"] < 1e-5 and r["metrics"] < 1e-5 and r["state3"] < 1e-5, (algo, r)
        assert r["replicated"], r
    assert out["norm"] < 1e-5, out


@pytest.mark.e2e
def test_two_device_toy_training_learns_and_resumes(tmp_path):
    out = run_2dev(f"""
    from daddpg_jax.running import checkpoint as ckpt
    from daddpg_jax.algo.train import make_train_fns
    from tests import toy_env
    env = toy_env.make(**LEARN_ENV)
    res = {{}}
    try:
        make_train_fns(env, TINY.replace(num_envs=3))
    except ValueError as e:
        res["error"] = str(e)
    cfg = LEARN
    seen, stages = [], []
    class Hooks:
        def cycle(self, m):
            seen.append(int(m["cycle"]))
        def stage(self, stage):
            stages.append(int(stage))
    f = make_train_fns(env, cfg, hooks=Hooks())
    s = f.init()
    res["n_dev"] = f.num_devices
    res["buffer_sharded"] = str(s.buffer.data.obs.sharding.spec)
    rates = [float(f.evaluate(s)["success"])]
    finite = True
    run = {str(tmp_path / "run")!r}
    for epoch in range(6):
        s, m = f.train_epoch(s)
        finite &= not bool(np.any(m["nonfinite"])) and all(
            bool(np.all(np.isfinite(np.asarray(v)))) for v in jax.tree.leaves(m))
        rates.append(float(f.evaluate(s)["success"]))
        if epoch == 1:
            ckpt.save(run, s, step=2, save_buffer=True)
            s2_copy = jax.tree.map(jnp.copy, s)
    jax.effects_barrier()
    res.update(rates=rates, finite=finite, seen=len(seen), stages=stages[:4],
               n_stages=len(stages),
               buffer_episodes=int(m["buffer_episodes"][-1]),
               norm_count=float(s.obs_norm.count), updates=int(s.updates))
    # the pmean-ed updates keep every replicated value identical on both devices
    per_dev = [[np.asarray(x.addressable_shards[i].data) for x in jax.tree.leaves(s.agent)]
               for i in range(2)]
    res["agent_same_on_devices"] = tree_equal(per_dev[0], per_dev[1])
    # resume from the sharded checkpoint: same shardings, no recompile, same next epoch
    restored, step = ckpt.restore(run, f.init(jax.random.PRNGKey(9)))
    res["restored_sharding"] = str(restored.buffer.data.obs.sharding.spec)
    res["restored_equal"] = tree_equal(restored, s2_copy)
    a1, m1 = f.train_epoch(restored)
    a2, m2 = f.train_epoch(s2_copy)
    res["resume_equal"] = all(np.array_equal(np.asarray(m1[k]), np.asarray(m2[k])) for k in m1)
    res["cache"] = f.train_epoch._cache_size()
    print(json.dumps(res))
    """)
    assert "num_envs=3" in out["error"] and "divisible" in out["error"]
    assert out["n_dev"] == 2 and "dev" in out["buffer_sharded"]
    assert out["finite"]
    assert out["seen"] == 60                              # progress once per cycle, not per device
    assert out["stages"] == [0, 1, 0, 1]                  # timing marks: device 0's, in order
    assert out["n_stages"] == 2 * 60                      # two marks per cycle
    assert out["buffer_episodes"] == 4 * 60 and out["norm_count"] == 4 * 60 * 10
    assert out["updates"] == 6 * 10 * 20
    rates = out["rates"]
    # learns like the single-device run (tests/test_train.py::test_learns_toy_reach; measured
    # 2 devices: 0.0 ... 0.60, 0.97 after epochs 5, 6; 1 device: 0.77, 1.0)
    assert max(rates[-2:]) >= rates[0] + 0.5, rates
    assert out["agent_same_on_devices"]
    assert "dev" in out["restored_sharding"] and out["restored_equal"] and out["resume_equal"]
    assert out["cache"] == 1


@pytest.mark.e2e
def test_two_device_reach_c_engine_callback_per_shard():
    out = run_2dev("""
    import mjx_envs
    from daddpg_jax.algo.train import make_train_fns
    env = mjx_envs.make("reach", physics="c", episode_length=10)
    sizes, frozen = [], []
    host_step = env.backend._host_step
    def spy(time, *a):
        sizes.append(int(np.size(time)))
        out = host_step(time, *a)
        frozen.append(int(np.size(out[-1]) - np.sum(out[-1])))  # ok: 0.0 where frozen
        return out
    env.backend._host_step = spy
    cfg = TINY.replace(n_cycles=1, n_batches=2, buffer_size=400, n_test_episodes=4,
                       physics="c")
    f = make_train_fns(env, cfg)
    s, m = f.train_epoch(f.init())
    jax.block_until_ready(s)
    ev = f.evaluate(s)
    finite = bool(all(np.all(np.isfinite(np.asarray(v))) for v in jax.tree.leaves(m)))
    print(json.dumps(dict(n_dev=f.num_devices, sizes=sorted(set(sizes)), calls=len(sizes),
                          finite=finite, nonfinite=bool(np.any(m["nonfinite"])),
                          frozen=sum(frozen), buffer=int(m["buffer_episodes"][-1]),
                          success=float(ev["success"]))))
    """)
    assert out["n_dev"] == 2
    # training steps call the C engine once per device with its 2 envs (evaluation: 4 envs)
    assert 2 in out["sizes"] and out["calls"] >= 2 * 10, out
    assert out["finite"] and not out["nonfinite"] and out["frozen"] == 0
    assert out["buffer"] == 4


def test_accelerator_preset_keeps_ratio_and_epoch_size():
    from daddpg_jax.algo.config import REPLAY_RATIO, TrainConfig, preset, replay_ratio

    assert preset("reach") == preset("reach", device="cpu")          # CPU preset unchanged
    p = preset("push", device="gpu")
    assert p["num_envs"] == 4096 and p["physics"] == "mjx" and p["batch_size"] == 8192
    assert p["n_batches"] == 2560 and p["n_cycles"] == 5 and p["n_epochs"] == 40
    for task, steps in (("reach", 4e5), ("push", 1e6), ("pickup", 1e6), ("pot", 1e6)):
        for n in (256, 1024, 4096, 16384):
            q = preset(task, n, device="gpu")
            ratio = replay_ratio(q["n_batches"], q["batch_size"], n)
            assert REPLAY_RATIO <= ratio < REPLAY_RATIO * 1.1
            epoch = q["n_cycles"] * n * 50
            assert q["n_cycles"] == 1 or 0.5 * steps <= epoch <= 1.5 * steps, (task, n, q)
            TrainConfig(**q)
    with pytest.raises(ValueError):
        preset("reach", device="fpga")
    with pytest.raises(ValueError):
        TrainConfig(num_devices=-1)
