"""

Thin caller of `daddpg_jax.cli.plot` (also the console script `daddpg-plot`);
`--help` lists every option.
"""

import sys

from daddpg_jax.cli.plot import main

if __name__ == "__main__":
    sys.exit(main())
