"""The method parameters the maze and the driving benchmark share, each with its one default.

The driving loss config, the driving ADVISOR's ``Params`` and the maze's learners read these
fields under these names; a study that needs another value sets it in its own profile (e.g.
``maze.study.MAZE_ADVISOR_ALPHA``), it does not declare a second default.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class PPOParams:
    """PPO's return and loss coefficients (the paper's, PureJaxRL's defaults)."""

    gamma: float = 0.99  # discount
    gae_lambda: float = 0.95  # GAE's lambda
    clip_eps: float = 0.2  # clip range of the probability ratio (and of the value, maze)
    ent_coef: float = 0.01  # entropy bonus
    vf_coef: float = 0.5  # value loss


@dataclass(frozen=True)
class MixWeights:
    """The paper's BC+PPO loss ``w_bc BC + w_rl PPO``."""

    w_bc: float = 1.0
    w_rl: float = 0.05


@dataclass(frozen=True)
class AdvisorParams:
    """ADVISOR's (Weihs et al. 2021) imitation weight ``exp(-alpha KL(teacher || aux))``."""

    alpha: float = 1.0  # 0: imitation only
