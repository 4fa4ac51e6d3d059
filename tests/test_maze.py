"""Rules of the pure-JAX maze (paper Fig. 2): layout, moves, rewards, limits, observations."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from igdrivsim.errors import ConfigError
from maze import env as E
from maze.oracles import planner_lengths, reference_returns

P = E.make_params()
STEP = jax.jit(E.step, static_argnums=2)
AUTO_STEP = jax.jit(E.auto_step, static_argnums=2)
OBS = jax.jit(E.observe, static_argnums=(1, 2))


def state_at(pos, goal, time=0):
    return E.MazeState(pos=jnp.asarray(pos, jnp.int32), goal=jnp.asarray(goal, jnp.int32),
                       time=jnp.asarray(time, jnp.int32), key=jax.random.PRNGKey(0))


def test_layout_is_the_metamaze_grid():
    walls = P.walls
    assert walls.shape == (15, 15)
    assert walls[0].all() and walls[-1].all() and walls[:, 0].all() and walls[:, -1].all()
    for r in range(1, 14, 2):
        assert not walls[r, 1:14].any()  # odd rows are open corridors
    for r in range(2, 13, 2):
        assert walls[r, 2:13:2].all() and not walls[r, 1:14:2].any()  # pillars at even columns
    assert P.start == (7, 7) and not walls[7, 7]
    assert len(P.goal_cells) == int((~walls).sum()) - 1  # every open cell but the start


def test_reset_starts_in_centre_with_goal_uniform_over_open_cells():
    keys = jax.random.split(jax.random.PRNGKey(1), 4000)
    states = jax.jit(jax.vmap(E.reset, (0, None)), static_argnums=1)(keys, P)
    assert (np.asarray(states.pos) == 7).all() and (np.asarray(states.time) == 0).all()
    goals = np.asarray(states.goal)
    assert not P.walls[goals[:, 0], goals[:, 1]].any()
    assert not (goals == 7).all(axis=1).any()
    distinct = {tuple(g) for g in goals}
    assert len(distinct) == len(P.goal_cells)  # 4000 draws cover all 132 cells


def test_moves_and_walls():
    s = state_at((7, 7), (1, 1))
    expected = {0: (6, 7), 1: (8, 7), 2: (7, 6), 3: (7, 8)}
    for action, pos in expected.items():
        nxt, reward, done = STEP(s, jnp.int32(action), P)
        assert tuple(np.asarray(nxt.pos)) == pos and float(reward) == 0.0 and not bool(done)
    s = state_at((7, 8), (1, 1))  # (6, 8) and (8, 8) are pillars
    for action in (0, 1):
        nxt, _, _ = STEP(s, jnp.int32(action), P)
        assert tuple(np.asarray(nxt.pos)) == (7, 8)
        assert int(nxt.time) == 1  # bumping into a wall still costs a step
    nxt, _, _ = STEP(state_at((1, 1), (3, 3)), jnp.int32(0), P)  # outer wall
    assert tuple(np.asarray(nxt.pos)) == (1, 1)


@pytest.mark.parametrize("time", [0, 9, 199])
def test_reward_formula_and_termination_at_goal(time):
    nxt, reward, done = STEP(state_at((7, 7), (7, 8), time), jnp.int32(3), P)
    assert bool(done)
    assert float(reward) == pytest.approx(10.0 - 9.0 * (time + 1) / 200)


def test_time_limit_ends_episode_with_zero_return():
    _, reward, done = STEP(state_at((7, 7), (1, 1), 198), jnp.int32(0), P)
    assert not bool(done)
    _, reward, done = STEP(state_at((7, 7), (1, 1), 199), jnp.int32(0), P)
    assert bool(done) and float(reward) == 0.0


def test_auto_step_resets_after_the_end():
    nxt, reward, done = AUTO_STEP(state_at((7, 7), (7, 8), 5), jnp.int32(3), P)
    assert bool(done) and float(reward) > 0
    assert tuple(np.asarray(nxt.pos)) == (7, 7) and int(nxt.time) == 0
    nxt, _, done = AUTO_STEP(state_at((7, 7), (1, 1), 5), jnp.int32(3), P)
    assert not bool(done) and tuple(np.asarray(nxt.pos)) == (7, 8) and int(nxt.time) == 6


def test_partial_observation_sees_goal_only_inside_the_patch():
    inside = np.asarray(OBS(state_at((7, 7), (8, 8)), P, "partial"))
    assert inside.shape == (13,)
    assert list(inside[9:]) == [7, 7, 8, 8]
    outside = np.asarray(OBS(state_at((7, 7), (7, 9)), P, "partial"))
    assert list(outside[9:]) == [7, 7, -1, -1]
    full = np.asarray(OBS(state_at((7, 7), (7, 9)), P, "full"))
    assert list(full[9:]) == [7, 7, 7, 9]
    assert (full[:9] == outside[:9]).all()


def test_wall_patch_is_centred():
    patch = np.asarray(OBS(state_at((7, 7), (1, 1)), P, "partial"))[:9].reshape(3, 3)
    np.testing.assert_array_equal(patch, [[1, 0, 1], [0, 0, 0], [1, 0, 1]])
    patch = np.asarray(OBS(state_at((7, 8), (1, 1)), P, "partial"))[:9].reshape(3, 3)
    np.testing.assert_array_equal(patch, [[0, 1, 0], [0, 0, 0], [0, 1, 0]])
    patch = np.asarray(OBS(state_at((1, 1), (3, 3)), P, "partial"))[:9].reshape(3, 3)
    np.testing.assert_array_equal(patch, [[1, 1, 1], [1, 0, 0], [1, 0, 1]])


def test_receptive_field_is_a_parameter():
    p5 = E.make_params(receptive_field=5)
    assert p5.obs_dim == 29
    obs = np.asarray(jax.jit(E.observe, static_argnums=(1, 2))(state_at((7, 7), (9, 9)), p5,
                                                               "partial"))
    assert obs.shape == (29,) and list(obs[25:]) == [7, 7, 9, 9]
    small = E.make_params(size=7, max_steps=50)
    assert small.walls.shape == (9, 9) and small.start == (4, 4)


@pytest.mark.parametrize("kwargs", [{"size": 12}, {"size": 13, "receptive_field": 15},
                                    {"receptive_field": 2}, {"max_steps": 0}])
def test_bad_parameters_raise_config_error(kwargs):
    with pytest.raises(ConfigError):
        E.make_params(**kwargs)
    with pytest.raises(ConfigError):
        E.observe(state_at((7, 7), (1, 1)), P, "other")


def test_reference_returns():
    refs = reference_returns(P)
    assert refs["oracle_full"][0] == pytest.approx(9.7014, abs=1e-3)
    assert refs["oracle_full"][1] == pytest.approx(6.636, abs=1e-2)
    assert 5.0 < refs["planner_partial"][0] < refs["oracle_full"][0]
    assert (planner_lengths(P) <= P.max_steps).all()  # the planner always finds the goal
