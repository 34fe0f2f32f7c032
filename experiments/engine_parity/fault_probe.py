"""Where MJX physics faults come from (#48 item 3): play a run's checkpoint on MJX, keep the
frozen state of every env that faulted (the backend freezes an env at the data it had before
the control step whose result turned non-finite: ctrl and mocap already set), then replay
that control step substep by substep and report the first substep whose forward pass or
integration turns non-finite, and which fields did first.

    python experiments/engine_parity/fault_probe.py RUN --episodes 96 --seed 9090 --out DIR
    python experiments/engine_parity/fault_probe.py --replay DIR/faults.pkl

Run it alone on a CPU (MJX, chunks of 32)."""

from __future__ import annotations

import argparse
import json
import os
import pickle
import sys

import jax
import jax.numpy as jnp
import numpy as np

from daddpg_jax.algo import acting
from daddpg_jax.analysis import evaluation

FIELDS = ("qpos", "qvel", "qacc", "qacc_warmstart", "qfrc_constraint", "efc_force", "efc_J",
          "efc_aref", "efc_D", "xpos", "xmat", "cinert", "qM")
CONTACT_FIELDS = ("dist", "pos", "frame", "solref", "solimp", "friction")


def collect(run: str, episodes: int, seed: int, chunk: int, best: bool = True) -> list:
    """The frozen MJX data of every faulted episode (a list of dicts of NumPy arrays)."""
    policy = evaluation.load_policy(run, best=best, physics="mjx")
    env, act = policy.env, policy.act

    def actors(s, _):
        return act(policy.params, s.obs["observation"], s.obs["desired_goal"])

    @jax.jit
    def play(keys):
        s0 = acting.reset(env, keys)
        final, _ = acting.unroll(env, s0, actors, int(env.episode_length),
                                 record=lambda s, a, s2: s2.metrics["success"])
        return final.data, env.backend.ok(final.data)

    keys = np.asarray(acting.episode_keys(jax.random.PRNGKey(seed), episodes))
    out = []
    for lo in range(0, episodes, chunk):
        data, ok = jax.device_get(play(keys[lo:lo + chunk]))
        for i in np.flatnonzero(np.asarray(ok) < 0.5):
            d = jax.tree.map(lambda x, i=i: np.asarray(x)[i], data)
            out.append(dict(episode=lo + int(i), data=d))
        print(f"episodes {lo}-{lo + chunk - 1}: {int((np.asarray(ok) < 0.5).sum())} faulted",
              flush=True)
    return out, policy


def _bad(x) -> bool:
    return x is not None and np.size(x) > 0 and not np.all(np.isfinite(np.asarray(x)))


def replay(policy, faults: list) -> list:
    """For each frozen state: step its substeps one at a time; report the first bad one."""
    from mujoco import mjx

    be = policy.env.backend
    model = be.model
    fwd = jax.jit(mjx.forward)
    stp = jax.jit(mjx.step)
    reports = []
    for f in faults:
        d = jax.tree.map(lambda x: x, f["data"])
        d = jax.tree.map(jnp.asarray, d)
        d = d.replace(time=jnp.zeros_like(d.time))
        rep = dict(episode=f["episode"], substep=None)
        for k in range(be.n_substeps):
            dd = fwd(model, d)
            bad = [n for n in FIELDS if _bad(getattr(dd, n, None))]
            cbad = [n for n in CONTACT_FIELDS if _bad(getattr(dd.contact, n, None))]
            if bad or cbad:
                rep.update(substep=k, stage="forward", fields=bad, contact_fields=cbad)
                rep.update(_contact_detail(policy, dd))
                break
            nxt = stp(model, d)
            if _bad(nxt.qpos) or _bad(nxt.qvel):
                rep.update(substep=k, stage="integrate",
                           fields=[n for n in FIELDS if _bad(getattr(nxt, n, None))])
                rep.update(_state_detail(policy, d, dd))
                break
            d = nxt
        reports.append(rep)
        print(json.dumps(rep, default=str), flush=True)
    return reports


def _contact_detail(policy, dd) -> dict:
    m = policy.env.backend.mj_model
    c = dd.contact
    bad = ~np.all(np.isfinite(np.asarray(c.frame).reshape(len(c.dist), -1)), 1) | \
        ~np.isfinite(np.asarray(c.dist))
    pairs = []
    for i in np.flatnonzero(bad)[:8]:
        g1, g2 = (int(x) for x in np.asarray(c.geom)[i])
        pairs.append((m.geom(g1).name, m.geom(g2).name, float(np.asarray(c.dist)[i])))
    return dict(bad_contacts=int(bad.sum()), bad_pairs=pairs)


