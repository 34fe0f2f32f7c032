"""What the policy sees of the true observation and how its actions reach the arms: the stages
of the observation pipeline, written once over ``xp`` (NumPy or jax.numpy).

The simulator applies them as wrappers (`mjx_envs.wrappers`: one wrapper per stage, the carry
in ``State.info``); the robot client (`daddpg_jax.deploy.robot.run_episode`, NumPy) and the
Gymnasium adapter (`mjx_envs.gym_env`, its action history) chain the same stages in a
`Pipeline`. In order, from the arms outwards:

1. believed frames: the gripper terms in each arm's nominal frame (`mjx_envs.randomize.
   believed_obs`; the simulator's physics randomization, part of `mjx_envs.wrappers.Randomize`:
   a real robot reports them so);
2. `PerturbStage`: noise, dropout, bias and period on what the policy sees, latency on what it
   sends (`mjx_envs.perturb`);
3. `HistoryStage`: the policy's own last k actions appended to each arm's observation
   (`mjx_envs.observation.with_action_history`), as chosen, before any latency.

Every stage has the same four pure methods; ``carry`` is the stage's per-episode state:

- ``start(key, obs) -> (seen, carry)`` at reset;
- ``act(carry, action) -> (action, carry)``: the policy's action [8] (clipped to [-1, 1]) on its
  way to the arms;
- ``hold(carry) -> carry``: a control period in which no action was sent (the robot client's
  missed deadlines; the arms hold);
- ``observe(carry, obs) -> (seen, carry)`` after a control step.

Keys: a PRNG key with `mjx_envs.rules.JaxSampler`, a ``numpy.random.Generator`` with
`mjx_envs.rules.NumpySampler` (whose ``split`` returns the generator itself).
"""

from __future__ import annotations

from mjx_envs import observation as obs_lib
from mjx_envs import perturb


class PerturbStage:
    """Observation and action perturbations (`mjx_envs.perturb`) of one episode."""

    def __init__(self, xp, sampler, perturbation: perturb.Perturbation):
        self.xp, self.sampler, self.perturbation = xp, sampler, perturbation

    def start(self, key, obs):
        k_start, k_carry = self.sampler.split(key, 2)
        seen, carry = perturb.start(self.xp, self.sampler, k_start, self.perturbation, obs)
        return seen, dict(carry, key=k_carry)

    def act(self, carry, action):
        return perturb.delay(self.xp, self.perturbation, carry, action)

    def hold(self, carry):
        return carry

    def observe(self, carry, obs):
        key, k_obs = self.sampler.split(carry["key"], 2)
        seen = obs
        if self.perturbation.observes:
            seen, carry = perturb.observe(self.xp, self.sampler, k_obs, self.perturbation,
                                          carry, obs)
        return seen, dict(carry, key=key)


class HistoryStage:
    """The policy's last ``k`` actions [k, 2, 4] (newest first) after each arm's observation."""

    def __init__(self, xp, k: int):
        self.xp, self.k = xp, int(k)

    def start(self, key, obs):
        del key
        history = obs_lib.empty_action_history(self.xp, self.k)
        return obs_lib.with_action_history(self.xp, obs, history), history

    def act(self, history, action):
        return action, obs_lib.push_action(self.xp, history, action)

    def hold(self, history):
        zero = self.xp.zeros((len(obs_lib.ARMS) * obs_lib.ARM_ACTION_SIZE,), self.xp.float32)
        return obs_lib.push_action(self.xp, history, zero)

    def observe(self, history, obs):
        return obs_lib.with_action_history(self.xp, obs, history), history


def stages(xp, sampler, perturbation: perturb.Perturbation | None = None,
           action_history: int = 0) -> list:
    """The stages a config turns on, from the arms outwards (none when all are off)."""
    out = []
    if perturbation is not None and perturbation.active:
        out.append(PerturbStage(xp, sampler, perturbation))
    if int(action_history) > 0:
        out.append(HistoryStage(xp, action_history))
    return out


class Pipeline:
    """Stages chained, from the arms outwards: observations pass them in that order, actions
    in the reverse one. The carry is a list with one entry per stage."""

    def __init__(self, stages: list):
        self.stages = list(stages)

    @property
    def perturbs(self) -> bool:
        """Whether a stage changes the observations between control steps (then the policy
        must see the pipeline's output, not a fresh reading)."""
        return any(isinstance(s, PerturbStage) for s in self.stages)

    def start(self, key, obs):
        carry = []
        for stage in self.stages:
            obs, c = stage.start(key, obs)
            carry.append(c)
        return obs, carry

    def act(self, carry, action):
        carry = list(carry)
        for i in reversed(range(len(self.stages))):
            action, carry[i] = self.stages[i].act(carry[i], action)
        return action, carry

    def hold(self, carry):
        return [stage.hold(c) for stage, c in zip(self.stages, carry, strict=True)]

    def observe(self, carry, obs):
        carry = list(carry)
        for i, stage in enumerate(self.stages):
            obs, carry[i] = stage.observe(carry[i], obs)
        return obs, carry
