"""Teacher-forced records and settings as data reproduce the online observation and training."""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from igdrivsim.data import Capacities, load_scenario, stack_scenarios, write_tfexample
from igdrivsim.observation import (
    ObservationConfig,
    episode_observations,
    get_setting,
    observe,
    stack_settings,
    superset_config,
)
from igdrivsim.simulator import SimParams, reset, toy
from igdrivsim.training.config import get_profile, with_overrides
from igdrivsim.training.records import compute_records
from igdrivsim.training.update import update_spec

SAMPLE = (Path(__file__).resolve().parents[1]
          / "../shared/data/womd/motion_data_one_example.tfrecord")
OBS = ObservationConfig(8, 512)  # the 512 nearest WOMD points span ~11 m (> the noise offset)
SETTINGS = ("full", "gaussian_noise", "circular_r4", "conic_r4", "random_masking")


@pytest.fixture(scope="module")
def recorded():
    if not SAMPLE.exists():
        pytest.skip("real WOMD sample not present")
    sc = load_scenario(str(SAMPLE), caps=Capacities(max_objects=32, max_roadgraph_points=20_000))
    states = jax.vmap(lambda s: reset(s, SimParams()))(stack_scenarios([sc]))
    rec = compute_records(jax.device_get(states), SimParams(), superset_config(OBS, 32))
    return states, rec


@pytest.mark.parametrize("name", SETTINGS)
def test_recorded_observation_equals_the_online_one(recorded, name):
    """Along the expert-driven episode, the record + the setting as data gives the online
    observation (same points, same hiding, same draws)."""
    states, rec = recorded
    key = jax.random.key(3)
    params = jax.tree.map(lambda x: x[0], stack_settings([name]))
    cached = episode_observations(jax.tree.map(lambda x: jnp.asarray(x[0]), rec).replace(
        actions=None, action_valid=None), params, key, OBS)
    state = jax.tree.map(lambda x: x[0], states)
    # online: replay the recorded expert actions from reset, observing at every step
    from igdrivsim.simulator import dynamics, step

    sim = SimParams()
    acts = jnp.asarray(rec.actions[0], jnp.int32)
    online = []
    for t in range(10):
        online.append(observe(state.replace(timestep=jnp.int32(t)), get_setting(name), key,
                              jax.random.fold_in(key, t), OBS))
    s = state
    for k in range(80):
        online.append(observe(s, get_setting(name), key, jax.random.fold_in(key, s.timestep),
                              OBS))
        s = step(s, dynamics.undiscretize(acts[k]), sim)
    record = jax.tree.map(lambda x: jnp.asarray(x[0]), rec).replace(actions=None,
                                                                     action_valid=None)
    for t in (0, 9, 10, 40, 89):
        a = jax.tree.map(lambda x, t=t: np.asarray(x[t]), cached)
        b = online[t]
        # one observe: a recorded step is a source as a simulator state is
        one = observe(jax.tree.map(lambda x, t=t: x[t], record), params, key,
                      jax.random.fold_in(key, t), OBS)
        jax.tree.map(np.testing.assert_array_equal, one, a)
        np.testing.assert_array_equal(a.objects_valid, np.asarray(b.objects_valid))
        np.testing.assert_array_equal(a.roadgraph_valid, np.asarray(b.roadgraph_valid))
        np.testing.assert_allclose(a.objects, np.asarray(b.objects), atol=2e-5)
        np.testing.assert_allclose(a.sdc_speed, np.asarray(b.sdc_speed), atol=1e-6)
        np.testing.assert_allclose(a.sdc_yaw_rate, np.asarray(b.sdc_yaw_rate), atol=1e-5)
        # points at equal distances may come in either order (float rounding): compare sets
        rows = lambda m: m[np.lexsort(np.round(m, 4).T[::-1])]
        np.testing.assert_allclose(rows(a.roadgraph), rows(np.asarray(b.roadgraph)), atol=2e-5)


def test_settings_train_together_as_they_would_alone(tmp_path):
    """One program for two settings gives each the parameters it gets when trained alone."""
    from igdrivsim.training.loop import train

    base = with_overrides(get_profile("smoke"), ["training.method=bc", "training.num_updates=2",
                                                 "training.seeds=1"])
    caps = base.capacities
    write_tfexample(tmp_path / "d" / "train.tfrecord",
                    [toy.straight_road(caps, speed=3.0 + i, scenario_id=f"t{i}")
                     for i in range(4)])
    data = str(tmp_path / "d")
    quiet = dict(progress=False, log=lambda *_: None, cache_dir=str(tmp_path / "cache"))
    both = train(with_overrides(base, ["observation.setting=full,circular_r4"]), data,
                 tmp_path / "both", **quiet)
    alone = train(with_overrides(base, ["observation.setting=circular_r4"]), data,
                  tmp_path / "alone", **quiet)
    assert len(list((tmp_path / "cache").glob("teacher-*.npz"))) == 1  # recorded once
    diff = jax.tree.map(lambda a, b: float(np.abs(np.asarray(a)[1] - np.asarray(b)[0]).max()),
                        both.params, alone.params)
    assert max(jax.tree.leaves(diff)) < 1e-5
    # recording each batch inside the update (paper scale) trains the same parameters
    fly = train(with_overrides(base, ["observation.setting=circular_r4",
                                      "data.record_teacher=false"]), data, tmp_path / "fly",
                **quiet)
    diff = jax.tree.map(lambda a, b: float(np.abs(np.asarray(a) - np.asarray(b)).max()),
                        fly.params, alone.params)
    assert max(jax.tree.leaves(diff)) < 1e-5
    spec = update_spec(with_overrides(base, ["observation.setting=full,circular_r4"]))
    assert spec.setting is None  # settings as data
