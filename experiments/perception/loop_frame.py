"""One frame of the camera in the closed loop, with what it detects drawn: Pick up through the
UR path on simulated controllers, the bar from its tag (640x480 from the nominal mount), the
scripted grasp closing on the bar's necks; the tags outlined (id, axes), the goals and the bar's
two points as the camera estimates them marked with crosses.

    MUJOCO_GL=egl python experiments/perception/loop_frame.py     # docs/perception_loop_frame.png
"""

from __future__ import annotations

import argparse
import os
import sys
import tomllib

os.environ.setdefault("MUJOCO_GL", "egl")

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from daddpg_jax.deploy import perception  # noqa: E402
from daddpg_jax.deploy.limits import SHIPPED, RobotLimits  # noqa: E402
from daddpg_jax.deploy.recording import annotate  # noqa: E402
from daddpg_jax.deploy.robot_session import arms_env, robot_task  # noqa: E402
from daddpg_jax.deploy.stand_in import GraspClient  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--steps", type=int, default=16, help="control periods before the frame")
    p.add_argument("--seed", type=int, default=3)
    p.add_argument("--out", default=os.path.join(ROOT, "docs", "perception_loop_frame.png"))
    a = p.parse_args(argv)
    with open(os.path.join(SHIPPED, "sim.toml"), "rb") as f:
        d = tomllib.load(f)
    # unpaced: rendering 640x480 on a CPU takes longer than the 40 ms period and the
    # simulated controllers' watchdog counts wall time
    limits = RobotLimits.from_dict({**d, "deadline": 2.0, "max_observation_age": 2.0})
    sight = perception.Perception("sampler", "camera-tag", "sim", limits, "pickup",
                                  seed=a.seed)
    env = arms_env("ur-sim", robot_task("pickup"), "pickup", limits,
                   safety=limits.safety_limits(), sources=sight)
    client = GraspClient()
    try:
        res = env.reset(rng=np.random.default_rng(a.seed))
        for _ in range(a.steps):
            action, _ = client.act(res.observation, res.desired_goal)
            target, ctrl = env.command_targets(action)
            res = env.step_targets(target, ctrl)
        frame = sight.object_source.source.last_frame
        img = annotate(frame, sight.config.T_world_cam,
                       [res.desired_goal, env.objects.last["object_point"]])
    finally:
        env.close()
    cv2.imwrite(a.out, cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
    print(f"written {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
