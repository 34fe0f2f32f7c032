"""Contact points of one static finger-neck pair on each engine, per collision set-up and tilt.

A pick-up finger box (half sizes 0.017 x 0.011 x 0.040 m, its inner face toward the neck, as in
the gripper: local y = world x, local z = world -z) pressed 0.5 mm into a bar neck (0.015 x
0.025 x 0.02 m) and tilted about world x (in the face's plane), y (about the neck's long
horizontal edge) and z (about the finger's vertical edge), alone and combined. Per set-up
(`SETUPS`: which geom is a box or a box-shaped convex mesh; the C engine's multiccd and
nativeccd flags) and tilt: the number of contact points of the pair on the C engine (mj_forward)
and on MJX (mjx.forward; points with dist < includemargin, after physics version 3's
de-duplication, which the model's numeric switches on), with their depths.

    python experiments/engine_parity/manifold_static.py OUT.json [SETUP ...] [--c-only]
    RANDOM=200 python experiments/engine_parity/manifold_static.py OUT.json [SETUP ...]

RANDOM=N: instead of the listed tilts, N random poses (seed 0): tilts uniform in +-3 degrees
about each axis, face-centre penetration uniform in 0.2-1.5 mm; reported per set-up: the
(C points, MJX points) counts, the share of poses where the counts agree, and the mean
absolute difference of the summed depths (mm).

The C engine answers at once; MJX compiles one program per set-up (~10-30 s on the 2-core VM).
Outputs: docs/results/engines/manifold_search/ (docs/MJX_VS_C.md).
"""

from __future__ import annotations

import itertools
import json
import os
import sys

if __package__ in (None, ""):  # run as a file: the repository root holds `experiments`
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))

import mujoco  # noqa: E402
import numpy as np  # noqa: E402

FINGER = (0.017, 0.011, 0.040)
NECK = (0.015, 0.025, 0.020)
PEN = 0.0005
"""penetration of the finger's face centre into the neck, m"""
FINGER_CENTRE = (0.003, 0.010)
"""(y, z) of the finger centre relative to the neck's: the finger covers the neck's height"""
TILTS_DEG = [(0, 0, 0), (1, 0, 0), (5, 0, 0),
             (0, 0.5, 0), (0, 2, 0), (0, 5, 0), (0, -2, 0),
             (0, 0, 0.5), (0, 0, 2), (0, 0, 5), (0, 0, -2),
             (0, 1, 1), (0, 2, 3), (0, 5, 2), (2, 2, 2), (0, 0.1, 0.1), (0, 0.05, 0)]
"""rotations of the finger about world x, y, z (degrees), about the contact centre"""

# name: (finger geom type, neck geom type, C engine flags to disable)
SETUPS = {
    "boxbox": ("box", "box", ()),                          # physics version 3
    "meshfinger": ("mesh", "box", ()),                     # mujoco 4: multiccd on by default
    "meshfinger_noccd": ("mesh", "box", ("multiccd",)),
    "meshfinger_mpr": ("mesh", "box", ("nativeccd",)),     # libccd MPR + perturbation multiccd
    "meshfinger_mpr_noccd": ("mesh", "box", ("nativeccd", "multiccd")),
    "meshneck": ("box", "mesh", ()),
    "meshneck_noccd": ("box", "mesh", ("multiccd",)),
    "meshboth": ("mesh", "mesh", ()),
    "meshboth_noccd": ("mesh", "mesh", ("multiccd",)),
    # MJX collides the box-shaped mesh as a box (physics version 4's routing,
    # mjx_envs/physics/mjx_contacts.py); C as a mesh, multiccd on
    "meshfinger_mjxbox": ("mesh", "box", ()),
    "meshneck_mjxbox": ("box", "mesh", ()),
}


def _verts(half) -> str:
    return " ".join(f"{v:.6f}" for c in itertools.product(*[(-h, h) for h in half]) for v in c)


