"""Latency and throughput of the policy service on loopback (bounded, loopback only).

Thin caller of `daddpg_jax.cli.bench_server` (also `python -m daddpg_jax.cli.bench_server`);
`--help` lists every option.
"""

import sys

from daddpg_jax.cli.bench_server import main

if __name__ == "__main__":
    sys.exit(main())
