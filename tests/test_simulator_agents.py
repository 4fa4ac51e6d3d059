"""IDM sim agents (igdrivsim.simulator.agents) and the at-fault overlap rule, on toy scenarios."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from igdrivsim.data.scenario import CURRENT_INDEX, TYPE_PEDESTRIAN
from igdrivsim.errors import ConfigError
from igdrivsim.simulator import SimParams, reset, step, toy
from igdrivsim.simulator.agents import IdmParams
from igdrivsim.simulator.episode_metrics import at_fault_overlap as episode_at_fault
from igdrivsim.simulator.metrics import at_fault_overlap, step_metrics
from igdrivsim.simulator.rollout import expert_actor, run_episode
from igdrivsim.simulator.state import current_objects, object_trajectory

IDM = SimParams(agents="idm")
LENGTH = 4.5  # toy cars


@jax.jit
def _episode_idm(state, key):
    return run_episode(state, expert_actor(IDM, discrete=False), key, IDM)


def drive(scenario, params=IDM):
    """Reset + 80 steps with the SDC replaying its log (continuous expert)."""
    state = reset(scenario, params)
    if params == IDM:
        return state, *_episode_idm(state, jax.random.PRNGKey(0))
    fn = jax.jit(lambda s, k: run_episode(s, expert_actor(params, discrete=False), k, params))
    return state, *fn(state, jax.random.PRNGKey(0))


def speeds(a, slot):
    return np.hypot(np.asarray(a.vel_x[slot]), np.asarray(a.vel_y[slot]))


def test_agent_behind_a_stopped_car_beyond_10_m_stops_at_the_minimum_gap():
    _, final, _ = drive(toy.following(gap=28.0, speed=10.0))
    a = final.agents
    assert bool(a.idm[1]) and bool(a.parked[2])
    gaps = np.asarray(a.x[2, CURRENT_INDEX:] - a.x[1, CURRENT_INDEX:]) - LENGTH
    assert gaps.min() > 0.5  # never overlaps (nor touches)
    assert abs(gaps[-1] - IDM.idm.min_gap) < 1.0  # stopped at about s0
    assert speeds(a, 1)[-1] < 0.3
    assert np.all(np.diff(np.asarray(a.x[1, CURRENT_INDEX:])) >= 0)  # never backwards


def test_a_parked_car_stays_put_and_valid():
    sc = toy.following(gap=28.0)
    sc.trajectory.valid[2, 50:] = False  # its log ends: it must not vanish
    _, final, _ = drive(sc)
    a = final.agents
    assert bool(a.parked[2]) and not bool(a.idm[2])
    np.testing.assert_allclose(np.asarray(a.x[2, CURRENT_INDEX:]), 28.0)
    np.testing.assert_allclose(np.asarray(a.y[2, CURRENT_INDEX:]), 0.0)
    assert np.all(np.asarray(a.valid[2, CURRENT_INDEX:]))
    assert np.all(speeds(a, 2)[CURRENT_INDEX + 1:] == 0)


def test_a_free_agent_reaches_and_holds_its_desired_speed_on_a_curved_path():
    params = SimParams(agents="idm", idm=IdmParams(desired_speed=12.0))
    _, final, _ = drive(toy.curve(radius=40.0, start_speed=8.0), params)
    a = final.agents
    v = speeds(a, 1)
    assert v[CURRENT_INDEX] < 9.0  # starts slower (logged 8 m/s)
    np.testing.assert_allclose(v[-15:], 12.0, atol=0.2)  # reaches it and holds it
    r = np.hypot(np.asarray(a.x[1, CURRENT_INDEX:]), np.asarray(a.y[1, CURRENT_INDEX:]))
    assert np.abs(r - 40.0).max() < 0.2  # on its logged path
    # heading follows the path (tangent of the circle) and no lateral jump at the start
    ang = np.arctan2(np.asarray(a.y[1, -1]), np.asarray(a.x[1, -1])) + np.pi / 2
    assert abs((float(a.yaw[1, -1]) - ang + np.pi) % (2 * np.pi) - np.pi) < 0.02
    step1 = np.hypot(float(a.x[1, 11] - a.x[1, 10]), float(a.y[1, 11] - a.y[1, 10]))
    assert step1 < 0.9  # 8 m/s and at most 2 m/s^2 over 0.1 s


def test_an_agent_stops_before_a_red_light():
    _, final, _ = drive(toy.red_light(stop_x=35.0, speed=10.0))
    a = final.agents
    front = np.asarray(a.x[1, CURRENT_INDEX:]) + LENGTH / 2
    assert front.max() < 35.0
    assert speeds(a, 1)[-1] < 0.5
    # the same agent with the light green drives through
    sc = toy.red_light(stop_x=35.0, speed=10.0)
    sc.traffic_lights.state[0] = 6  # LANE_STATE_GO
    _, final, _ = drive(sc)
    assert float(final.agents.x[1, -1]) > 60.0


def test_past_the_end_of_its_log_an_agent_keeps_its_heading_brakes_and_stays():
    sc = toy.following(gap=200.0, speed=10.0)
    sc.trajectory.valid[1, 30:] = False
    _, final, _ = drive(sc)
    a = final.agents
    assert np.all(np.asarray(a.valid[1, CURRENT_INDEX:]))
    np.testing.assert_allclose(np.asarray(a.yaw[1, 30:]), 0.0, atol=1e-6)
    np.testing.assert_allclose(np.asarray(a.y[1, 30:]), 0.0, atol=1e-5)
    v = speeds(a, 1)[35:]
    assert np.all(np.diff(v) <= 1e-6) and v[-1] < 0.1


def test_the_ego_replaying_its_log_under_idm_has_zero_log_divergence():
    _, _, tr = drive(toy.straight_road())
    assert float(jnp.max(tr.metrics.log_divergence)) < 1e-4
    assert not bool(jnp.any(tr.metrics.overlap))


def test_pedestrians_and_objects_overlapping_at_the_start_replay_their_log():
    sc = toy.straight_road()
    sc.metadata.object_type[1] = TYPE_PEDESTRIAN
    _, final, _ = drive(sc)
    a, lg = final.agents, final.log
    assert not bool(a.idm[1])
    for f in ("x", "y", "yaw", "vel_x", "vel_y", "valid"):
        np.testing.assert_array_equal(np.asarray(getattr(a, f)[1]), np.asarray(getattr(lg, f)[1]))
    _, final, _ = drive(toy.following(gap=3.0))  # slots 1 and 2 overlap at step 10
    assert not bool(final.agents.idm[1]) and not bool(final.agents.parked[2])
    np.testing.assert_array_equal(np.asarray(final.agents.x[1]), np.asarray(final.log.x[1]))


def test_step_stays_jittable_and_vmappable_with_todays_shapes():
    batch = jax.tree.map(lambda *a: np.stack(a), toy.straight_road(), toy.following())
    action = jnp.zeros((2, 3), jnp.float32)
    outs = {}
    for agents in ("log", "idm"):
        params = SimParams(agents=agents)
        state = reset(batch, params)
        s1 = jax.jit(step, static_argnums=2)(state, action, params)
        one = jax.vmap(lambda st, ac, p=params: step(st, ac, p))(state, action)
        np.testing.assert_allclose(np.asarray(current_objects(s1).x),
                                   np.asarray(current_objects(one).x), atol=1e-5)
        outs[agents] = (s1, step_metrics(s1, params), current_objects(s1))
    for a, b in zip(jax.tree.leaves(outs["log"][1:]), jax.tree.leaves(outs["idm"][1:]),
                    strict=True):
        assert a.shape == b.shape and a.dtype == b.dtype
    log_state, idm_state = outs["log"][0], outs["idm"][0]
    for a, b in zip(jax.tree.leaves(log_state.replace(agents=None)),
                    jax.tree.leaves(idm_state.replace(agents=None)), strict=True):
        assert a.shape == b.shape and a.dtype == b.dtype
    assert object_trajectory(idm_state).x.shape == log_state.log.x.shape
    with pytest.raises(ConfigError):
        step(log_state, action, SimParams(agents="idm"))
    with pytest.raises(ConfigError):
        SimParams(agents="waymax")
    with pytest.raises(ConfigError):
        IdmParams(min_gap=-1.0)


def _two_cars(ego_x, ego_v, other_x, other_v, other_y=0.0, other_yaw=0.0):
    """A state with the SDC (slot 0) and one other car, both at step 10."""
    sc = toy.straight_road()
    t = (np.arange(sc.trajectory.x.shape[-1]) - CURRENT_INDEX) * 0.1
    toy.set_object(sc, 0, ego_x + ego_v * t, 0.0, 0.0, sdc=True)
    toy.set_object(sc, 1, other_x + other_v * t, other_y, other_yaw)
    sc.trajectory.valid[2] = False
    return reset(sc)


@pytest.mark.parametrize("ego_v, other_x, other_v, other_y, other_yaw, fault", [
    (10.0, 4.0, 5.0, 0.0, 0.0, True),  # the ego's front into a slower car: at fault
    (10.0, 4.0, 0.0, 0.0, 0.0, True),  # into a stopped car: at fault
    (5.0, -4.0, 10.0, 0.0, 0.0, False),  # rear-ended: not at fault
    (0.0, 4.0, -5.0, 0.0, 0.0, False),  # the ego stopped: not at fault
    (10.0, -0.5, 5.0, 1.8, 0.0, False),  # side by side (no front contact): not at fault
    (10.0, 3.0, 5.0, 1.5, np.pi / 2, True),  # a crossing car at the front: at fault
])
def test_at_fault_overlap_follows_nuplans_rule(ego_v, other_x, other_v, other_y, other_yaw,
                                               fault):
    state = _two_cars(0.0, ego_v, other_x, other_v, other_y, other_yaw)
    assert bool(step_metrics(state).overlap)
    assert bool(at_fault_overlap(state)) == fault


@jax.jit
def _episode_log(state, key):
    params = SimParams()
    final, tr = run_episode(state, expert_actor(params, discrete=False), key, params)
    return episode_at_fault(final), jnp.any(tr.metrics.overlap)


def test_at_fault_overlap_over_an_episode():
    # the logged ego drives into a stopped car: at fault
    fault, hit = _episode_log(_two_cars(0.0, 10.0, 30.0, 0.0), jax.random.PRNGKey(0))
    assert bool(hit) and float(fault) == 1.0
    # a stopped ego rear-ended by a replayed car: an overlap, not at fault
    fault, hit = _episode_log(_two_cars(0.0, 0.0, -30.0, 10.0), jax.random.PRNGKey(0))
    assert bool(hit) and float(fault) == 0.0


def test_idm_parameters_are_written_with_the_run():
    record = dataclasses.asdict(IDM)
    assert record["agents"] == "idm" and record["idm"]["desired_speed"] == 30.0
    assert record["idm"]["min_gap"] == 2.0 and record["idm"]["time_headway"] == 2.0


def test_training_against_idm_agents_is_a_config_option():
    from igdrivsim.training.config import get_profile, with_overrides

    config = with_overrides(get_profile("smoke"), ["training.sim_agents=idm"])
    assert config.sim_params.agents == "idm" and get_profile("smoke").sim_params.agents == "log"
    with pytest.raises(ConfigError, match="training.sim_agents"):
        with_overrides(get_profile("smoke"), ["training.sim_agents=waymax"]).validate()
