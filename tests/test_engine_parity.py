"""The engine-parity measurement (experiments/engine_parity/parity.py): its C-engine harness
reproduces the C backend, its candidate edits change what they name; the table format.

Cost: C engine only, no MJX compile, ~10 s in all; except the `mjx`-tier statistical parity
test (one MJX program: ~60-90 s cold, ~25 s with JAX's persistent compilation cache).
"""

from __future__ import annotations

import copy

import jax
import mujoco
import numpy as np
import pytest

import mjx_envs
from experiments.engine_parity import parity as ep


def _run(env, keys, actions):
    r = ep.Runner(env, mjx_envs.make(env.task_name, physics="c"))
    obs, _, s = r.run(keys, actions)
    return obs, s


@pytest.mark.e2e  # ~7-15 s: kept out of the default tier's 5 minutes
def test_stateful_c_harness_reproduces_the_rollout_backend():
    """mj_step per env with the warmstart zeroed and float32 state = mujoco.rollout (the
    backend), bit for bit; carrying the warmstart changes the trajectory (~4 s)."""
    keys = ep.episode_keys(2)
    base = mjx_envs.make("pickup", physics="c")
    actions = ep.Runner(base, base).run(keys)[1][:6]
    ref, s_ref = _run(base, keys, actions)
    same, s = _run(ep.make_env("pickup", "c", ep.CANDIDATES["c_nows_f32"]), keys, actions)
    np.testing.assert_array_equal(same, ref)
    np.testing.assert_array_equal(np.asarray(s.data.qpos), np.asarray(s_ref.data.qpos))
    ws, _ = _run(ep.make_env("pickup", "c", ep.CANDIDATES["c_plain"]), keys, actions)
    assert np.abs(ws - ref).max() > 0.0


def test_candidate_edits_change_what_they_name():
    env = mjx_envs.make("pickup", physics="c")
    m0 = env.mj_model
    fingers = ep._pairs_with(m0, "finger")
    assert fingers.size == 12 and np.all(m0.pair_margin[fingers] == 0.0)  # physics version 2
    m0.pair_margin[fingers] = 0.005  # a copy of the env's model below must keep this
    m = copy.copy(m0)
    ep.CANDIDATES["finger_inflate"].edit(m)
    g = ep._finger_geoms(m)
    assert g.size == 4
    np.testing.assert_allclose(m.geom_size[g] - m0.geom_size[g], 0.005)
    assert np.all(m.pair_margin[fingers] == 0.0)
    others = np.setdiff1d(np.arange(m.ngeom), g)
    np.testing.assert_array_equal(m.geom_size[others], m0.geom_size[others])
    m = copy.copy(m0)
    ep.CANDIDATES["pyramidal"].edit(m)
    assert m.opt.cone == mujoco.mjtCone.mjCONE_PYRAMIDAL
    assert m0.opt.cone == mujoco.mjtCone.mjCONE_ELLIPTIC  # the env's model is untouched
    assert np.all(m0.pair_margin[fingers] == 0.005)


def test_combined_candidates_share_engine_sides():
    c = ep.candidate("finger_inflate+c_plain")
    assert c.side("mjx") == ep.CANDIDATES["finger_inflate"].side("mjx")
    assert c.side("c") == "finger_inflate/ws_f64"
    assert ep.candidate("c_warmstart").side("mjx") == ep.CANDIDATES["baseline"].side("mjx")
    with pytest.raises(KeyError):
        ep.candidate("finger_inflate+nope")


def test_episode_keys_start_with_the_parity_tests_episodes():
    k = np.asarray(ep.episode_keys(5))
    np.testing.assert_array_equal(k[:2], np.asarray(jax.random.split(jax.random.PRNGKey(7), 2)))
    assert len({tuple(x) for x in k}) == 5
    assert np.asarray(ep.episode_keys(1)).shape[0] == 1


