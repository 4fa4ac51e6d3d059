"""The reproduction profiles: how much data, how many seeds, which maze study."""

from __future__ import annotations

from dataclasses import dataclass, replace

from igdrivsim.names import GPU_SEEDS, SETTINGS


@dataclass(frozen=True)
class PipelineProfile:
    """Sizes of one reproduction profile (its training hyper-parameters: the training profile's)."""

    name: str
    train_scenarios: int  # synthetic training scenarios generated
    val_scenarios: int  # synthetic validation scenarios generated
    seeds: int  # seeds per (setting, method)
    eval_max_scenarios: int  # 0: every kept validation scenario
    maze_profile: str  # maze.study profile
    settings: tuple[str, ...] = SETTINGS
    eval_batch: int = 32


_LAPTOP = PipelineProfile("laptop", train_scenarios=3072, val_scenarios=512, seeds=3,
                          eval_max_scenarios=0, maze_profile="default")
PROFILES: dict[str, PipelineProfile] = {
    "smoke": PipelineProfile("smoke", train_scenarios=16, val_scenarios=8, seeds=2,
                             eval_max_scenarios=8, maze_profile="smoke", eval_batch=8),
    "laptop": _LAPTOP,
    # the laptop's sizes; the training profile of the same name trains 300 updates
    "quick": replace(_LAPTOP, name="quick"),
    # the laptop's training data and updates; 4x the seeds and validation scenarios, for power
    "gpu": replace(_LAPTOP, name="gpu", val_scenarios=2048, seeds=GPU_SEEDS, eval_batch=128),
    "paper": PipelineProfile("paper", train_scenarios=20_000, val_scenarios=2_000, seeds=3,
                             eval_max_scenarios=0, maze_profile="default"),
}
