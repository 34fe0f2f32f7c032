"""Hold test (python hold.py TASK OUT.json CAND...; LOADS=3,6 in the environment picks the loads): at the C engine's grasped states (scripted controller, both grippers holding), keep
the targets and finger commands fixed, pull the object down with L x its weight, and simulate
T control steps on both engines. Reports the object's drop (mm) per engine and the fraction of
states where it fell > 20 mm.  python hold.py TASK OUT.json CAND [CAND...]"""
import copy, json, os, sys, time
import jax, jax.numpy as jnp, mujoco, numpy as np
HERE = "/work/main/docs/results/engines/grasp_hold"
sys.path[:0] = [HERE, os.path.join(HERE, "..", "finger_pads")]
import mjx_envs
from mjx_envs import registry, settings
from mjx_envs.physics import backends
from daddpg_jax.analysis import engine_parity as ep

TASK, OUT = sys.argv[1], sys.argv[2]
LOADS = tuple(float(x) for x in os.environ.get("LOADS", "0,3,8").split(","))
T, N, CH = 20, 64, 32
GRASP = ("pot_handle", "neck")

def soft(**f):
    def edit(m):
        for i in range(m.npair):
            names = {m.geom(int(m.pair_geom1[i])).name, m.geom(int(m.pair_geom2[i])).name}
            if any(any(s in n for s in GRASP) for n in names) and m.pair_friction[i][0] > 1.0:
                for k, v in f.items():
                    getattr(m, f"pair_{k}")[i][:len(v)] = v
    return edit

def opt(**o):
    def edit(m):
        for k, v in o.items():
            setattr(m.opt, k, v)
    return edit

def both(*es):
    def edit(m):
        for e in es:
            e(m)
    return edit

def condim(n, tors=None):
    def edit(m):
        for i in range(m.npair):
            names = {m.geom(int(m.pair_geom1[i])).name, m.geom(int(m.pair_geom2[i])).name}
            if any(any(s in nm for s in GRASP) for nm in names) and m.pair_friction[i][0] > 1.0:
                m.pair_dim[i] = n
                if tors is not None:
                    m.pair_friction[i][2] = tors
    return edit

CANDS = {"condim4": condim(4), "condim4_t02": condim(4, 0.02), "condim6": condim(6), "dense": "dense", "meshf": "meshf", "meshf_noccd": "meshf_noccd", "solimp_hard": soft(solimp=(0.99, 0.999, 0.001)), "impratio_5": opt(impratio=5.0),
         "solref_001": soft(solref=(0.01, 1.0)), "impratio_5_hard": both(opt(impratio=5.0), soft(solimp=(0.99, 0.999, 0.001))),
         "caps": "caps", "caps3": "caps3", "baseline": None, "solimp_soft": soft(solimp=(0.9, 0.95, 0.001)),
         "solref_004": soft(solref=(0.04, 1.0)), "pads": "pads", "iters50": opt(iterations=50, ls_iterations=50, tolerance=1e-10), "iters4": opt(iterations=4, ls_iterations=4), "pyramidal": opt(cone=0), "pyr_imp5": opt(cone=0, impratio=5.0), "pyr_fric3": both(opt(cone=0), soft(friction=(3.0, 3.0)))}

env = mjx_envs.make(TASK, physics="c")
n_sub = env.config.n_substeps
st = ep.grasp_states(TASK)
idx = np.linspace(0, st["qpos"].shape[0] - 1, N).astype(int)
st = {k: v[idx].astype(np.float64 if os.environ.get("JAX_ENABLE_X64") else np.float32) for k, v in st.items()}
out = json.load(open(OUT)) if os.path.exists(OUT) else {}
mjx = backends.import_mjx()
if os.environ.get('UNIQ'):
    import uniq; uniq.install()

