"""The JAX driving simulator: dynamics, state, reset/step/rollout, roadgraph crop, metrics.

Waymax conventions on WOMD: 10 warm-up steps replayed from the log, then 80 steps where only the
SDC is controlled (delta-local actions by default) and every other object replays its log.
"""

from igdrivsim.simulator.dynamics import (
    ACTION_HIGH,
    ACTION_LOW,
    NUM_BINS,
    NUM_LEVELS,
    clip_action,
    delta_global,
    delta_local,
    discretize,
    inverse_delta_global,
    inverse_delta_local,
    undiscretize,
    validate_actions,
)
from igdrivsim.simulator.metrics import (
    ScenarioMetrics,
    StepMetrics,
    log_divergence,
    mean_log_divergence,
    offroad,
    overlap,
    reward,
    scenario_metrics,
    step_metrics,
)
from igdrivsim.simulator.roadgraph import RoadEdges, select_road_edges
from igdrivsim.simulator.rollout import (
    ACTORS,
    Actor,
    StepInfo,
    Transition,
    constant_velocity_actor,
    expert_action,
    expert_actor,
    expert_discrete_action,
    jit_rollout,
    log_metrics,
    rollout,
    run_episode,
    with_logged_sdc,
)
from igdrivsim.simulator.state import (
    ObjectState,
    SdcTrajectory,
    SimParams,
    SimState,
    check_scenario,
    current_objects,
    reset,
    sdc_pose,
    sdc_yaw_rate,
    simulated_trajectory,
    step,
)

__all__ = [
    "Actor", "StepInfo", "Transition", "run_episode",
    "ACTORS", "ScenarioMetrics", "StepMetrics", "constant_velocity_actor", "expert_action",
    "expert_actor", "expert_discrete_action", "jit_rollout", "log_divergence",
    "mean_log_divergence", "offroad", "overlap", "reward", "rollout", "scenario_metrics",
    "step_metrics", "check_scenario", "log_metrics", "with_logged_sdc",
    "ACTION_HIGH", "ACTION_LOW", "NUM_BINS", "NUM_LEVELS", "ObjectState", "RoadEdges",
    "SdcTrajectory", "SimParams", "SimState", "clip_action", "select_road_edges", "current_objects",
    "delta_global", "delta_local", "discretize", "inverse_delta_global", "inverse_delta_local",
    "reset", "sdc_pose", "sdc_yaw_rate", "simulated_trajectory", "step", "undiscretize",
    "validate_actions",
]
