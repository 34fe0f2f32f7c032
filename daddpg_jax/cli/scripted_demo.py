"""Run a task's scripted controller and print its success rate; optionally render a video.

    python experiments/scripted_demo.py --task pickup --episodes 8
    MUJOCO_GL=egl python experiments/scripted_demo.py --task pot --video pot.mp4
    python experiments/scripted_demo.py --task pot --policy zero --episodes 100  # do nothing

``--policy zero`` sends all-zero actions instead (the arms hold still, fingers half open): the
success rate and goal distance of leaving the object where it lies, the baseline that a trained
policy's evaluation is compared with. ``--env KEY=VALUE`` overrides a field of the task's
``default_config()`` (e.g. ``target_low=0.22,-0.03,0.0,-0.10``).

The controllers (mjx_envs/tasks/scripted.py) are pure functions of the observation; this script only
parses flags, rolls them out with the C engine (or MJX with --physics mjx) and renders.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import sys

os.environ.setdefault("MUJOCO_GL", "egl")   # before MuJoCo is first imported (below)

from mjx_envs import registry, schema  # noqa: E402  (JAX-free; after MUJOCO_GL)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="daddpg-scripted-demo", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--task", required=True, choices=registry.scripted_task_names(),
                   help="task whose scripted controller to run (reach has none)")
    p.add_argument("--episodes", type=int, default=4,
                   help="episodes rolled out at once, one reset key each (default 4)")
    p.add_argument("--seed", type=int, default=0,
                   help="seed of the episodes' reset keys (default 0)")
    p.add_argument("--physics", default="c", choices=["c", "mjx", "auto"],
                   help="physics engine: c = MuJoCo's C engine (default), mjx, or auto (MJX on "
                        "an accelerator, C on a CPU)")
    p.add_argument("--policy", default="scripted", choices=["scripted", "zero"],
                   help="the task's scripted controller (default) or all-zero actions")
    p.add_argument("--env", action="append", default=[], metavar="KEY=VALUE",
                   help="override an env field of the task's default_config(); repeatable")
    p.add_argument("--video", default=None, metavar="OUT.mp4",
                   help="write an mp4 of episode 0 (a GIF for a .gif name, or when no mp4 "
                        "writer is installed); needs MUJOCO_GL=egl and imageio")
    p.add_argument("--width", type=int, default=640, help="video width, pixels (default 640)")
    p.add_argument("--height", type=int, default=480,
                   help="video height, pixels (default 480)")
    args = p.parse_args(argv)

    if args.episodes < 1:
        p.error("--episodes must be >= 1")
    try:
        env_over = schema.parse_overrides(type(registry.default_config(args.task)), args.env,
                                          "--env")
    except schema.ConfigError as e:
        p.error(str(e))
    # lazy: JAX and the engines load only for a rollout, not for --help or argument errors
    import mjx_envs
    from daddpg_jax.analysis import scripted_rollout

    env = mjx_envs.make(args.task, physics=args.physics, **env_over)
    traj = scripted_rollout.rollout(env, args.policy, args.episodes, args.seed)
    final = traj["success"][-1]
    dist = scripted_rollout.final_distance(traj)  # [arms]
    for i, ok in enumerate(final):
        print(f"episode {i}: {'success' if ok else 'failure'}")
    what = "the scripted controller" if args.policy == "scripted" else "zero actions"
    print(f"{args.task}: success {final.mean():.2f} ({int(final.sum())}/{len(final)}) "
          f"with {what} on physics={env.physics}")
    print(f"final goal distance, m: left {dist[0]:.4f} right {dist[-1]:.4f} (mean over episodes)")
    return _video(env, traj, args) if args.video else 0


def _video(env, traj: dict, args) -> int:
    """Episode 0 as a video (--video); the exit code."""
    if importlib.util.find_spec("imageio") is None:   # an optional extra: checked first
        print("--video needs imageio (pip install imageio imageio-ffmpeg); no video written",
              file=sys.stderr)
        return 1
    from daddpg_jax.analysis import scripted_rollout  # lazy: imports JAX (see main)
    from mjx_envs.render import Renderer

    try:
        r = Renderer(env, width=args.width, height=args.height)
    except Exception as e:  # no EGL / GL context
        print(f"rendering failed ({e}); set MUJOCO_GL=egl and install libegl1 libegl-mesa0 "
              "libgl1-mesa-dri", file=sys.stderr)
        return 1
    written, n = scripted_rollout.write_video(r, traj, args.video, int(round(1.0 / env.dt)))
    r.close()
    if written != args.video:
        print(f"could not write {args.video} (install imageio-ffmpeg for mp4); wrote "
              f"{written} instead", file=sys.stderr)
    print(f"wrote {written} ({n} frames)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
