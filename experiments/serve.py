"""Serve an exported policy over HTTP + JSON (the decision service the robot queries).

Thin caller of `daddpg_jax.cli.serve` (also the console script `daddpg-serve`);
`--help` lists every option.
"""

import sys

from daddpg_jax.cli.serve import main

if __name__ == "__main__":
    sys.exit(main())
