"""One checkpoint's paired C - MJX comparisons over disjoint episode sets, pooled, and what the
±0.10 bar can tell at that checkpoint.

    python experiments/engine_parity/pooled.py A.json [B.json ...] [--json OUT.json]

Each input is a `daddpg-evaluate --physics c,mjx --json` output of the same run and checkpoint,
on episodes of a different seed (fresh episodes: the sets do not overlap). The pooled interval
is Newcombe's paired interval (`daddpg_jax.analysis.engines.newcombe_paired_interval`) over the
summed counts.

``null_pass`` is the chance that two engines which differ at this checkpoint only as noise
does (each episode solved by one engine only goes either way with probability 1/2; the counts
of episodes solved by both and by neither as observed) give an interval inside ±0.10 with the
pooled number of episodes: the exact binomial sum over the split of the one-engine episodes.
It says how often the bar fails at such a checkpoint even without a lean."""

from __future__ import annotations

import argparse
import json
import math
import os
import sys

if __package__ in (None, ""):  # run as a file: the repository root holds `experiments`
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))

from daddpg_jax.analysis.engines import newcombe_paired_interval  # noqa: E402
from experiments.engine_parity.mjx_to_c_rows import BAR, inside  # noqa: E402

KEYS = ("both", "first_only", "second_only", "neither")


def pooled_counts(docs: list[dict]) -> dict:
    """Summed paired counts of comparisons of one checkpoint; ValueError if the inputs are not
    the same run and checkpoint, not C against MJX, or share a seed."""
    first = docs[0]
    seeds = [d["seed"] for d in docs]
    if len(set(seeds)) != len(seeds):
        raise ValueError(f"episode seeds repeat ({seeds}): the episode sets would overlap")
    for d in docs:
        if (os.path.normpath(d["run_dir"]), d["checkpoint"]) != (
                os.path.normpath(first["run_dir"]), first["checkpoint"]):
            raise ValueError("the inputs are not one run's checkpoint")
        if list(d["difference"]["engines"]) != ["c", "mjx"]:
            raise ValueError("each input must compare c with mjx, in that order")
    return {k: sum(int(d["difference"]["paired"][k]) for d in docs) for k in KEYS}


def null_pass(counts: dict, bar: float = BAR) -> float:
    """P(the interval lies within ±bar) when the episodes solved by one engine only split
    Binomial(D, 1/2) between the engines (``both`` and ``neither`` kept)."""
    a, d = counts["both"], counts["neither"]
    disc = counts["first_only"] + counts["second_only"]
    total = 0.0
    for b in range(disc + 1):
        lo, hi = newcombe_paired_interval(a, b, disc - b, d)
        if inside(lo, hi, bar):
            total += math.comb(disc, b) / 2.0 ** disc
    return total


def summary(docs: list[dict]) -> dict:
    counts = pooled_counts(docs)
    n = sum(counts.values())
    diff = (counts["first_only"] - counts["second_only"]) / n
    lo, hi = newcombe_paired_interval(*(counts[k] for k in KEYS))
    return dict(run=os.path.basename(os.path.dirname(os.path.normpath(docs[0]["run_dir"]))),
                checkpoint=docs[0]["checkpoint"], seeds=[d["seed"] for d in docs], episodes=n,
                counts=counts, difference=diff, ci95=[lo, hi], within=inside(lo, hi),
                null_pass=null_pass(counts))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("inputs", nargs="+")
    p.add_argument("--json", default=None)
    a = p.parse_args(argv)
    docs = [json.load(open(f)) for f in a.inputs]
    s = summary(docs)
    c = s["counts"]
    print(f"{s['run']} checkpoint {s['checkpoint']}, {s['episodes']} episodes (seeds "
          f"{', '.join(map(str, s['seeds']))}): C - MJX {s['difference']:+.3f} "
          f"({s['ci95'][0]:+.3f} to {s['ci95'][1]:+.3f}); both {c['both']}, C only "
          f"{c['first_only']}, MJX only {c['second_only']}, neither {c['neither']}; within "
          f"±{BAR:.2f}: {'yes' if s['within'] else 'no'}; without a lean it would be within "
          f"with probability {s['null_pass']:.2f}")
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(s, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
