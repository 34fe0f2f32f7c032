"""Train two cooperating UR3 arms with DADDPG + HER (or a baseline variant).

Thin caller of `daddpg_jax.cli.train` (also the console script `daddpg-train`);
`--help` lists every option.
"""

import sys

from daddpg_jax.cli.train import main

if __name__ == "__main__":
    sys.exit(main())
