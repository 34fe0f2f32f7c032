"""Flood benchmark of the policy service (loopback only, bounded in time and connections).

Starts daddpg-serve on a policy file (its own process), then runs a robot probe that polls
POST /act once per control period (25 Hz) with a 40 ms deadline, first alone, then while
--flooders connections (in a second process) send the largest malformed bodies the service
reads (a well-framed body of max_body bytes that is not valid JSON, over keep-alive, as fast as
the service answers). Reports the probe's round-trip times (p50, p99, max) and missed deadlines
in both phases, and how many malformed bodies the service refused meanwhile.

Examples
  python experiments/service_bench/bench_flood.py tests/data/legacy_reach/policy.npz
  python experiments/service_bench/bench_flood.py policy.npz --flooders 16 --seconds 10 --json f

The benchmark is experiments/service_bench/flood.py.
"""

from __future__ import annotations

import argparse
import json
import os
import sys

if __package__ in (None, ""):  # run as a file: the repository root holds `experiments`
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))

from experiments.service_bench.flood import (  # noqa: E402
    BODY_KINDS,
    MAX_FLOODERS,
    MAX_SECONDS,
    flood,
    malformed_body,
    run_phases,
)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="bench_flood.py", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("policy", nargs="?", help="exported .npz to serve")
    p.add_argument("--flood-only", default=None, metavar="URL", help=argparse.SUPPRESS)
    p.add_argument("--flooders", type=int, default=16, help="flooding connections (default 16)")
    p.add_argument("--seconds", type=float, default=10.0, help="length of each phase, s")
    p.add_argument("--kind", choices=BODY_KINDS, default="nesting",
                   help="malformed body (default nesting: '[' * max_body)")
    p.add_argument("--max-body", type=int, default=64 * 1024,
                   help="the service's body limit; each flood body is this large")
    p.add_argument("--json", default=None, help="also write the result to this JSON file")
    args = p.parse_args(argv)
    if not 1 <= args.flooders <= MAX_FLOODERS:
        p.error(f"--flooders must be in 1..{MAX_FLOODERS}")
    if not 0.5 <= args.seconds <= MAX_SECONDS:
        p.error(f"--seconds must be in 0.5..{MAX_SECONDS:g}")
    if args.flood_only:  # the flooders' process: print how many bodies were answered
        host, port = args.flood_only.rsplit("//", 1)[1].rsplit(":", 1)
        print(flood(host, int(port), args.flooders, malformed_body(args.max_body, args.kind),
                    args.seconds), flush=True)
        return 0
    if args.policy is None:
        p.error("give a policy file")
    if not os.path.exists(args.policy):
        print(f"error: policy file {args.policy!r} not found", file=sys.stderr)
        return 2
    try:
        out = run_phases(args.policy, args.flooders, args.kind, args.max_body, args.seconds)
    except RuntimeError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(json.dumps(out, indent=2))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
