"""TensorBoard's cost on a reach run (CPU preset, C engine), with and without the logger.

Thin caller of `daddpg_jax.analysis.tensorboard_overhead`; usage:
`python experiments/tensorboard_overhead.py [EPOCHS]` (default 5 epochs per run).
"""

import sys

from daddpg_jax.analysis.tensorboard_overhead import main

if __name__ == "__main__":
    sys.exit(main())
