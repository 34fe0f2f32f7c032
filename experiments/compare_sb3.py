"""Side by side on one machine: Stable-Baselines3 DDPG + HerReplayBuffer (through the Gymnasium

Thin caller of `daddpg_jax.cli.compare_sb3` (also `python -m daddpg_jax.cli.compare_sb3`);
`--help` lists every option.
"""

import sys

from daddpg_jax.cli.compare_sb3 import main

if __name__ == "__main__":
    sys.exit(main())
