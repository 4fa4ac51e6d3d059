"""The one episode runner: the same numbers as the loops it replaced, on the real WOMD sample.

Each reference below is the loop that the caller ran before it was ported onto
:func:`igdrivsim.simulator.rollout.run_episode` (kept here, verbatim in substance, as the
definition of "unchanged").
"""

from __future__ import annotations

from functools import partial
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from igdrivsim.data.scenario import CURRENT_INDEX
from igdrivsim.observation import ObservationConfig, get_setting, observe
from igdrivsim.policy.act import (
    action_log_prob,
    choose_levels,
    example_observation,
    policy_actor,
    policy_rollout,
)
from igdrivsim.policy.network import (
    POOLED_NETWORK,
    PolicyConfig,
    apply_step,
    init_params,
    initial_carry,
)
from igdrivsim.simulator import SimParams, dynamics, reset, step
from igdrivsim.simulator.metrics import reward, step_metrics
from igdrivsim.simulator.rollout import (
    ACTORS,
    Actor,
    action_defined,
    expert_discrete_action,
    rollout,
    run_episode,
)

SAMPLE = Path(__file__).resolve().parents[2] / "shared" / "data" / "womd" / (
    "motion_data_one_example.tfrecord")
PARAMS = SimParams()
TINY = PolicyConfig(**POOLED_NETWORK, object_hidden=(8,), point_hidden=(8,),
                    roadgraph_hidden=(8,),
                    trunk_hidden=(8,), gru_hidden=8, actor_hidden=(8,), value_hidden=(8,))
OBS = ObservationConfig(4, 16)


@pytest.fixture(scope="module")
def scenario():
    if not SAMPLE.exists():
        pytest.skip(f"real WOMD sample not found at {SAMPLE}")
    from igdrivsim.data import Capacities, load_scenario

    return load_scenario(SAMPLE, caps=Capacities(max_objects=16, max_roadgraph_points=20_000))


@pytest.fixture(scope="module")
def state(scenario):
    return jax.jit(reset, static_argnums=1)(scenario, PARAMS)


def _previous_reference_loop(state, actor):
    """The old evaluation / simulator loop: act, step, metrics of the state reached."""

    def body(s, _):
        action, _, _ = actor(s, None, None)
        s = step(s, action, PARAMS)
        return s, step_metrics(s, PARAMS)

    return jax.lax.scan(body, state, None, length=PARAMS.num_controlled_steps)


@pytest.mark.parametrize("name", sorted(ACTORS))
def test_reference_actors_give_the_previous_metrics(state, name):
    actor = ACTORS[name](PARAMS)
    assert isinstance(actor, Actor) and actor.init(state, None) is None
    old_final, old = jax.jit(_previous_reference_loop, static_argnums=1)(state, actor)
    run = jax.jit(partial(run_episode, params=PARAMS, expert=True, with_reward=True),
                  static_argnums=1)
    final, tr = run(state, actor, jax.random.key(0))
    for field in ("log_divergence", "overlap", "offroad", "valid"):
        np.testing.assert_array_equal(getattr(tr.metrics, field), getattr(old, field))
    np.testing.assert_array_equal(final.sdc.x, old_final.sdc.x)
    assert tr.action.shape == (80, 3) and tr.expert.shape == (80, 3)
    assert tr.observation is None and tr.log_prob is None and tr.value is None
    np.testing.assert_array_equal(tr.reward, reward(old))
    if name == "expert":  # the actor's extras are its levels, and the expert labels equal them
        np.testing.assert_array_equal(tr.extras, tr.expert)
        assert float(jnp.max(tr.metrics.log_divergence)) < 0.1
    # the older face of the runner agrees
    _, m, _ = jax.jit(rollout, static_argnums=(1, 3))(state, actor, jax.random.key(0), PARAMS)
    np.testing.assert_array_equal(m.log_divergence, old.log_divergence)


def _previous_policy_episode(policy_params, state, key, setting, actions):
    """The old ``evaluation.rollout._policy_episode`` (GRU warm-up, then fold_in step keys)."""
    episode_key, action_key = jax.random.split(key)

    def look(s, t):
        return observe(s, setting, episode_key, jax.random.fold_in(episode_key, t), OBS)

    def warm(h, t):
        h, _, _ = apply_step(TINY, policy_params, h, look(state.replace(timestep=t), t), t == 0)
        return h, None

    h0, _ = jax.lax.scan(warm, initial_carry(TINY), jnp.arange(CURRENT_INDEX))

    def body(carry, _):
        s, h = carry
        t = s.timestep
        h, logits, _ = apply_step(TINY, policy_params, h, look(s, t), jnp.bool_(False))
        level = choose_levels(logits, jax.random.fold_in(action_key, t), actions)
        s = step(s, dynamics.undiscretize(level), PARAMS)
        return (s, h), step_metrics(s, PARAMS)

    _, out = jax.lax.scan(body, (state, h0), None, length=PARAMS.num_controlled_steps)
    return out


