"""The JAX driving simulator: dynamics, state, reset/step/rollout, roadgraph crop, metrics.

Waymax conventions on WOMD: 10 warm-up steps replayed from the log, then 80 steps where only the
SDC is controlled (delta-local actions by default) and every other object replays its log.
"""

from igdrivsim.simulator.dynamics import (
    ACTION_HIGH,
    ACTION_LOW,
    NUM_LEVELS,
    delta_global,
    delta_local,
    discretize,
    inverse_delta_global,
    inverse_delta_local,
    undiscretize,
    validate_actions,
)
from igdrivsim.simulator.metrics import StepMetrics, reward, step_metrics
from igdrivsim.simulator.rollout import expert_action, expert_discrete_action
from igdrivsim.simulator.state import (
    SimParams,
    SimState,
    check_scenario,
    current_objects,
    reset,
    sdc_pose,
    sdc_yaw_rate,
    step,
)

__all__ = [
    "ACTION_HIGH", "ACTION_LOW", "NUM_LEVELS", "SimParams", "SimState", "StepMetrics",
    "check_scenario", "current_objects", "delta_global", "delta_local", "discretize",
    "expert_action", "expert_discrete_action", "inverse_delta_global", "inverse_delta_local",
    "reset", "reward", "sdc_pose", "sdc_yaw_rate", "step", "step_metrics", "undiscretize",
    "validate_actions",
]
