"""Measure env and training throughput per task, engine and size; print a table, write JSON.

Thin caller of `daddpg_jax.cli.benchmark` (also the console script `daddpg-benchmark`);
`--help` lists every option.
"""

import sys

from daddpg_jax.cli.benchmark import main

if __name__ == "__main__":
    sys.exit(main())
