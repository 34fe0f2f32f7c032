"""What the engine probes share: edits of a compiled model's options and grasp pairs, the
scripted controller's grasped states set into C and MJX data, and a trained policy evaluated
on both engines with an edit (paired outcomes, Newcombe interval of the difference)."""

from __future__ import annotations

import time

import mujoco
import numpy as np

from experiments.engine_parity import parity as ep
from mjx_envs import model as model_lib
from mjx_envs import registry

GRASP = ("pot_handle", "neck")
"""substrings of the object geoms the fingers grasp (pot handles, bar necks)"""
STATE_KEYS = ("qpos", "qvel", "mocap", "ctrl")


def pair_ids(m: mujoco.MjModel, words=GRASP, min_friction: float | None = 1.0,
             finger: bool = False) -> list:
    """Pairs with a geom whose name contains one of `words` (friction above `min_friction`
    when given; with `finger`, the other geom must be a finger box)."""
    out = []
    for i in range(m.npair):
        names = {m.geom(int(m.pair_geom1[i])).name, m.geom(int(m.pair_geom2[i])).name}
        if not any(w in n for w in words for n in names):
            continue
        if min_friction is not None and not m.pair_friction[i][0] > min_friction:
            continue
        if finger and not any(n.removesuffix("_mesh").endswith(("finger1", "finger2"))
                              for n in names):
            continue
        out.append(i)
    return out


def pair_fields(words=GRASP, min_friction=1.0, finger=False, **fields):
    """Edit: set pair_<field>[:len(value)] on the selected pairs."""
    def edit(m):
        for i in pair_ids(m, words, min_friction, finger):
            for k, v in fields.items():
                getattr(m, f"pair_{k}")[i][:len(v)] = v
    return edit


def pair_dim(n: int, torsion: float | None = None, words=GRASP):
    """Edit: condim `n` on the grasp pairs (and the torsional friction when given)."""
    def edit(m):
        for i in pair_ids(m, words):
            m.pair_dim[i] = n
            if torsion is not None:
                m.pair_friction[i][2] = torsion
    return edit


def options(**opts):
    """Edit: set m.opt.<name> = value."""
    def edit(m):
        for k, v in opts.items():
            setattr(m.opt, k, v)
    return edit


def mjx_ls_iterations(n: int):
    """Edit: MJX's Newton line search runs up to `n` iterations (the numeric
    ``mjx_envs.model.MJX_LS_ITERATIONS`` of versions 6 and later, which ``mjx_model`` reads);
    the C engine keeps the model's own ``opt.ls_iterations``. ValueError on an older model."""
    def edit(m):
        for i in range(m.nnumeric):
            if m.numeric(i).name == model_lib.MJX_LS_ITERATIONS:
                m.numeric_data[m.numeric_adr[i]] = float(n)
                return
        raise ValueError(f"the model has no numeric {model_lib.MJX_LS_ITERATIONS!r} "
                         "(physics versions 6 and later)")
    return edit


def chain(*edits):
    """Edit: the edits in order."""
    def edit(m):
        for e in edits:
            e(m)
    return edit


def sample_states(task: str, n: int, episodes: int = 8, dtype=None, **overrides) -> dict:
    """`n` of the scripted controller's grasped states on the C engine (the env's config
    `overrides`, e.g. its physics version), evenly spaced."""
    st = ep.grasp_states(task, episodes=episodes, **overrides)
    idx = np.linspace(0, st["qpos"].shape[0] - 1, n).astype(int)
    return {k: (v[idx] if dtype is None else v[idx].astype(dtype)) for k, v in st.items()}


def set_c_state(m, d, st: dict, i: int, xfrc=None):
    """C data `d` at state `i` of `st` (and the applied forces), forward computed."""
    mujoco.mj_resetData(m, d)
    d.qpos[:], d.qvel[:] = st["qpos"][i], st["qvel"][i]
    d.mocap_pos[:2], d.ctrl[:] = st["mocap"][i], st["ctrl"][i]
    if xfrc is not None:
        d.xfrc_applied[:] = xfrc
    mujoco.mj_forward(m, d)


def mjx_state(d0, q, v, mocap, ctrl, xfrc=None):
    """MJX data `d0` at one state (and the applied forces)."""
    dd = d0.replace(qpos=q, qvel=v, mocap_pos=d0.mocap_pos.at[:2].set(mocap), ctrl=ctrl)
    return dd if xfrc is None else dd.replace(xfrc_applied=xfrc)


def down_force(m, task: str, load: float) -> tuple[int, np.ndarray]:
    """(object body, xfrc_applied pulling it down with `load` x its weight)."""
    body = m.body(registry.OBJECTS[task][1]).id
    f = np.zeros((m.nbody, 6))
    f[body, 2] = -load * float(m.body_subtreemass[body]) * 9.81
    return body, f


def evaluate_engines(run: str, edit=None, engines=("c", "mjx"), episodes=320, seed=2024,
                     label="", step: int | None = None) -> dict:
    """{engine: success per episode} of RUN's best checkpoint (or checkpoint `step`) with `edit`
    applied to each engine's model (MJX: the edited model is put again)."""
    from daddpg_jax.analysis import evaluation
    from mjx_envs.physics.backends import import_mjx

    res = {}
    for eng in engines:
        t0 = time.time()
        pol = evaluation.load_policy(run, step=step, best=step is None, physics=eng)
        if edit is not None:
            edit(pol.env.mj_model)
            if eng == "mjx":
                mjx = import_mjx()
                pol.env.backend.model = mjx.put_model(model_lib.mjx_model(pol.env.mj_model))
                pol.env.backend._data0 = mjx.make_data(pol.env.backend.model)
        _, tr = evaluation.evaluate(pol, episodes=episodes, seed=seed)
        res[eng] = tr["success"].astype(bool)
        print(label, eng, "pairs", pol.env.mj_model.npair, float(res[eng].mean()),
              f"{time.time() - t0:.0f}s", flush=True)
    return res


def paired(res: dict) -> dict:
    """Both engines' success rates, the paired counts and the Newcombe 95% interval of the
    difference (C - MJX); one engine: its success rate."""
    if set(res) != {"c", "mjx"}:
        return {eng: float(s.mean()) for eng, s in res.items()}
    from daddpg_jax.analysis import engines

    c, mj = res["c"], res["mjx"]
    both, c_only, m_only = int((c & mj).sum()), int((c & ~mj).sum()), int((mj & ~c).sum())
    return dict(c=float(c.mean()), mjx=float(mj.mean()), both=both, c_only=c_only,
                mjx_only=m_only, difference=float(c.mean() - mj.mean()),
                ci95=engines.newcombe_paired_interval(both, c_only, m_only,
                                                      len(c) - both - c_only - m_only))
