"""One checkpoint under two simulations, paired over the same fresh episodes: each side is
ENGINE:VERSION (e.g. ``mjx:6`` and ``mjx:7``). With the same engine and two physics versions
that differ only by float rounding on it (pick up on MJX in versions 6 and 7: the blocker
pairs' mesh copies collide as the boxes they copy, the geoms in the other order), it measures
how far rounding alone moves a policy's outcomes: the floor under any C - MJX difference.

    python experiments/engine_parity/paired_versions.py RUN mjx:6 mjx:7 [--step N] \\
        [--episodes 300] [--seed 9090] [--json OUT.json]

Prints both success rates, the paired counts and the Newcombe 95 % interval of A - B.
Outputs: docs/results/engines/v7/noise_floor/.
"""

from __future__ import annotations

import argparse
import json
import os
import sys

if __package__ in (None, ""):  # run as a file: the repository root holds `experiments`
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))

from daddpg_jax.analysis import engines, evaluation  # noqa: E402


def side(spec: str) -> tuple[str, int]:
    """'mjx:7' -> ('mjx', 7); ValueError on anything else."""
    engine, _, version = spec.partition(":")
    if engine not in ("c", "mjx") or not version.isdigit():
        raise ValueError(f"expected ENGINE:VERSION with ENGINE c or mjx, got {spec!r}")
    return engine, int(version)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("run")
    p.add_argument("a", help="ENGINE:VERSION, e.g. mjx:6")
    p.add_argument("b", help="ENGINE:VERSION, e.g. mjx:7")
    p.add_argument("--step", type=int, default=None, help="checkpoint (default: the best)")
    p.add_argument("--episodes", type=int, default=300)
    p.add_argument("--seed", type=int, default=9090)
    p.add_argument("--json", default=None)
    a = p.parse_args(argv)
    sides = {}
    for spec in (a.a, a.b):
        engine, version = side(spec)
        sides[f"{engine}_v{version}"] = evaluation.load_policy(
            a.run, step=a.step, best=a.step is None, physics=engine, physics_version=version)
    if len(sides) != 2:
        p.error("A and B must differ")
    summary, _ = engines.compare(sides, a.episodes, a.seed,
                                 report=lambda n, r: print(f"{n}: success {r['success_rate']:.3f}",
                                                           flush=True))
    d = summary["difference"]
    print(f"{' - '.join(d['engines'])}: {d['value']:+.3f} (paired 95% {d['ci95'][0]:+.3f} to "
          f"{d['ci95'][1]:+.3f}); {d['paired']}")
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(dict(summary, run=a.run, step=a.step), fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
