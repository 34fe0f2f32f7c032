"""Flood benchmark of the policy service (loopback, bounded): a robot probe at 25 Hz with a
40 ms deadline, alone and while connections flood the largest malformed bodies.

Thin caller of `daddpg_jax.cli.bench_flood`; `--help` lists every option.
"""

import sys

from daddpg_jax.cli.bench_flood import main

if __name__ == "__main__":
    sys.exit(main())
