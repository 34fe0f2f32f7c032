"""Render a task's scene at its start state to a PNG (headless: MUJOCO_GL=egl).

Example: MUJOCO_GL=egl daddpg-render --task reach --out docs/scene_reach.png
(or python experiments/render_scene.py ...)
"""

import argparse
import os

import mjx_envs
from mjx_envs.registry import TASKS
from mjx_envs.settings import DEFAULT_TASK

os.environ.setdefault("MUJOCO_GL", "egl")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="daddpg-render", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--task", default=DEFAULT_TASK, choices=TASKS, help="task whose scene to render")
    p.add_argument("--out", default="docs/scene_reach.png", help="output PNG path")
    p.add_argument("--seed", type=int, default=0, help="seed of the reset (goal markers)")
    p.add_argument("--width", type=int, default=960, help="image width, pixels")
    p.add_argument("--height", type=int, default=720, help="image height, pixels")
    args = p.parse_args(argv)
    # lazy: JAX and the renderer load only for a render, not for --help or argument errors
    import imageio.v3 as iio
    import jax

    env = mjx_envs.make(args.task, physics="c")
    state = env.reset(jax.random.PRNGKey(args.seed))
    img = env.render(state, width=args.width, height=args.height)
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    iio.imwrite(args.out, img)
    print(f"wrote {args.out} ({img.shape[1]}x{img.shape[0]})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