def test_format_table_lists_each_candidate_once():
    rows = [dict(task="pickup", candidate=c, episodes=4, div_test_mm=17.0, div_mean_mm=12.0,
                 c=dict(success=1.0), mjx=dict(success=0.5)) for c in ("margin0", "baseline")]
    text = ep.format_table(rows)
    lines = text.splitlines()
    assert lines[2].startswith("| baseline |") and lines[3].startswith("| margin0 |")
    assert "17 / 12" in text and "1.00 / 0.50" in text


def test_cli_rejects_unknown_names(capsys):
    with pytest.raises(SystemExit) as e:
        ep.main(["--tasks", "pickup", "--candidates", "nope"])
    assert e.value.code == 2
    assert "nope" in capsys.readouterr().err


@pytest.mark.mjx
def test_scripted_pot_succeeds_alike_on_both_engines():
    """The scripted controller over the same 8 pot episodes (the task where physics version 1
    parted: 5/8 on MJX against 8/8 on C in these episodes) succeeds alike on both engines, and
    the object parts by less than the parity tolerance in the first 10 open-loop steps.
    Cost: one MJX compile (pot, batch 8), ~60-90 s cold."""
    row = ep.measure("pot", ep.CANDIDATES["baseline"], episodes=8, log=lambda *a: None)
    assert row["c"]["successes"] >= 7 and row["mjx"]["successes"] >= 7, row
    assert abs(row["c"]["successes"] - row["mjx"]["successes"]) <= 1, row
    assert row["mjx"]["physics_ok"] == 1.0
    assert row["div_test_mm"] < 15.0 and row["div_mean_mm"] < 15.0, row


def _comparison(seed, both, c_only, mjx_only, neither, run="/runs/x/run", step=7):
    return dict(run_dir=run, checkpoint=step, seed=seed,
                difference=dict(engines=["c", "mjx"], paired=dict(
                    both=both, first_only=c_only, second_only=mjx_only, neither=neither)))


def test_pooled_sums_disjoint_episode_sets_and_refuses_overlaps():
    """experiments/engine_parity/pooled.py: counts add up, the interval is Newcombe's over the
    sums; a repeated seed or another checkpoint is refused (pure Python, ~0.1 s)."""
    from daddpg_jax.analysis.engines import newcombe_paired_interval
    from experiments.engine_parity import pooled

    a, b = _comparison(9090, 91, 59, 47, 103), _comparison(9191, 178, 117, 110, 195)
    s = pooled.summary([a, b])
    assert s["counts"] == dict(both=269, first_only=176, second_only=157, neither=298)
    assert s["episodes"] == 900
    assert s["difference"] == pytest.approx((176 - 157) / 900)
    assert s["ci95"] == pytest.approx(list(newcombe_paired_interval(269, 176, 157, 298)))
    with pytest.raises(ValueError, match="overlap"):
        pooled.summary([a, _comparison(9090, 1, 1, 1, 1)])
    with pytest.raises(ValueError, match="checkpoint"):
        pooled.summary([a, _comparison(9191, 1, 1, 1, 1, step=8)])
    with pytest.raises(ValueError, match="checkpoint"):
        pooled.summary([a, _comparison(9191, 1, 1, 1, 1, run="/runs/y/run")])


def test_null_pass_falls_with_discordance_and_rises_with_episodes():
    """The bar's pass chance without a lean: 1 when no episode is solved by one engine only,
    lower the more episodes split, higher for the same rates on three times the episodes;
    a probability in every case (pure Python, ~0.2 s)."""
    from experiments.engine_parity import pooled

    none = dict(both=150, first_only=0, second_only=0, neither=150)
    assert pooled.null_pass(none) == pytest.approx(1.0)
    few = pooled.null_pass(dict(both=200, first_only=20, second_only=20, neither=60))
    many = pooled.null_pass(dict(both=100, first_only=60, second_only=60, neither=80))
    many_x3 = pooled.null_pass(dict(both=300, first_only=180, second_only=180, neither=240))
    assert 0.0 <= many < few <= 1.0
    assert many < many_x3 <= 1.0
