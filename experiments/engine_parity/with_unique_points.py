"""daddpg-evaluate or the parity measurement with the unique-points prototype installed
(unique_points.py; UNIQ=0 leaves it out, MID=1 moves the points midway):

    python experiments/engine_parity/with_unique_points.py evaluate RUN --best --physics mjx ...
    python experiments/engine_parity/with_unique_points.py parity --tasks pickup ...

Recorded at git fef0c05 (docs/results/engines/unique_points/README.md): ep_*.json (parity),
pickup_mjx_on_mjxu.* and pot_mid.* (evaluate). The prototype needs the MJX of that revision.
"""

from __future__ import annotations

import os
import sys

if __package__ in (None, ""):  # run as a file: the repository root holds `experiments`
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] not in ("evaluate", "parity"):
        print(__doc__)
        return 2
    from mjx_envs.physics import backends

    backends.import_mjx()
    if os.environ.get("UNIQ", "1") == "1":
        from experiments.engine_parity import unique_points
        unique_points.install()
    if argv[0] == "evaluate":
        from daddpg_jax.cli.evaluate import main as run
    else:
        from experiments.engine_parity.parity import main as run
    return run(argv[1:])


if __name__ == "__main__":
    sys.exit(main())
