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
from igdrivsim.simulator.roadgraph import RoadEdges, crop_roadgraph
from igdrivsim.simulator.state import (
    ObjectState,
    SdcTrajectory,
    SimParams,
    SimState,
    current_objects,
    reset,
    sdc_pose,
    simulated_trajectory,
    step,
)

__all__ = [
    "ACTION_HIGH", "ACTION_LOW", "NUM_BINS", "NUM_LEVELS", "ObjectState", "RoadEdges",
    "SdcTrajectory", "SimParams", "SimState", "clip_action", "crop_roadgraph", "current_objects",
    "delta_global", "delta_local", "discretize", "inverse_delta_global", "inverse_delta_local",
    "reset", "sdc_pose", "simulated_trajectory", "step", "undiscretize", "validate_actions",
]
