"""Training configuration: one frozen dataclass plus per-task presets.

Every field has a docstring (cleanrl style). `TrainConfig` holds plain Python values only, so it
is hashable, can be closed over by jitted functions and written to `config.json` with
`dataclasses.asdict`.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Optional, Tuple

ALGOS = ("daddpg", "maddpg", "ddpg", "single")
HER_MODES = ("future", "final", "none")


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    task: str = "reach"
    """task name passed to `mjx_envs.make` (reach, push, pickup, pot)"""
    algo: str = "daddpg"
    """'daddpg': actors see both arms, centralized critics; 'maddpg': actors see their own arm,
    critics see both; 'ddpg': independent arms (actor and critic see their own arm only);
    'single': one agent with an 8-d action, reward = sum over arms"""
    her: str = "future"
    """goal relabelling: 'future' (a strictly later achieved goal of the same episode),
    'final' (the episode's last achieved goal) or 'none'"""
    replay_k: int = 4
    """HER ratio k: a sampled transition is relabelled with probability 1 - 1/(1+k)"""
    num_envs: int = 2
    """environments stepped in parallel; each cycle collects one episode per env"""
    n_epochs: int = 50
    """number of epochs (an epoch is `n_cycles` cycles followed by an evaluation)"""
    n_cycles: int = 50
    """cycles per epoch (a cycle = one rollout of every env + `n_batches` updates)"""
    n_batches: int = 40
    """gradient updates of both agents per cycle"""
    batch_size: int = 256
    """transitions per gradient update"""
    buffer_size: int = 1_000_000
    """replay capacity in transitions (stored as buffer_size // T whole episodes)"""
    gamma: float = 0.98
    """discount factor"""
    polyak: float = 0.95
    """target update: target <- polyak * target + (1 - polyak) * online (once per cycle)"""
    lr_actor: float = 1e-3
    """Adam learning rate of the actors"""
    lr_critic: float = 1e-3
    """Adam learning rate of the critics"""
    noise_eps: float = 0.2
    """std of the Gaussian exploration noise added to actions in [-1, 1]"""
    random_eps: float = 0.3
    """probability that an arm takes a uniformly random action for a step"""
    action_l2: float = 1.0
    """weight of the L2 penalty on the actors' pre-scaled actions"""
    clip_obs: float = 200.0
    """raw observations and goals are clipped to +-clip_obs before normalization"""
    norm_clip: float = 5.0
    """normalized inputs are clipped to +-norm_clip"""
    norm_eps: float = 0.01
    """lower bound of the normalizer's std"""
    hidden: Tuple[int, ...] = (256, 256, 256)
    """hidden layer widths of actors and critics (ReLU)"""
    clip_target: bool = True
    """clip TD targets to [r_min/(1-gamma), r_max/(1-gamma)] from `env.reward_range`"""
    other_action: str = "buffer"
    """in arm i's actor loss the other arm's action comes from the replay 'buffer', or from the
    current 'policy' under stop_gradient; either way arm i's actor gets gradient only from
    its own parameters"""
    n_test_episodes: int = 100
    """deterministic evaluation episodes per epoch (vectorized, fixed seeds)"""
    seed: int = 0
    """seed of the training PRNG key"""
    eval_seed: int = 12345
    """seed of the evaluation episodes (the same episodes every epoch)"""
    physics: str = "auto"
    """physics backend passed to `mjx_envs.make` ('auto', 'mjx' or 'c')"""
    save_buffer: bool = False
    """store the replay buffer in checkpoints (needed for a bit-exact resume; large)"""
    keep_checkpoints: int = 3
    """number of most recent checkpoints kept"""
    num_devices: int = 0
    """local devices to spread envs, replay and the update batch over (0 = all local devices;
    1 = the single-device code path). num_envs and batch_size must be multiples of it"""
    n_demos: int = 0
    """scripted demonstration episodes (the task's controller in mjx_envs/tasks/scripted.py) rolled
    out once at init and kept in a fixed demo buffer beside the replay (0 = none: the paper's
    setting). Not part of the paper: with n_demos > 0 every update adds `demo_batch`
    HER-relabelled demo transitions to the batch of critics and actors and a behaviour-cloning
    term on them (demonstrations as in Nair et al. 2018). Demo env steps are not counted in
    env_steps"""
    demo_batch: int = 128
    """demo transitions added to each update's batch (with n_demos > 0)"""
    bc_weight: float = 10.0
    """weight of the behaviour-cloning term: mean over demo transitions of
    ||mu_i(o, g) - a_demo,i||^2 (arm i's slot of the demo action), added to each actor's loss"""
    q_filter: bool = True
    """apply the behaviour-cloning term only on demo transitions where agent i's critic rates
    the demo action above the actor's own (Q filter)"""

    def __post_init__(self):
        if self.algo not in ALGOS:
            raise ValueError(f"algo must be one of {ALGOS}, got {self.algo!r}")
        if self.her not in HER_MODES:
            raise ValueError(f"her must be one of {HER_MODES}, got {self.her!r}")
        if self.other_action not in ("buffer", "policy"):
            raise ValueError(f"other_action must be 'buffer' or 'policy', got {self.other_action!r}")
        if self.replay_k < 0:
            raise ValueError("replay_k must be >= 0")
        if self.num_devices < 0:
            raise ValueError("num_devices must be >= 0 (0 = all local devices)")
        if self.n_demos < 0:
            raise ValueError("n_demos must be >= 0")
        if self.n_demos > 0 and self.demo_batch < 1:
            raise ValueError("demo_batch must be >= 1 when n_demos > 0")
        if self.bc_weight < 0:
            raise ValueError("bc_weight must be >= 0")
        object.__setattr__(self, "hidden", tuple(int(h) for h in self.hidden))

    @property
    def future_p(self) -> float:
        """probability that a sampled transition gets a relabelled goal"""
        return 0.0 if self.her == "none" else 1.0 - 1.0 / (1.0 + self.replay_k)

    @property
    def num_agents(self) -> int:
        """size of the stacked agent axis (1 for 'single', else 2)"""
        return 1 if self.algo == "single" else 2

    def replace(self, **kw) -> "TrainConfig":
        return dataclasses.replace(self, **kw)

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["hidden"] = list(d["hidden"])
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "TrainConfig":
        names = {f.name for f in dataclasses.fields(cls)}
        return cls(**{k: (tuple(v) if k == "hidden" else v) for k, v in d.items() if k in names})


# HER baselines reference point: 2 rollouts per worker, 40 batches of 256 per cycle, T = 50,
# i.e. 40 * 256 / (2 * 50) = 102.4 gradient samples per stored transition.
BASE_NUM_ENVS = 2
BASE_BATCH = 256
BASE_N_BATCHES = 40
REPLAY_RATIO = BASE_N_BATCHES * BASE_BATCH / (BASE_NUM_ENVS * 50)
MAX_BATCH = 8192
MIN_BUFFER_CYCLES = 20

_TASK_DEFAULTS = {
    # n_cycles follows the HER baselines (20 for reach, 50 otherwise); epochs are a budget.
    "reach": dict(n_cycles=20, n_epochs=20),
    "push": dict(n_cycles=50, n_epochs=100),
    "pickup": dict(n_cycles=50, n_epochs=200),
    "pot": dict(n_cycles=50, n_epochs=300),
}


# Accelerator presets (device="gpu"/"tpu"): MJX physics, ACCELERATOR_NUM_ENVS envs by default,
# the same replay-ratio rule, and n_cycles chosen so that an epoch (cycles between evaluations
# and checkpoints) holds about `epoch_env_steps` env steps whatever num_envs is: one epoch then
# stays well inside a 10-minute device command and `--time-budget` + `--resume` chunk a run.
# n_epochs is a budget in epochs (total env steps = n_epochs * epoch_env_steps). NOT measured on
# an accelerator here: starting points, see docs/SCALING.md.
ACCELERATOR_NUM_ENVS = 4096
_ACCEL_TASK_DEFAULTS = {
    "reach": dict(epoch_env_steps=400_000, n_epochs=10),
    "push": dict(epoch_env_steps=1_000_000, n_epochs=40),
    "pickup": dict(epoch_env_steps=1_000_000, n_epochs=80),
    "pot": dict(epoch_env_steps=1_000_000, n_epochs=120),
}
DEVICES = ("cpu", "gpu", "tpu")


def replay_ratio(n_batches: int, batch_size: int, num_envs: int, episode_length: int = 50) -> float:
    """Gradient samples per stored transition: n_batches * batch_size / (num_envs * T)."""
    return n_batches * batch_size / (num_envs * episode_length)


def preset(task: str, num_envs: Optional[int] = None, episode_length: int = 50,
           ratio: float = REPLAY_RATIO, max_batch: int = MAX_BATCH, device: str = "cpu") -> dict:
    """Per-task overrides for `TrainConfig` at a given number of parallel envs.

    The replay ratio (gradient samples per stored transition)

        ratio = n_batches * batch_size / (num_envs * T)

    is held near the HER baselines' value (40 * 256 / (2 * 50) = 102.4) as num_envs grows:
    batch_size grows first, batch_size = min(max_batch, 256 * num_envs / 2) (rounded to a power
    of two), then n_batches = ceil(ratio * num_envs * T / batch_size). At num_envs = 2 this gives
    exactly the baselines' 40 batches of 256. The buffer keeps 1e6 transitions unless that holds
    fewer than 20 cycles of data, in which case it holds 20 cycles.

    num_envs=None picks 2 (the HER baselines' rollouts per worker; right for 2 CPU cores).
    Returns a dict to pass as `TrainConfig(**preset(...))` or `cfg.replace(**preset(...))`.

    device="gpu" (or "tpu"): the accelerator preset: physics "mjx", num_envs=None picks
    ACCELERATOR_NUM_ENVS (4096), the same batch/updates rule, and n_cycles =
    round(epoch_env_steps / (num_envs * T)) (at least 1) so that an epoch holds about the same
    number of env steps at any num_envs (reach 4e5, contact tasks 1e6); n_epochs is the task's
    budget. Unmeasured starting points (no accelerator was available): docs/SCALING.md.
    """
    if task not in _TASK_DEFAULTS:
        raise ValueError(f"unknown task {task!r}; known: {sorted(_TASK_DEFAULTS)}")
    if device not in DEVICES:
        raise ValueError(f"device must be one of {DEVICES}, got {device!r}")
    accel = device != "cpu"
    if num_envs is None:
        num_envs = ACCELERATOR_NUM_ENVS if accel else BASE_NUM_ENVS
    num_envs = int(num_envs)
    if num_envs < 1:
        raise ValueError("num_envs must be >= 1")
    scale = max(1.0, num_envs / BASE_NUM_ENVS)
    batch = int(min(max_batch, 2 ** round(math.log2(BASE_BATCH * scale))))
    batch = max(batch, min(BASE_BATCH, max_batch))
    samples = ratio * num_envs * episode_length
    n_batches = max(1, int(math.ceil(samples / batch - 1e-9)))
    buffer_size = max(1_000_000, MIN_BUFFER_CYCLES * num_envs * episode_length)
    out = dict(task=task, num_envs=num_envs, batch_size=batch, n_batches=n_batches,
               buffer_size=buffer_size)
    out.update(_TASK_DEFAULTS[task])
    if accel:
        a = _ACCEL_TASK_DEFAULTS[task]
        out.update(physics="mjx", n_epochs=a["n_epochs"],
                   n_cycles=max(1, int(round(a["epoch_env_steps"] / (num_envs * episode_length)))))
    return out