def _geom(name, kind, half, extra=""):
    if kind == "box":
        return (f'<geom name="{name}" type="box" size="{half[0]} {half[1]} {half[2]}" '
                f'contype="0" conaffinity="0" {extra}/>')
    return (f'<geom name="{name}" type="mesh" mesh="{name}_mesh" contype="0" conaffinity="0" '
            f'{extra}/>')


def model(setup: str) -> mujoco.MjModel:
    """The two-geom model of `setup` (the neck on a free joint, the finger on a mocap body)."""
    fk, nk, off = SETUPS[setup]
    mjxbox = ('<numeric name="mjx_box_meshes" data="1"/>' if setup.endswith("_mjxbox")
              else "")
    xml = f"""
<mujoco>
  <option timestep="0.005" cone="elliptic" iterations="15" ls_iterations="15"/>
  <custom><numeric name="mjx_unique_contact_points" data="1"/>{mjxbox}</custom>
  <asset>
    <mesh name="finger_mesh" vertex="{_verts(FINGER)}"/>
    <mesh name="neck_mesh" vertex="{_verts(NECK)}"/>
  </asset>
  <worldbody>
    <body name="bar"><freejoint/>{_geom("neck", nk, NECK, 'mass="0.5"')}</body>
    <body name="finger" mocap="true">{_geom("finger", fk, FINGER)}</body>
  </worldbody>
  <contact>
    <pair geom1="finger" geom2="neck" condim="3" friction="1.5 1.5 0.01 0.0001 0.0001"
          solref="0.02 1" solimp="0.95 0.99 0.001"/>
  </contact>
</mujoco>"""
    m = mujoco.MjModel.from_xml_string(xml)
    for flag in off:
        m.opt.disableflags |= int(getattr(mujoco.mjtDisableBit, f"mjDSBL_{flag.upper()}"))
    return m


def _rot(deg) -> np.ndarray:
    ax, ay, az = np.radians(deg)
    rx = np.array([[1, 0, 0], [0, np.cos(ax), -np.sin(ax)], [0, np.sin(ax), np.cos(ax)]])
    ry = np.array([[np.cos(ay), 0, np.sin(ay)], [0, 1, 0], [-np.sin(ay), 0, np.cos(ay)]])
    rz = np.array([[np.cos(az), -np.sin(az), 0], [np.sin(az), np.cos(az), 0], [0, 0, 1]])
    return rz @ ry @ rx


BASE = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
"""finger geom frame in the world (columns: local x = world y, local y = world x, z = -z)"""


def finger_pose(deg, pen=PEN) -> tuple[np.ndarray, np.ndarray]:
    """(mocap pos, quat) of the finger tilted by `deg` about its face centre on the neck."""
    r = _rot(deg)
    contact = np.array([NECK[0] - pen, FINGER_CENTRE[0], 0.0])   # face centre, in the neck
    centre0 = np.array([NECK[0] - pen + FINGER[1], *FINGER_CENTRE])
    pos = contact + r @ (centre0 - contact)
    q = np.empty(4)
    mujoco.mju_mat2Quat(q, (r @ BASE).ravel())
    return pos, q


def c_points(m, poses) -> list:
    """Per pose: [(depth mm, pos mm)] of the pair's contacts on the C engine."""
    d, out = mujoco.MjData(m), []
    for pos, q in poses:
        mujoco.mj_resetData(m, d)
        d.mocap_pos[0], d.mocap_quat[0] = pos, q
        mujoco.mj_forward(m, d)
        out.append([(round(1000 * float(c.dist), 3), np.round(1000 * c.pos, 2).tolist())
                    for c in d.contact[:d.ncon]])
    return out


