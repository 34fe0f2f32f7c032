"""Export a training run's actors and normalizers to one NumPy .npz for the robot side.

Thin caller of `daddpg_jax.cli.export` (also the console script `daddpg-export`);
`--help` lists every option.
"""

import sys

from daddpg_jax.cli.export import main

if __name__ == "__main__":
    sys.exit(main())
