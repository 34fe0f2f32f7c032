"""Hold test: at the C engine's grasped states (scripted controller, both grippers holding),
keep the targets and finger commands fixed, pull the object down with L x its weight and
simulate T control steps on both engines. Reports per load the object's drop (mm) per engine,
the fraction of states where it fell > 20 mm and the mean absolute difference of the drops.

    python experiments/engine_parity/hold.py TASK OUT.json CAND [CAND ...]

Environment: LOADS (comma list, default 0,3,8), UNIQ=1 (MJX with the unique-points prototype,
unique_points.py), JAX_ENABLE_X64=1 (float64 MJX), PHYSICS_VERSION (the scenes' version,
default the current one; MJX simulates ``mjx_envs.model.mjx_model`` of each model, as the env
does). Candidates: model edits of the grasp pairs and solver options, or finger pads (pads.py;
``meshf_mjxbox`` / ``meshneck_mjxbox``: box-shaped meshes that MJX collides as boxes,
mjx_envs/physics/mjx_contacts.py). Outputs:
docs/results/engines/grasp_hold/hold_*.json, docs/results/engines/unique_points/h_*.json and
docs/results/engines/manifold_search/hold_*.json (docs/MJX_VS_C.md).
"""

from __future__ import annotations

import copy
import json
import os
import sys
import time

if __package__ in (None, ""):  # run as a file: the repository root holds `experiments`
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import mujoco  # noqa: E402
import numpy as np  # noqa: E402

import mjx_envs  # noqa: E402
from experiments.engine_parity import pads  # noqa: E402
from experiments.engine_parity import probe_tools as pt  # noqa: E402
from mjx_envs import model as model_lib  # noqa: E402
from mjx_envs.physics import backends  # noqa: E402

T, N, CH = 20, 64, 32   # control steps held, states, MJX batch
HARD = dict(solimp=(0.99, 0.999, 0.001))
CANDIDATES = {
    "baseline": None,
    "solimp_hard": pt.pair_fields(**HARD),
    "solimp_soft": pt.pair_fields(solimp=(0.9, 0.95, 0.001)),
    "solref_001": pt.pair_fields(solref=(0.01, 1.0)),
    "solref_004": pt.pair_fields(solref=(0.04, 1.0)),
    "impratio_5": pt.options(impratio=5.0),
    "impratio_5_hard": pt.chain(pt.options(impratio=5.0), pt.pair_fields(**HARD)),
    "condim4": pt.pair_dim(4),
    "condim4_t02": pt.pair_dim(4, 0.02),
    "condim6": pt.pair_dim(6),
    "iters50": pt.options(iterations=50, ls_iterations=50, tolerance=1e-10),
    "iters4": pt.options(iterations=4, ls_iterations=4),
    "mjx_ls50": pt.mjx_ls_iterations(50),   # versions 6+: MJX's line search as the C engine's
    "pyramidal": pt.options(cone=0),
    "pyr_imp5": pt.options(cone=0, impratio=5.0),
    "pyr_fric3": pt.chain(pt.options(cone=0), pt.pair_fields(friction=(3.0, 3.0))),
}
PAD_CANDIDATES = {"pads": "spheres", "dense": "dense", "caps": "caps", "caps3": "caps3",
                  "meshf": "meshf", "meshf_noccd": "meshf_noccd", "meshneck": "meshneck",
                  "meshneck_noccd": "meshneck_noccd", "meshf_mjxbox": "meshf_mjxbox",
                  "meshneck_mjxbox": "meshneck_mjxbox"}


def model_for(task: str, name: str, ref: mujoco.MjModel) -> mujoco.MjModel:
    if name in PAD_CANDIDATES:
        return pads.like(PAD_CANDIDATES[name], f"scene_{task}.xml", ref)
    m = copy.copy(ref)
    if CANDIDATES[name] is not None:
        CANDIDATES[name](m)
    return m


def drops_c(m, st, body, f, steps) -> np.ndarray:
    d, out = mujoco.MjData(m), np.empty(N)
    for i in range(N):
        pt.set_c_state(m, d, st, i, f)
        z0 = d.xpos[body][2]
        for _ in range(steps):
            mujoco.mj_step(m, d)
        out[i] = 1000 * (z0 - d.xpos[body][2])
    return out


def drops_mjx(m, st, body, f, steps) -> np.ndarray:
    mjx = backends.import_mjx()
    mm = mjx.put_model(model_lib.mjx_model(m))
    d0 = mjx.make_data(mm)

    @jax.jit
    def run(q, v, mc, c):
        def one(q, v, mc, c):
            dd = mjx.forward(mm, pt.mjx_state(d0, q, v, mc, c, jnp.asarray(f, d0.qpos.dtype)))
            z0 = dd.xpos[body, 2]
            dd = jax.lax.fori_loop(0, steps, lambda _, x: mjx.step(mm, x), dd)
            return 1000 * (z0 - dd.xpos[body, 2])
        return jax.vmap(one)(q, v, mc, c)

    return np.concatenate([np.asarray(jax.device_get(run(*[st[k][a:a + CH]
                                                           for k in pt.STATE_KEYS])))
                           for a in range(0, N, CH)])


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) < 3 or any(c not in CANDIDATES and c not in PAD_CANDIDATES for c in argv[2:]):
        print(__doc__ + "\ncandidates: " + ", ".join([*CANDIDATES, *PAD_CANDIDATES]))
        return 2
    task, out_path = argv[0], argv[1]
    loads = tuple(float(x) for x in os.environ.get("LOADS", "0,3,8").split(","))
    version = os.environ.get("PHYSICS_VERSION")
    overrides = {} if version is None else dict(physics_version=int(version))
    env = mjx_envs.make(task, physics="c", **overrides)
    steps = T * env.config.n_substeps
    st = pt.sample_states(task, N, dtype=np.float64 if os.environ.get("JAX_ENABLE_X64")
                          else np.float32, **overrides)
    out = json.load(open(out_path)) if os.path.exists(out_path) else {}
    backends.import_mjx()   # also routes box-shaped meshes for models with the numeric (*_mjxbox)
    if os.environ.get("UNIQ"):
        from experiments.engine_parity import unique_points
        unique_points.install()
    for name in argv[2:]:
        m = model_for(task, name, env.mj_model)
        row = {}
        for load in loads:
            body, f = pt.down_force(m, task, load)
            t0 = time.time()
            dc, dm = drops_c(m, st, body, f, steps), drops_mjx(m, st, body, f, steps)
            row[str(load)] = dict(c_mean=float(np.nanmean(dc)), mjx_mean=float(np.nanmean(dm)),
                                  c_fell=float((dc > 20).mean()), mjx_fell=float((dm > 20).mean()),
                                  absdiff_mean=float(np.nanmean(np.abs(dc - dm))))
            print(task, name, load, row[str(load)], f"{time.time() - t0:.0f}s", flush=True)
        out[name] = row
        with open(out_path, "w") as fh:
            json.dump(out, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