def mjx_points(m, poses) -> list:
    """The same on MJX (points with dist < includemargin)."""
    import jax
    import jax.numpy as jnp

    from mjx_envs.physics import backends

    mjx = backends.import_mjx()   # installs physics version 3's unique points
    from mjx_envs import model as model_lib

    # import_mjx also routes box-shaped meshes for models with the numeric (physics version 4)
    if model_lib.MJX_BOX_MESHES in [m.numeric(i).name for i in range(m.nnumeric)]:
        model_lib.check_box_meshes(m)
    mm = mjx.put_model(model_lib.mjx_model(m))
    d0 = mjx.make_data(mm)

    @jax.jit
    def fwd(p, q):
        def one(p, q):
            dd = mjx.forward(mm, d0.replace(mocap_pos=d0.mocap_pos.at[0].set(p),
                                            mocap_quat=d0.mocap_quat.at[0].set(q)))
            c = dd._impl.contact
            return c.dist, c.pos, c.includemargin
        return jax.vmap(one)(p, q)

    dist, pos, im = jax.device_get(fwd(jnp.asarray(np.array([p for p, _ in poses]), jnp.float32),
                                       jnp.asarray(np.array([q for _, q in poses]), jnp.float32)))
    return [[(round(1000 * float(dist[i, k]), 3), np.round(1000 * pos[i, k], 2).tolist())
             for k in range(dist.shape[1]) if dist[i, k] < im[i, k]]
            for i in range(len(poses))]


def random_poses(out, out_path, setups, n, c_only) -> int:
    from collections import Counter

    rng = np.random.default_rng(0)
    tilts = rng.uniform(-3, 3, (n, 3))
    pens = rng.uniform(0.0002, 0.0015, n)
    poses = [finger_pose(t, p) for t, p in zip(tilts, pens)]
    for s in setups:
        m = model(s)
        rc = c_points(m, poses)
        rm = None if c_only else mjx_points(m, poses)
        cnt = Counter((len(a), len(b) if rm else -1) for a, b in zip(rc, rm or rc))
        row = {"n": n, "counts_c_mjx": {f"{a},{b}": k for (a, b), k in sorted(cnt.items())},
               "c_mean_points": float(np.mean([len(a) for a in rc]))}
        if rm is not None:
            depth = [(sum(-x[0] for x in a), sum(-x[0] for x in b)) for a, b in zip(rc, rm)]
            row.update(mjx_mean_points=float(np.mean([len(b) for b in rm])),
                       same_count=float(np.mean([len(a) == len(b) for a, b in zip(rc, rm)])),
                       depth_sum_absdiff_mm=float(np.mean([abs(a - b) for a, b in depth])))
        out.setdefault("random", {})[s] = row
        print(s, json.dumps(row), flush=True)
        with open(out_path, "w") as fh:
            json.dump(out, fh, indent=1)
    return 0


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    c_only = "--c-only" in argv
    argv = [a for a in argv if a != "--c-only"]
    if not argv or any(s not in SETUPS for s in argv[1:]):
        print(__doc__ + "\nset-ups: " + ", ".join(SETUPS))
        return 2
    out_path, setups = argv[0], argv[1:] or list(SETUPS)
    out = json.load(open(out_path)) if os.path.exists(out_path) else {}
    if os.environ.get("RANDOM"):
        return random_poses(out, out_path, setups, int(os.environ["RANDOM"]), c_only)
    poses = [finger_pose(t) for t in TILTS_DEG]
    for s in setups:
        m = model(s)
        rows_c = c_points(m, poses)
        rows_m = None if c_only else mjx_points(m, poses)
        row = out.setdefault(s, {})
        for i, t in enumerate(TILTS_DEG):
            key = "tilt_xyz_deg=" + ",".join(f"{a:g}" for a in t)
            row[key] = {"c": rows_c[i], **({} if rows_m is None else {"mjx": rows_m[i]})}
            nm = "-" if rows_m is None else len(rows_m[i])
            print(f"{s:22s} {key:26s} C {len(rows_c[i])} MJX {nm}   C depths "
                  f"{[r[0] for r in rows_c[i]]}"
                  + ("" if rows_m is None else f"   MJX depths {[r[0] for r in rows_m[i]]}"),
                  flush=True)
        with open(out_path, "w") as fh:
            json.dump(out, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
