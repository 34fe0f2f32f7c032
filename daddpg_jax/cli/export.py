"""Export a training run's actors and normalizers to one NumPy .npz for the robot side.

Examples (daddpg-export = python experiments/export.py)
  daddpg-export runs/reach --out policy.npz            # latest checkpoint
  daddpg-export runs/reach --step 2 --out policy.npz   # checkpoint 2
  daddpg-export runs/reach --best --out policy.npz     # the best test success

The file holds the actors' weights, the normalizers, action scaling, the observation layout and
the run's env settings (format: daddpg_jax/running/export.py, docs/DEPLOYMENT.md). Load it
without JAX with daddpg_jax.deploy.NumpyPolicy.load, or serve it with daddpg-serve.
"""

from __future__ import annotations

import argparse
import os
import sys


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="export.py", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run_dir", help="training run directory (with config.json and checkpoints/)")
    which = p.add_mutually_exclusive_group()
    which.add_argument("--step", type=int, default=None,
                       help="checkpoint to export (default: latest)")
    which.add_argument("--best", action="store_true",
                       help="export the checkpoint with the best test success "
                            "(RUN_DIR/checkpoints_best; kept besides the last ones)")
    p.add_argument("--out", required=True, help="output .npz file")
    args = p.parse_args(argv)

    from daddpg_jax.running.export import ExportError, export_run

    try:
        path = export_run(args.run_dir, args.out, step=args.step, best=args.best)
    except ExportError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    from daddpg_jax.deploy import NumpyPolicy, PolicyFormatError

    try:
        pol = NumpyPolicy.load(path)
    except PolicyFormatError as e:
        print(f"error: the written file does not read back: {e}", file=sys.stderr)
        return 1
    best = " (best test success)" if args.best else ""
    print(f"wrote {path}: task {pol.task}, algo {pol.algo}, checkpoint "
          f"{pol.meta['source'].get('checkpoint_step')}{best}, layers {pol.meta['layer_sizes']}, "
          f"{os.path.getsize(path) / 1024:.0f} KiB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
