"""

Thin caller of `daddpg_jax.cli.robot_client` (also the console script `daddpg-robot-client`);
`--help` lists every option.
"""

import sys

from daddpg_jax.cli.robot_client import main

if __name__ == "__main__":
    sys.exit(main())