@pytest.fixture(scope="module")
def policy_params():
    return init_params(TINY, jax.random.key(5), example_observation(OBS))


@pytest.mark.parametrize(("setting", "actions"), [("random_masking", "sample"),
                                                   ("gaussian_noise", "mean")])
def test_policy_episode_equals_the_previous_one(scenario, state, policy_params, setting,
                                                actions):
    setting = get_setting(setting)
    key = jax.random.key(11)
    old = jax.jit(_previous_policy_episode, static_argnums=(3, 4))(
        policy_params, state, key, setting, actions)

    @jax.jit
    def new(p, s, k):
        actor = policy_actor(TINY, p, setting, OBS, actions)
        return run_episode(s, actor, k, PARAMS, observation=True, value=True, log_prob=True)

    _, tr = new(policy_params, state, key)
    for field in ("log_divergence", "overlap", "offroad", "valid"):
        np.testing.assert_array_equal(getattr(tr.metrics, field), getattr(old, field))
    assert tr.observation.objects.shape == (80, 4, 6) and tr.value.shape == (80,)
    assert (tr.log_prob is None) == (actions == "mean")
    # evaluation's episode is this one, with the key of seed 0 and scenario 0
    from igdrivsim.policy.closed_loop import EVAL_SEED, StepOutputs, evaluate_policy

    key = jax.random.fold_in(jax.random.fold_in(jax.random.key(EVAL_SEED), 0), 0)
    old = jax.jit(_previous_policy_episode, static_argnums=(3, 4))(
        policy_params, state, key, setting, actions)
    one = partial(jax.tree.map, lambda x: np.asarray(x)[None])  # a batch of one
    out = evaluate_policy(one(one(policy_params)), one(scenario), policy_config=TINY,
                          setting=[setting.name], obs_config=OBS, params=PARAMS,
                          actions=actions, batch_size=1)
    for field in StepOutputs.FIELDS:
        np.testing.assert_array_equal(getattr(out, field)[0, 0, 0], getattr(old, field))


def _previous_policy_rollout(params, carry, state, setting, episode_keys, key):
    """The old ``policy_rollout`` on a batch ``[B]`` (one draw per step)."""

    def observe_batch(s):
        return jax.vmap(lambda st, k: observe(st, setting, k, jax.random.fold_in(
            k, st.timestep), OBS))(s, episode_keys)

    def body(c, k):
        s, h = c
        obs = observe_batch(s)
        h, logits, value = apply_step(TINY, params, h, obs, jnp.zeros(h.shape[:-1], bool))
        idx = jax.random.categorical(k, logits).astype(jnp.int32)
        valid = action_defined(s)
        s = step(s, dynamics.undiscretize(idx), PARAMS)
        r = jnp.where(valid, reward(step_metrics(s, PARAMS)), 0.0)
        return (s, h), (obs, idx, action_log_prob(logits, idx), value, r, valid)

    _, out = jax.lax.scan(body, (state, carry), jax.random.split(key, 80))
    return out


def test_training_rollout_equals_the_previous_one(state, policy_params):
    setting = get_setting("random_masking")
    batch = jax.tree.map(lambda x: jnp.stack([x, x]), state)
    episode_keys = jax.random.split(jax.random.key(2), 2)
    carry = jax.random.normal(jax.random.key(3), (2, TINY.gru_hidden))
    key = jax.random.key(4)
    old = jax.jit(_previous_policy_rollout, static_argnums=3)(
        policy_params, carry, batch, setting, episode_keys, key)
    new = jax.jit(lambda p, c, s, e, k: policy_rollout(TINY, p, c, s, setting, OBS, PARAMS, e,
                                                       k))(
        policy_params, carry, batch, episode_keys, key)
    for a, b in zip(jax.tree.leaves(tuple(new)), jax.tree.leaves(old), strict=True):
        np.testing.assert_array_equal(a, b)
    assert new.actions.shape == (80, 2, 3) and new.rewards.shape == (80, 2)


def test_expert_labels_are_the_discretised_expert(state):
    cv = ACTORS["constant_velocity"](PARAMS)
    _, tr = jax.jit(lambda s: run_episode(s, cv, jax.random.key(0), PARAMS, expert=True,
                                          metrics_fn=None))(state)
    assert tr.metrics is None
    first = expert_discrete_action(state, PARAMS)
    np.testing.assert_array_equal(tr.expert[0], first)
