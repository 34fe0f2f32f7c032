"""Frame calibration of the two arms' bases (daddpg_jax/deploy/calibrate.py).

Thin caller of `daddpg_jax.cli.calibrate` (also the console script `daddpg-calibrate`);
`--help` lists every option.
"""

import sys

from daddpg_jax.cli.calibrate import main

if __name__ == "__main__":
    sys.exit(main())