def _state_detail(policy, d, dd) -> dict:
    qacc = np.asarray(dd.qacc)
    qvel = np.asarray(d.qvel)
    m = policy.env.backend.mj_model
    top = np.argsort(-np.abs(qacc))[:4]
    active = np.asarray(dd.contact.dist) < 0
    return dict(max_qacc=float(np.abs(qacc).max()), max_qvel=float(np.abs(qvel).max()),
                top_dofs=[(int(j), m.joint(int(m.dof_jntid[j])).name, float(qacc[j]))
                          for j in top],
                max_efc_force=float(np.abs(np.asarray(dd.efc_force)).max()),
                penetrating_contacts=int(active.sum()),
                deepest=float(np.asarray(dd.contact.dist).min()))


def newton_trace(policy, data) -> list:
    """The Newton solver of one frozen state's first substep, iteration by iteration (MJX's own
    functions, unjitted): per iteration the cost, whether the cone Hessian, the full Hessian's
    Cholesky factor and the search direction are finite, and the Hessian's smallest eigenvalue
    (float64 of the float32 matrix)."""
    from mujoco.mjx._src import forward as mfwd
    from mujoco.mjx._src import sensor, solver, support

    m = policy.env.backend.model
    d = jax.tree.map(jnp.asarray, data)
    d = d.replace(time=jnp.zeros_like(d.time))
    for f in (mfwd.fwd_position, sensor.sensor_pos, mfwd.fwd_velocity, sensor.sensor_vel,
              mfwd.fwd_actuation, mfwd.fwd_acceleration):
        d = f(m, d)
    warm = solver.Context.create(m, d.replace(qacc=d.qacc_warmstart), grad=False)
    smth = solver.Context.create(m, d.replace(qacc=d.qacc_smooth), grad=False)
    d = d.replace(qacc=jnp.where(warm.cost < smth.cost, d.qacc_warmstart, d.qacc_smooth))
    ctx = solver.Context.create(m, d)
    rows = []
    impl = d._impl
    for it in range(int(m.opt.iterations)):
        ctx = solver._linesearch(m, d, ctx)
        ctx = solver._update_constraint(m, d, ctx)
        # the Hessian as _update_gradient assembles it
        cm = jnp.diag(impl.efc_D * ctx.active)
        adr = impl.contact.efc_address[impl.contact.dim > 1]
        dim = impl.contact.dim[impl.contact.dim > 1]
        for i, (cd, a) in enumerate(zip(dim, adr)):
            cm = cm.at[a:a + cd, a:a + cd].add(ctx.h[i, :cd, :cd])
        h = support.full_m(m, d) + impl.efc_J.T @ cm @ impl.efc_J
        hs = np.asarray((h + h.T) * 0.5, np.float64)
        ctx = solver._update_gradient(m, d, ctx)
        eig = np.linalg.eigvalsh(hs) if np.all(np.isfinite(hs)) else [np.nan]
        rows.append(dict(iteration=it, cost=float(ctx.cost), qacc_finite=bool(
            np.all(np.isfinite(np.asarray(ctx.qacc)))), cone_h_finite=bool(
            np.all(np.isfinite(np.asarray(ctx.h)))), hessian_min_eig=float(np.min(eig)),
            hessian_max_eig=float(np.max(eig)), mgrad_finite=bool(
            np.all(np.isfinite(np.asarray(ctx.Mgrad))))))
        print(json.dumps(rows[-1]), flush=True)
        if not rows[-1]["mgrad_finite"] or not rows[-1]["qacc_finite"]:
            break
        ctx = ctx.replace(search=-ctx.Mgrad, solver_niter=ctx.solver_niter + 1)
    return rows


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("run", nargs="?")
    p.add_argument("--episodes", type=int, default=96)
    p.add_argument("--seed", type=int, default=9090)
    p.add_argument("--chunk", type=int, default=32)
    p.add_argument("--out", default=None)
    p.add_argument("--replay", default=None, help="a faults.pkl written by an earlier run")
    p.add_argument("--newton", action="store_true",
                   help="with --replay: trace the Newton solver of each fault's first substep")
    a = p.parse_args(argv)
    if a.replay:
        with open(a.replay, "rb") as fh:
            saved = pickle.load(fh)
        policy = evaluation.load_policy(saved["run"], best=True, physics="mjx")
        faults = saved["faults"]
        if a.newton:
            for f in faults:
                print(f"episode {f['episode']}", flush=True)
                newton_trace(policy, f["data"])
            return 0
    else:
        faults, policy = collect(a.run, a.episodes, a.seed, a.chunk)
        if a.out:
            os.makedirs(a.out, exist_ok=True)
            with open(os.path.join(a.out, "faults.pkl"), "wb") as fh:
                pickle.dump(dict(run=a.run, faults=faults), fh)
    print(f"{len(faults)} faulted episodes", flush=True)
    reports = replay(policy, faults)
    if a.out:
        with open(os.path.join(a.out, "replay.json"), "w") as fh:
            json.dump(reports, fh, indent=1, default=str)
    return 0


if __name__ == "__main__":
    sys.exit(main())
