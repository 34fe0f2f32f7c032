"""Export a training run's actors and normalizers to one NumPy .npz for the robot side.

Examples (daddpg-export = python experiments/export.py)
  daddpg-export runs/reach --out policy.npz            # latest checkpoint
  daddpg-export runs/reach --step 2 --out policy.npz   # checkpoint 2
  daddpg-export runs/reach --best --out policy.npz     # the best test success
  daddpg-export runs/reach --format onnx --out policy.onnx   # one ONNX graph (onnxruntime)

The file holds the actors' weights, the normalizers, action scaling, the observation layout and
the run's env settings (format: daddpg_jax/running/export.py, docs/DEPLOYMENT.md). Load it
without JAX with daddpg_jax.deploy.NumpyPolicy.load, or serve it with daddpg-serve.
--format onnx writes the normalizers, actors and tanh as one ONNX graph with the same
metadata (inputs observation [batch, 2, obs] and desired_goal [batch, 2, goal], output actions
[batch, 8]; daddpg_jax/deploy/onnx_policy.py); it needs pip install 'daddpg-jax[onnx]'.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import sys

from daddpg_jax.deploy import PolicyFormatError
from daddpg_jax.deploy.onnx_policy import load_policy


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="daddpg-export", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run_dir", help="training run directory (with config.json and checkpoints/)")
    which = p.add_mutually_exclusive_group()
    which.add_argument("--step", type=int, default=None,
                       help="checkpoint to export (default: latest)")
    which.add_argument("--best", action="store_true",
                       help="export the checkpoint with the best test success "
                            "(RUN_DIR/checkpoints_best; kept besides the last ones)")
    p.add_argument("--format", choices=("npz", "onnx"), default=None,
                   help="npz (NumPy arrays + JSON metadata) or onnx (one ONNX graph); default: "
                        "from the --out name's extension")
    p.add_argument("--out", required=True, help="output file (.npz or .onnx)")
    args = p.parse_args(argv)
    fmt = "onnx" if args.out.lower().endswith(".onnx") else "npz"
    if args.format is not None and args.format != fmt:
        p.error(f"--format {args.format} needs an --out name ending in .{args.format}, got "
                f"{args.out!r}")
    if fmt == "onnx":
        if any(importlib.util.find_spec(m) is None for m in ("onnx", "onnxruntime")):
            p.error("--format onnx needs onnx and onnxruntime: pip install 'daddpg-jax[onnx]'")

    # lazy: imports JAX (to restore the checkpoint), and argument errors stay JAX-free
    from daddpg_jax.running.export import ExportError, export_run

    try:
        path = export_run(args.run_dir, args.out, step=args.step, best=args.best)
    except ExportError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    try:
        pol = load_policy(path)   # read back through the loader's validation
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
