"""Where MJX and the C engine part on grasps: per candidate cause, the short-horizon object
divergence and the scripted controller's success on both engines.

Thin caller of `daddpg_jax.analysis.engine_parity`; `--help` lists every option. Example (one
task and candidate per process keeps each MJX probe short; bound it with `timeout 180`):

    timeout 180 python experiments/engine_parity.py --tasks pickup --candidates baseline \
        --store docs/results/engine_parity/rows.json --cache /tmp/engine_parity
"""

import sys

from daddpg_jax.analysis.engine_parity import main

if __name__ == "__main__":
    sys.exit(main())
