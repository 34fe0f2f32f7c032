"""Finger pads screened on the parity measurement: with pads of KIND on the grasp pairs
(pads.py), one forward pass at the scripted controller's grasped states and the scripted
controller over the 32 fixed episodes on both engines, with the 10-step divergence.

    python experiments/engine_parity/screen_pads.py KIND OUT.json TASK [TASK ...]

KIND: spheres, dense, caps, caps3, recessed (OUT_M, GRID, SETTLE, HOLD_HI from the environment),
meshf, meshf_noccd, meshneck, meshneck_noccd, meshf_mjxbox, meshneck_mjxbox (physics version 4's
numeric).
Outputs: docs/results/engines/finger_pads/screen_pickup_pot.json (spheres),
docs/results/engines/grasp_hold/screen_dense_pickup.json, recessed_*.json and their logs.
"""

from __future__ import annotations

import json
import os
import sys

if __package__ in (None, ""):  # run as a file: the repository root holds `experiments`
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))

from experiments.engine_parity import pads  # noqa: E402

FORWARD_KEYS = ("states", "finger_contacts_c", "finger_contacts_mjx", "dacc_lin_mean",
                "dacc_lin_p95")


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) < 3 or argv[0] not in pads.PADS:
        print(__doc__)
        return 2
    kind, out_path, tasks = argv[0], argv[1], argv[2:]
    pads.patch(kind)
    from experiments.engine_parity import parity as ep

    ep._finger_geoms = pads.finger_geoms   # the pads count as finger contacts
    out = {}
    for task in tasks:
        f = ep.forward_gap(task, ep.candidate("baseline"), ep.grasp_states(task))
        print("forward", task, {k: f[k] for k in FORWARD_KEYS}, flush=True)
        r = ep.measure(task, ep.candidate("baseline"), episodes=32)
        out[task] = dict(forward=f, c=r["c"]["success"], mjx=r["mjx"]["success"],
                         div_test=r["div_test_mm"], div_mean=r["div_mean_mm"])
        print("RESULT", task, *(out[task][k] for k in ("c", "mjx", "div_test", "div_mean")),
              flush=True)
        with open(out_path, "w") as fh:
            json.dump(out, fh, indent=1, default=str)
    return 0


if __name__ == "__main__":
    sys.exit(main())
