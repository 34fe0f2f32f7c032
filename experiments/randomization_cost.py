"""What physics randomization costs in env steps/s (whole episodes, randomization off and on).

Thin caller of `daddpg_jax.analysis.randomization_cost`; `--help` lists every option.
"""

import sys

from daddpg_jax.analysis.randomization_cost import main

if __name__ == "__main__":
    sys.exit(main())
