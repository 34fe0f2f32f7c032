"""What the C engine does in the episodes that only MJX solves (and the reverse): one checkpoint,
the same fresh episodes on both engines, each episode's outcome on each engine sorted into
never lifted (the object's centre never rose 2 cm above its start), dropped (it rose, and ended
within 2 cm of its start height), lifted but short of the goal, and solved.

    python experiments/engine_parity/outcomes.py RUN --episodes 128 --seed 9090 [--step N] \
        [--json OUT.json]

Run it alone on a CPU (MJX in chunks of 32)."""

from __future__ import annotations

import argparse
import json
import sys
from collections import Counter

import numpy as np

from daddpg_jax.analysis import evaluation

LIFT = 0.02
"""metres above the start height that count as lifted"""


def outcome(obj: np.ndarray, success: bool) -> str:
    """One episode's outcome from its object centres [T+1, 3]."""
    if success:
        return "solved"
    rise = obj[:, 2] - obj[0, 2]
    if rise.max() < LIFT:
        return "never lifted"
    return "dropped" if rise[-1] < LIFT else "lifted, short of the goal"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("run")
    p.add_argument("--episodes", type=int, default=128)
    p.add_argument("--seed", type=int, default=9090)
    p.add_argument("--step", type=int, default=None, help="checkpoint (default: the best)")
    p.add_argument("--json", default=None)
    a = p.parse_args(argv)
    out = {}
    for physics in ("c", "mjx"):
        pol = evaluation.load_policy(a.run, step=a.step, best=a.step is None, physics=physics)
        _, traj = evaluation.evaluate(pol, a.episodes, a.seed)
        sound = np.asarray(traj["physics_fault"]) < 0.5
        out[physics] = [outcome(o, bool(s)) if f else "physics fault"
                        for o, s, f in zip(traj["object"], traj["success"], sound)]
    table = {}
    for only, other in (("mjx", "c"), ("c", "mjx")):
        idx = [i for i in range(a.episodes)
               if out[only][i] == "solved" and out[other][i] != "solved"]
        table[f"solved on {only} only"] = dict(Counter(out[other][i] for i in idx), n=len(idx))
    table["all episodes"] = {k: dict(Counter(v)) for k, v in out.items()}
    print(json.dumps(table, indent=1))
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(dict(run=a.run, step=a.step, episodes=a.episodes, seed=a.seed,
                           outcomes=out, table=table), fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
