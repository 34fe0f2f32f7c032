"""The env's concerns as wrappers (mjx_envs/wrappers.py) and the observation pipeline shared
with the robot client (mjx_envs/pipeline.py). Default tier: no MJX; the traced reset below
costs ~3 s, everything else well under 1 s. The golden rollouts are e2e."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mjx_envs
from mjx_envs import perturb, pipeline, rules, wrappers
from mjx_envs.core import DualArmEnv
from mjx_envs.tasks import grasp_start
from tests import golden_wrapped


def _chain(env) -> list[str]:
    out = []
    while env is not env.unwrapped:
        out.append(type(env).__name__)
        env = env.env
    return out + [type(env).__name__]


def test_make_wraps_the_plain_env_in_the_concerns_its_config_turns_on():
    plain = mjx_envs.make("reach", physics="c")
    assert isinstance(plain, DualArmEnv) and plain is plain.unwrapped
    assert wrappers.find(plain, wrappers.Perturb) is None
    env = mjx_envs.make("push", physics="c", base_yaw=2.0, latency=1, action_history=2)
    assert _chain(env) == ["ActionHistory", "Perturb", "Randomize", "Push"]
    assert env.obs_size == 25 + 4 * 2 and env.unwrapped.obs_size == 25
    # attributes the wrappers lack are the plain env's
    assert env.rules is env.unwrapped.rules and env.config.latency == 1
    assert wrappers.find(env, wrappers.Perturb).perturbation.latency == 1
    assert env.backend.rand is wrappers.find(env, wrappers.Randomize).model_index
    only_obs = mjx_envs.make("push", physics="c", obs_noise=0.01)
    assert _chain(only_obs) == ["Perturb", "Push"]
    # Randomize acts on the physics: it wraps the plain env only
    with pytest.raises(ValueError, match="plain env"):
        wrappers.Randomize(only_obs, wrappers.randomize.Randomization(base_yaw=1.0))


def test_building_a_grasp_start_env_simulates_nothing(monkeypatch):
    """The grasped states are recorded when they are first needed (the first reset traced),
    not when the env is built."""
    recorded = []

    def fake_record(env_cls, config):
        recorded.append(env_cls.task_name)
        model = env_cls(config, physics="c").mj_model
        return grasp_start.GraspStates(qpos=np.zeros((2, model.nq), np.float32),
                                       qvel=np.zeros((2, model.nv), np.float32),
                                       mocap=np.zeros((2, 2, 3), np.float32), tries=2,
                                       seconds=0.0)

    monkeypatch.setattr(grasp_start, "_CACHE", {})
    monkeypatch.setattr(grasp_start, "_record", fake_record)
    env = mjx_envs.make("pickup", physics="c", grasp_start_fraction=0.5, n_grasp_states=2)
    assert recorded == []
    s = jax.eval_shape(env.reset, jax.random.PRNGKey(0))     # traced: now they are needed
    assert recorded == ["pickup"]
    assert s.data.qpos.shape == (env.mj_model.nq,)
    assert env.grasp_states.tries == 2 and recorded == ["pickup"]   # once


def test_observation_stages_are_the_same_over_numpy_and_jax():
    """The robot client's pipeline (NumPy) and the env wrappers' stages (jax.numpy): with the
    history outermost, the policy's chosen actions are remembered before the latency delays
    them; a held period remembers zeros and sends nothing."""
    p = perturb.Perturbation(latency=1, exact=True, has_object=False)
    a1, a2, a3 = (np.full(8, v, np.float32) for v in (0.5, -0.25, 2.0))   # a3 is clipped
    obs = np.zeros((2, 25), np.float32)
    out = {}
    for xp, sampler, key in ((np, rules.NumpySampler(), np.random.default_rng(0)),
                             (jnp, rules.JaxSampler(), jax.random.PRNGKey(0))):
        pipe = pipeline.Pipeline(pipeline.stages(xp, sampler, p, action_history=2))
        seen, c = pipe.start(key, obs)
        sent1, c = pipe.act(c, a1)
        sent2, c = pipe.act(c, a2)
        seen2, c = pipe.observe(c, obs)
        c = pipe.hold(c)
        seen3, c = pipe.observe(c, obs)
        sent3, c = pipe.act(c, a3)
        out[xp.__name__] = [np.asarray(x) for x in (seen, sent1, sent2, seen2, seen3, sent3)]
    for a, b in zip(out["numpy"], out["jax.numpy"], strict=True):
        np.testing.assert_array_equal(a, b)
    seen, sent1, sent2, seen2, seen3, sent3 = out["numpy"]
    assert seen.shape == (2, 33) and not seen.any()
    assert not sent1.any() and np.array_equal(sent2, a1) and np.array_equal(sent3, a2)
    np.testing.assert_array_equal(seen2[:, 25:], np.concatenate(
        [a2.reshape(2, 4), a1.reshape(2, 4)], -1))                 # newest first, per arm
    np.testing.assert_array_equal(seen3[:, 25:29], 0.0)             # the held period
    np.testing.assert_array_equal(seen3[:, 29:], a2.reshape(2, 4))
    assert not pipeline.Pipeline(pipeline.stages(np, None, None, 2)).perturbs


@pytest.mark.e2e
@pytest.mark.parametrize("case", golden_wrapped.CASES)
def test_wrapped_rollouts_match_the_golden_record(case):
    """Randomization, perturbations, action history and grasped starts on: the same state
    fields and values as the record (taken before the concerns became wrappers). Cost: ~10-30 s
    per case (C engine, one compile)."""
    want = np.load(golden_wrapped.RECORD)
    got = golden_wrapped.rollout(case)
    np.testing.assert_array_equal(got.pop("fields"), want[f"{case}/fields"])
    assert sorted(got) == sorted(k[len(case) + 1:] for k in want.files
                                 if k.startswith(f"{case}/") and k != f"{case}/fields")
    for k, v in got.items():
        # same tolerance as the golden epoch (tests/test_golden_epoch.py)
        np.testing.assert_allclose(v, want[f"{case}/{k}"], rtol=1e-6, atol=0, err_msg=k)