def model_for(name):
    c = CANDS[name]
    if c in ("meshf", "meshf_noccd"):
        import meshf
        m = meshf.load_model(f"scene_{TASK}.xml", multiccd=(c == "meshf"))
        m.opt.timestep, m.opt.cone = env.mj_model.opt.timestep, env.mj_model.opt.cone
        return m
    if c in ("caps", "caps3"):
        import caps
        caps.OPTS.update(r=0.006, xs=(-0.011, 0.011) if c == "caps" else (-0.011, 0.0, 0.011), zc=0.035, half=0.032)
        m = caps.load_model(f"scene_{TASK}.xml")
        m.opt.timestep, m.opt.cone = env.mj_model.opt.timestep, env.mj_model.opt.cone
        return m
    if c in ("pads", "dense"):
        import spheres
        if c == "dense":
            spheres.OPTS.update(r=0.004, xs=(-0.012, -0.004, 0.004, 0.012),
                                zs=tuple(0.001 + 0.008 * k for k in range(9)))
            m = spheres.load_model(f"scene_{TASK}.xml")
            m.opt.timestep, m.opt.cone = env.mj_model.opt.timestep, env.mj_model.opt.cone
            return m
        import spheres
        spheres.OPTS.update(r=0.006, xs=(-0.01, 0.01), zs=(0.005, 0.025, 0.045, 0.065))
        m = spheres.load_model(f"scene_{TASK}.xml")
        m.opt.timestep, m.opt.cone = env.mj_model.opt.timestep, env.mj_model.opt.cone
        return m
    m = copy.copy(env.mj_model)
    if c is not None:
        c(m)
    return m

for name in sys.argv[3:]:
    m = model_for(name)
    body = m.body(registry.OBJECTS[TASK][1]).id
    mass = float(m.body_subtreemass[body])
    row = {}
    for L in LOADS:
        f = np.zeros((m.nbody, 6)); f[body, 2] = -L * mass * 9.81
        # C engine
        d = mujoco.MjData(m); drop_c = np.empty(N)
        for i in range(N):
            mujoco.mj_resetData(m, d)
            d.qpos[:], d.qvel[:] = st["qpos"][i], st["qvel"][i]
            d.mocap_pos[:2] = st["mocap"][i]; d.ctrl[:] = st["ctrl"][i]; d.xfrc_applied[:] = f
            mujoco.mj_forward(m, d); z0 = d.xpos[body].copy()
            for _ in range(T * n_sub):
                mujoco.mj_step(m, d)
            drop_c[i] = 1000 * (z0[2] - d.xpos[body][2])
        # MJX
        mm = mjx.put_model(m); d0 = mjx.make_data(mm)
        @jax.jit
        def run(q, v, mc, c):
            def one(q, v, mc, c):
                dd = d0.replace(qpos=q, qvel=v, mocap_pos=d0.mocap_pos.at[:2].set(mc), ctrl=c,
                                xfrc_applied=jnp.asarray(f, d0.qpos.dtype))
                dd = mjx.forward(mm, dd); z0 = dd.xpos[body, 2]
                dd = jax.lax.fori_loop(0, T * n_sub, lambda _, x: mjx.step(mm, x), dd)
                return 1000 * (z0 - dd.xpos[body, 2])
            return jax.vmap(one)(q, v, mc, c)
        t0 = time.time(); dm = []
        for a in range(0, N, CH):
            dm.append(np.asarray(jax.device_get(run(*[st[k][a:a + CH] for k in ("qpos", "qvel", "mocap", "ctrl")]))))
        drop_m = np.concatenate(dm)
        row[str(L)] = dict(c_mean=float(np.nanmean(drop_c)), mjx_mean=float(np.nanmean(drop_m)),
                           c_fell=float((drop_c > 20).mean()), mjx_fell=float((drop_m > 20).mean()),
                           absdiff_mean=float(np.nanmean(np.abs(drop_c - drop_m))))
        print(TASK, name, L, row[str(L)], f"{time.time()-t0:.0f}s", flush=True)
    out[name] = row
    json.dump(out, open(OUT, "w"), indent=1)
