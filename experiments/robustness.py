"""Robustness over seeds: perturbation grids of several runs summarized per group (mean ± std).

Thin caller of `daddpg_jax.analysis.robustness`; `--help` lists every option.
"""

import sys

from daddpg_jax.analysis.robustness import main

if __name__ == "__main__":
    sys.exit(main())
