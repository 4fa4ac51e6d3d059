"""What a policy observes depends only on the state and the past, never on the logged future."""

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from igdrivsim.data import Capacities, fit_to_capacities, load_scenario
from igdrivsim.data.scenario import CURRENT_INDEX
from igdrivsim.observation import ObservationConfig, get_setting, observe_with_selection
from igdrivsim.simulator import SimParams, reset, sdc_pose

SAMPLE = (Path(__file__).resolve().parents[1]
          / "../shared/data/womd/motion_data_one_example.tfrecord")
needs_sample = pytest.mark.skipif(not SAMPLE.exists(), reason="real WOMD sample not present")


def _scramble_future(scenario, seed=0):
    """The same scenario with every object's logged future (t > 10) replaced by noise."""
    rng = np.random.default_rng(seed)
    tr = scenario.trajectory
    future = np.arange(tr.x.shape[-1]) > CURRENT_INDEX
    moved = {k: np.where(future, np.asarray(getattr(tr, k))
                         + rng.normal(0, 200, np.shape(getattr(tr, k))), getattr(tr, k))
             for k in ("x", "y")}
    return scenario.replace(trajectory=tr.replace(**moved))


@needs_sample
def test_load_time_selection_ignores_the_logged_future():
    scenario = load_scenario(str(SAMPLE))
    caps = Capacities(max_objects=16, max_roadgraph_points=512)
    a = fit_to_capacities(scenario, caps)
    b = fit_to_capacities(_scramble_future(scenario), caps)
    np.testing.assert_array_equal(np.asarray(a.roadgraph.xyz), np.asarray(b.roadgraph.xyz))
    np.testing.assert_array_equal(np.asarray(a.metadata.id), np.asarray(b.metadata.id))
    # the kept points are the nearest to the SDC's current position
    sdc = int(np.argmax(a.metadata.is_sdc))
    here = np.array([a.trajectory.x[sdc, CURRENT_INDEX], a.trajectory.y[sdc, CURRENT_INDEX]])
    full = np.asarray(scenario.roadgraph.xyz)[np.asarray(scenario.roadgraph.valid), :2]
    kept = np.asarray(a.roadgraph.xyz)[np.asarray(a.roadgraph.valid), :2]
    radius = np.linalg.norm(kept - here, axis=-1).max()
    assert len(kept) == 512
    assert (np.linalg.norm(full - here, axis=-1) < radius - 1e-3).sum() <= 512


@needs_sample
def test_off_the_log_the_policy_sees_the_exact_nearest_points_of_the_whole_map():
    scenario = load_scenario(str(SAMPLE))
    state = reset(jax.tree.map(jnp.asarray, scenario), SimParams())
    # move the SDC 30 m sideways off its logged path
    x, y, yaw, _ = sdc_pose(state)
    t = int(state.timestep)
    side = 30.0 * jnp.array([-jnp.sin(yaw), jnp.cos(yaw)])
    sdc = state.sdc.replace(x=state.sdc.x.at[t].set(x + side[0]),
                            y=state.sdc.y.at[t].set(y + side[1]))
    moved = state.replace(sdc=sdc)
    n = 256
    key = jax.random.key(0)
    _, sel = observe_with_selection(moved, get_setting("full"), key, key,
                                    ObservationConfig(8, n))
    rg = scenario.roadgraph  # the uncropped map
    xy = np.asarray(rg.xyz)[:, :2]
    d = np.linalg.norm(xy - np.asarray([x + side[0], y + side[1]]), axis=-1)
    d = np.where(np.asarray(rg.valid), d, np.inf)
    exact = set(np.argsort(d, kind="stable")[:n].tolist())
    assert set(np.asarray(sel.roadgraph_index).tolist()) == exact
