"""Render a task's scene at its start state to a PNG (headless: MUJOCO_GL=egl).

Thin caller of `daddpg_jax.cli.render` (also the console script `daddpg-render`);
`--help` lists every option.
"""

import sys

from daddpg_jax.cli.render import main

if __name__ == "__main__":
    sys.exit(main())
