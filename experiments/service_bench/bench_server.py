"""Latency and throughput of the policy service on loopback (bounded, loopback only).

Examples
  python experiments/service_bench/bench_server.py policy.npz          # starts the service
  python experiments/service_bench/bench_server.py policy.npz --requests 2000 --clients 4 --json b
  python experiments/service_bench/bench_server.py --url http://127.0.0.1:8000 --requests 1000

With a policy file the service runs in its own process (experiments/serve.py on a free loopback
port), as in deployment, so client and server do not share an interpreter lock. Each client
thread keeps one HTTP/1.1 connection and sends its share of POST /act requests with random
observations, one at a time (as a robot does once per control period, but back to back).
Reported: client round-trip p50/p90/p99/max (ms), the server's own compute time p50, and
requests/s over the whole run. Only loopback addresses are accepted.
The benchmark is experiments/service_bench/latency.py.
"""

from __future__ import annotations

import argparse
import json
import os
import sys

from daddpg_jax.deploy import NumpyPolicy, PolicyFormatError

if __package__ in (None, ""):  # run as a file: the repository root holds `experiments`
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))

from experiments.service_bench.latency import (  # noqa: E402
    bench,
    machine,
    not_loopback,
    served_policy,
    start_service,
)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="bench_server.py", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("policy", nargs="?", help="exported .npz to serve in-process (or use --url)")
    p.add_argument("--url", default=None, help="benchmark an already running loopback service")
    p.add_argument("--requests", type=int, default=2000, help="timed requests in all (max 100000)")
    p.add_argument("--clients", type=int, default=1, help="concurrent client threads (max 32)")
    p.add_argument("--warmup", type=int, default=50, help="untimed requests per client first")
    p.add_argument("--json", default=None, help="also write the result to this JSON file")
    args = p.parse_args(argv)
    if not 1 <= args.requests <= 100_000:
        p.error("--requests must be in 1..100000")
    if not 1 <= args.clients <= 32:
        p.error("--clients must be in 1..32")
    if (args.policy is None) == (args.url is None):
        p.error("give either a policy file or --url")
    proc = None
    if args.url is not None:
        if not_loopback(args.url):
            p.error(not_loopback(args.url))
        url = args.url
        obs_size, task, algo, layers = served_policy(url)
    else:
        try:
            policy = NumpyPolicy.load(args.policy)
        except (FileNotFoundError, PolicyFormatError) as e:
            print(f"error: {e}", file=sys.stderr)
            return 2
        proc, url = start_service(args.policy)
        obs_size, task, algo = policy.obs_size, policy.task, policy.algo
        layers = policy.meta["layer_sizes"]
    try:
        res = bench(url, args.requests, args.clients, args.warmup, obs_size)
    finally:
        if proc is not None:
            proc.terminate()
            proc.wait(timeout=10)
    args_text = " ".join(argv if argv is not None else sys.argv[1:])
    res.update(task=task, algo=algo, layer_sizes=layers, server="subprocess" if proc else url,
               machine=machine(),
               command="python experiments/service_bench/bench_server.py " + args_text)
    print(json.dumps(res, indent=2))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(res, f, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
