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
import os
import sys

os.environ.setdefault("MUJOCO_GL", "egl")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--task", required=True, choices=["push", "pickup", "pot"])
    p.add_argument("--episodes", type=int, default=4)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--physics", default="c", choices=["c", "mjx", "auto"])
    p.add_argument("--policy", default="scripted", choices=["scripted", "zero"],
                   help="the task's scripted controller (default) or all-zero actions")
    p.add_argument("--env", action="append", default=[], metavar="KEY=VALUE",
                   help="override an env field of the task's default_config(); repeatable")
    p.add_argument("--video", default=None, help="write an mp4 (or gif) of episode 0")
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--height", type=int, default=480)
    args = p.parse_args(argv)

    if args.episodes < 1:
        p.error("--episodes must be >= 1")


    import jax
    import jax.numpy as jnp
    import numpy as np

    import mjx_envs
    from daddpg_jax.algo import acting
    from mjx_envs import schema, settings
    from mjx_envs.tasks import scripted

    try:
        env_over = schema.parse_overrides(type(settings.default_config(args.task)), args.env,
                                          "--env")
    except schema.ConfigError as e:
        p.error(str(e))
    env = mjx_envs.make(args.task, physics=args.physics, **env_over)
    if args.policy == "zero":
        def policy(obs, max_delta):
            return jnp.zeros(obs["observation"].shape[:-2] + (env.action_size,), jnp.float32)
    else:
        policy = scripted.get_policy(args.task)

    def record(s, a, s2):
        return (env.backend.qpos(s2.data), env.backend.mocap_pos(s2.data),
                s2.metrics["success"], s2.obs["desired_goal"], s2.obs["achieved_goal"])

    @jax.jit
    def rollout(keys):
        return acting.rollout(env, lambda s, _: policy(s.obs, env.config.max_delta), keys,
                              record=record)[1]

    keys = jax.random.split(jax.random.PRNGKey(args.seed), args.episodes)
    qpos, mocap, success, goal, achieved = jax.tree.map(np.asarray, rollout(keys))
    final = success[-1]
    dist = np.linalg.norm(achieved[-1] - goal[-1], axis=-1).mean(axis=0)  # [arms]
    for i, ok in enumerate(final):
        print(f"episode {i}: {'success' if ok else 'failure'}")
    what = "the scripted controller" if args.policy == "scripted" else "zero actions"
    print(f"{args.task}: success {final.mean():.2f} ({int(final.sum())}/{len(final)}) "
          f"with {what} on physics={env.physics}")
    print(f"final goal distance, m: left {dist[0]:.4f} right {dist[-1]:.4f} (mean over episodes)")

    if args.video:
        try:
            import imageio.v2 as imageio
        except ImportError:
            print("--video needs imageio (pip install imageio imageio-ffmpeg); no video written",
                  file=sys.stderr)
            return 1
        from mjx_envs.render import Renderer

        try:
            r = Renderer(env, width=args.width, height=args.height)
        except Exception as e:  # no EGL / GL context
            print(f"rendering failed ({e}); set MUJOCO_GL=egl and install libegl1 libegl-mesa0 "
                  "libgl1-mesa-dri", file=sys.stderr)
            return 1
        frames = [r.frame(qpos[t, 0], goal[t, 0], mocap[t, 0]) for t in range(len(qpos))]
        r.close()
        fps = int(round(1.0 / env.dt))
        try:
            imageio.mimsave(args.video, frames, fps=fps)
        except Exception as e:  # e.g. mp4 without imageio-ffmpeg
            alt = os.path.splitext(args.video)[0] + ".gif"
            print(f"could not write {args.video} ({e}); install imageio-ffmpeg for mp4. "
                  f"Writing {alt} instead.", file=sys.stderr)
            imageio.mimsave(alt, frames, duration=1.0 / fps)
            args.video = alt
        print(f"wrote {args.video} ({len(frames)} frames)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
