"""Evaluate a trained run: success rate (95% Wilson interval), arm-contact rate, final goal

Thin caller of `daddpg_jax.cli.evaluate` (also the console script `daddpg-evaluate`);
`--help` lists every option.
"""

import sys

from daddpg_jax.cli.evaluate import main

if __name__ == "__main__":
    sys.exit(main())
