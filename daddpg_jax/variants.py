"""The algorithm variants as data: one row per variant (standard library only).

Every piece of code that depends on the variant (the networks' inputs, the losses, the export and
the NumPy policy on the robot) reads its row here instead of testing the variant's name, so a
new variant is one new row.

Notation: o_i, g_i = arm i's observation and goal; a_i = arm i's 4-d action [dx, dy, dz, finger];
agents are stacked on a leading axis of size `num_agents`; agent j controls the action columns
[j * d, (j + 1) * d) of the joint 8-d action, d = `agent_action_dim` (arm 0 first), so the joint
action is always the agents' actions concatenated in agent order.

    variant  agents  actor_i sees             critic_i sees                        reward of agent i
    daddpg   2       o_1, o_2, g_1, g_2       o_1, o_2, g_1, g_2, a_1, a_2         arm i's
    maddpg   2       o_i, g_i                 o_1, o_2, g_1, g_2, a_1, a_2         arm i's
    ddpg     2       o_i, g_i                 o_i, g_i, a_i                        arm i's
    single   1       o_1, o_2, g_1, g_2       o_1, o_2, g_1, g_2, a_1, a_2         sum over arms
"""

from __future__ import annotations

import dataclasses

from mjx_envs.observation import ARM_ACTION_SIZE

NUM_ARMS = 2
ARM_ACTION = ARM_ACTION_SIZE
"""action entries per arm: [dx, dy, dz, finger] (mjx_envs.observation.ARM_ACTION_SIZE)"""

BOTH, OWN = "both", "own"
PER_ARM, SUM = "per_arm", "sum"


@dataclasses.dataclass(frozen=True)
class Variant:
    name: str
    num_agents: int
    """agents stacked on the agent axis (each arm an agent, or one agent for both arms)"""
    actor_sees: str
    """'both': (o_1, o_2, g_1, g_2) flattened; 'own': agent i's own (o_i, g_i)"""
    critic_sees: str
    """'both': (o_1, o_2, g_1, g_2) and the joint action; 'own': (o_i, g_i) and agent i's
    own action slot"""
    reward: str
    """'per_arm': agent i learns from arm i's reward; 'sum': from the sum over arms"""
    doc: str

    @property
    def agent_action_dim(self) -> int:
        """action entries each agent outputs (its slot of the joint action)"""
        return NUM_ARMS * ARM_ACTION // self.num_agents

    @property
    def arms_per_agent(self) -> int:
        return NUM_ARMS // self.num_agents

    def input_dims(self, obs_size: int, goal_size: int = 3) -> tuple[int, int]:
        """(actor input size, critic input size)."""
        own, both = obs_size + goal_size, NUM_ARMS * (obs_size + goal_size)
        actor = both if self.actor_sees == BOTH else own
        if self.critic_sees == BOTH:
            critic = both + NUM_ARMS * ARM_ACTION
        else:
            critic = own + self.agent_action_dim
        return actor, critic


VARIANTS: dict[str, Variant] = {v.name: v for v in (
    Variant("daddpg", 2, BOTH, BOTH, PER_ARM,
            "the paper's method: actors see both arms, centralized critics"),
    Variant("maddpg", 2, OWN, BOTH, PER_ARM,
            "actors see their own arm, centralized critics"),
    Variant("ddpg", 2, OWN, OWN, PER_ARM,
            "independent arms: actor and critic see their own arm only"),
    Variant("single", 1, BOTH, BOTH, SUM,
            "one agent with an 8-d action, reward = sum over arms"),
)}

ALGOS = tuple(VARIANTS)


def get(name: str) -> Variant:
    if name not in VARIANTS:
        raise ValueError(f"unknown algo {name!r}; available: {', '.join(ALGOS)}")
    return VARIANTS[name]
