"""The driving policy network (flax): see :mod:`igdrivsim.policy.network`."""

from igdrivsim.policy.network import (
    NUM_ACTION_DIMS,
    NUM_BINS,
    DrivingPolicy,
    PolicyConfig,
    apply_step,
    count_params,
    init_params,
    init_params_per_seed,
    initial_carry,
    masked_max,
)

__all__ = [
    "NUM_ACTION_DIMS", "NUM_BINS", "DrivingPolicy", "PolicyConfig", "apply_step", "count_params",
    "init_params", "init_params_per_seed", "initial_carry", "masked_max",
]
