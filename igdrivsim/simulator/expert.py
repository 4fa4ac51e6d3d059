"""The expert actor: inverse dynamics from the simulated SDC pose to its next logged pose.

Starting from the *simulated* pose at ``t`` (not the logged one) means the quantisation error of
earlier discretised actions is corrected at every step, so replaying the discretised expert stays
within a few centimetres of the log. The action is clipped to the bounds; when the logged pose at
``t + 1`` is invalid, the expert action is the zero action (the SDC waits; during a gap in the
log it keeps its last pose and rejoins the log at the first valid step, within the bounds).
"""

from __future__ import annotations

import jax.numpy as jnp

from igdrivsim.data.scenario import NUM_STEPS
from igdrivsim.simulator import dynamics
from igdrivsim.simulator.state import SimParams, SimState, log_sdc_at, sdc_pose

DEFAULT_PARAMS = SimParams()


def expert_action(state: SimState, params: SimParams = DEFAULT_PARAMS):
    """``f32[..., 3]``: the (clipped) action that moves the simulated SDC onto its next log pose."""
    _, inverse = dynamics.DYNAMICS[params.dynamics]
    x, y, yaw, _ = sdc_pose(state)
    t1 = jnp.minimum(state.timestep + 1, NUM_STEPS - 1)
    lx, ly, lyaw, lvalid = log_sdc_at(state, t1)
    action = inverse(x, y, yaw, lx, ly, lyaw)
    ok = (lvalid & (state.timestep < NUM_STEPS - 1))[..., None]
    return jnp.where(ok, action, 0.0).astype(jnp.float32)


def expert_discrete_action(state: SimState, params: SimParams = DEFAULT_PARAMS):
    """``int32[..., 3]``: the expert action on the 257-level grid (see ``dynamics.discretize``)."""
    return dynamics.discretize(expert_action(state, params))
