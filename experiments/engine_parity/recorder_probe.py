"""Why the grasped-start recorder keeps fewer states with the recessed pads (pads.py; OUT_M
0.001 and HOLD_HI 0.024 unless set in the environment): the recording episodes, the settled
step and each finger's force there, and for three weak holds the contacts and openings.

    python experiments/engine_parity/recorder_probe.py

Output: docs/results/engines/grasp_hold/recorder_probe_log.txt.
"""

from __future__ import annotations

import os
import sys

if __package__ in (None, ""):  # run as a file: the repository root holds `experiments`
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))

FINGER_JOINTS = ("l_finger1", "l_finger2", "r_finger1", "r_finger2")


def main() -> int:
    os.environ.setdefault("OUT_M", "0.001")
    os.environ.setdefault("HOLD_HI", "0.024")
    from experiments.engine_parity import pads

    pads.patch("recessed")
    import jax
    import numpy as np

    import mjx_envs
    from mjx_envs.tasks import grasp_start as gs

    env = mjx_envs.make("pickup", physics="c")
    keys = jax.random.split(jax.random.PRNGKey(gs.GRASP_SEED), 80)
    qpos, qvel, mocap, held = gs._play(env, keys)
    step = gs._settled_step(held)
    print("settled", (step >= 0).sum())
    check = gs.FingerContacts(env.mj_model, env.rules.object_body)
    print("fingers map size", len(check.fingers))
    settled = np.flatnonzero(step >= 0)
    forces = {b: check.forces(qpos[step[b], b], qvel[step[b], b], mocap[step[b], b])
              for b in settled}
    mins = np.array([min(forces[b].values()) for b in settled])
    print("holds", (mins >= gs.MIN_FINGER_FORCE).sum(), np.percentile(mins, [5, 25, 50]).round(2))
    m, d = check.model, check.data
    ids = [m.jnt_qposadr[m.joint(n).id] for n in FINGER_JOINTS]
    for b in [b for b in settled if min(forces[b].values()) < 0.5][:3]:
        t = step[b]
        f = check.forces(qpos[t, b], qvel[t, b], mocap[t, b])   # leaves d at this state
        print("ep", b, "t", t, {k: round(v, 2) for k, v in f.items()})
        print("  contacts:", sorted({(m.geom(int(c.geom1)).name[:14], m.geom(int(c.geom2)).name)
                                     for c in d.contact[:d.ncon]}))
        print("  openings", np.round(qpos[t, b][ids], 4))
    return 0


if __name__ == "__main__":
    sys.exit(main())
