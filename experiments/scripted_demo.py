"""Run a task's scripted controller and print its success rate; optionally render a video.

Thin caller of `daddpg_jax.cli.scripted_demo` (also the console script `daddpg-scripted-demo`);
`--help` lists every option.
"""

import sys

from daddpg_jax.cli.scripted_demo import main

if __name__ == "__main__":
    sys.exit(main())
