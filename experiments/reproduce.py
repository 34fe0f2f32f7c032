"""Reproduce the paper's experiments: learning curves per task over seeds, and the cooperation

Thin caller of `daddpg_jax.cli.reproduce` (also the console script `daddpg-reproduce`);
`--help` lists every option.
"""

import sys

from daddpg_jax.cli.reproduce import main

if __name__ == "__main__":
    sys.exit(main())
