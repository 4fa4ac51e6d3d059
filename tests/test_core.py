"""The shared core: the episode runner, GAE and the SGD loop on hand-made problems, and that the
maze and the driving benchmark train through the same runner, loss terms, SGD loop, network
parts, method parameters and lane scheduler (and the maze loads no driving package)."""

from __future__ import annotations

import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np

from igdrivsim.core import episode, learn
from igdrivsim.core.episode import Actor, StepInfo, run_episode


def test_run_episode_threads_state_carry_and_keys():
    """A counter environment and an actor that counts its steps and reports its key."""

    def env_step(state, action):
        return state + action, state * 10

    def step(state, carry, key):
        return jnp.int32(2), carry + 1, StepInfo(observation=state, extras=key)

    key = jax.random.PRNGKey(7)
    final, carry, steps = run_episode(env_step, Actor(step=step, init=lambda s, k: 100),
                                      jnp.int32(1), key, 4)
    assert int(final) == 9 and int(carry) == 104
    np.testing.assert_array_equal(steps.info.observation, [1, 3, 5, 7])  # before each step
    np.testing.assert_array_equal(steps.out, [10, 30, 50, 70])
    np.testing.assert_array_equal(steps.info.extras, jax.random.split(key, 4))
    _, _, kept = run_episode(env_step, Actor(step=step), jnp.int32(1), key, 4, carry=0,
                             record=lambda s: s.out)
    np.testing.assert_array_equal(kept, [10, 30, 50, 70])


def _gae_by_loop(values, rewards, dones, last_value, gamma, lam):
    adv = np.zeros_like(values)
    next_adv, next_value = 0.0, last_value
    for t in reversed(range(len(values))):
        keep = 1.0 - dones[t]
        delta = rewards[t] + gamma * next_value * keep - values[t]
        next_adv = delta + gamma * lam * keep * next_adv
        adv[t], next_value = next_adv, values[t]
    return adv


def test_gae_cuts_at_episode_ends():
    rng = np.random.default_rng(0)
    values, rewards = rng.normal(size=12).astype(np.float32), rng.normal(size=12).astype(
        np.float32)
    dones = np.zeros(12, np.float32)
    dones[[3, 8]] = 1.0
    adv, ret = learn.gae(jnp.asarray(values), jnp.asarray(rewards), jnp.asarray(dones, bool),
                          jnp.float32(0.7), 0.9, 0.8)
    np.testing.assert_allclose(adv, _gae_by_loop(values, rewards, dones, 0.7, 0.9, 0.8),
                               rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(ret, np.asarray(adv) + values, rtol=1e-6)
    # The step that ends an episode neither bootstraps nor inherits the next episode's advantage.
    assert float(adv[3]) == np.float32(rewards[3] - values[3])


def test_categorical_terms_by_hand():
    logits = jnp.log(jnp.array([[0.5, 0.25, 0.25], [0.1, 0.1, 0.8]]))
    np.testing.assert_allclose(learn.log_prob(logits, jnp.array([1, 2])),
                               np.log([0.25, 0.8]), rtol=1e-6)
    np.testing.assert_allclose(learn.entropy(logits)[0], -(0.5 * np.log(0.5) + 0.5 * np.log(
        0.25)), rtol=1e-6)
    target = jax.nn.log_softmax(logits[::-1])
    np.testing.assert_allclose(learn.kl_divergence(target, logits),
                               learn.soft_cross_entropy(target, logits) - learn.entropy(
                                   logits[::-1]), rtol=1e-5, atol=1e-6)
    # clipped value loss: a value moved past the clip range is held at it when that is worse
    v = learn.clipped_value_loss(jnp.array([2.0]), jnp.array([0.0]), jnp.array([0.0]), 0.5)
    assert float(v) == 0.5 * 4.0


def test_maze_and_driving_share_the_runner_and_the_loss_terms():
    import importlib

    from igdrivsim.training import update
    from igdrivsim.training.methods import advisor, bc, bc_rl, dagger
    from maze import dagger as maze_dagger
    from maze import mixed, ppo, rollout

    driving = importlib.import_module("igdrivsim.simulator.rollout")
    assert rollout.run_episode is driving.episode.run_episode is episode.run_episode
    assert rollout.Actor is driving.Actor is episode.Actor
    for name in ("log_prob", "entropy", "masked_mean"):
        assert getattr(bc, name) is getattr(bc_rl, name) is getattr(learn, name)
    assert bc_rl.surrogate_terms is advisor.surrogate_terms is ppo.surrogate_terms
    assert ppo.surrogate_terms is learn.surrogate_terms and ppo.entropy is learn.entropy
    assert dagger.soft_cross_entropy is maze_dagger.soft_cross_entropy is learn.soft_cross_entropy
    assert advisor.soft_cross_entropy is mixed.soft_cross_entropy is learn.soft_cross_entropy
    assert advisor.kl_divergence is mixed.kl_divergence is learn.kl_divergence
    assert update.gae is learn.gae and update.normalize is learn.normalize
    assert ppo.gae is mixed.gae is learn.gae


def test_sgd_epochs_is_a_loop_over_shuffled_minibatches():
    """Adam (no clipping) on a least-squares problem: the core loop's parameters
    and per-step losses equal a Python loop over the same permutations."""
    x = jax.random.normal(jax.random.PRNGKey(0), (12, 3))
    y = x @ jnp.array([1.0, -2.0, 0.5])
    data = {"x": x, "y": y}

    def loss_fn(w, mb):
        loss = jnp.mean((mb["x"] @ w - mb["y"]) ** 2)
        return loss, {"loss": loss}

    keys = jax.random.split(jax.random.PRNGKey(1), 3)
    w0 = jnp.zeros(3)
    tx = learn.clipped_adam(1e9)
    w, _, aux = jax.jit(lambda w, o: learn.sgd_epochs(w, o, data, loss_fn, tx, keys, 4, 0.1,
                                                    grad_norm=True))(w0, tx.init(w0))
    assert aux["loss"].shape == (3, 4) and aux["grad_norm"].shape == (3, 4)
    ref, opt, losses_ = w0, tx.init(w0), []
    for k in keys:
        for idx in jax.random.permutation(k, 12).reshape(4, -1):
            mb = {"x": x[idx], "y": y[idx]}
            (loss, _), g = jax.value_and_grad(loss_fn, has_aux=True)(ref, mb)
            u, opt = tx.update(g, opt, ref)
            ref, _ = ref - 0.1 * u, losses_.append(loss)
    np.testing.assert_allclose(w, ref, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(aux["loss"].ravel(), losses_, rtol=1e-5, atol=1e-6)
    assert float(aux["loss"][-1].mean()) < float(aux["loss"][0].mean())


def test_every_learner_trains_through_the_core():
    """The maze's four learners and the driving update share the SGD loop and its optimiser,
    the network parts, the method parameters and the lane scheduler."""
    from igdrivsim import lanes
    from igdrivsim.core import nn, params
    from igdrivsim.pipeline import stages
    from igdrivsim.policy import network
    from igdrivsim.training import update
    from igdrivsim.training.config import LossConfig
    from igdrivsim.training.methods import advisor
    from maze import bc, dagger, mixed, ppo, study
    from maze import network as maze_network

    for module in (ppo, mixed, bc, update):
        assert module.sgd_epochs is learn.sgd_epochs
    assert dagger.sgd_steps is learn.sgd_steps
    assert ppo.clipped_adam is bc.clipped_adam is dagger.clipped_adam is update.clipped_adam
    assert maze_network.gru_scan is network.gru_scan is nn.gru_scan
    assert maze_network.dense_2d is network.dense_2d is nn.dense_2d
    assert study.run_jobs is stages.lanes.run_jobs is lanes.run_jobs
    # one default per shared parameter; the maze study sets its own ADVISOR alpha explicitly
    assert issubclass(ppo.PPOConfig, params.PPOParams)
    assert issubclass(mixed.MixedConfig, params.MixWeights)
    assert issubclass(mixed.MixedConfig, params.AdvisorParams)
    assert issubclass(advisor.Params, params.AdvisorParams)
    assert issubclass(LossConfig, params.PPOParams) and issubclass(LossConfig, params.MixWeights)
    t, p, m = LossConfig(), ppo.PPOConfig(), mixed.MixedConfig()
    for name in ("gamma", "gae_lambda", "clip_eps", "ent_coef", "vf_coef"):
        assert getattr(t, name) == getattr(p, name) == getattr(params.PPOParams(), name)
    assert (t.w_bc, t.w_rl) == (m.w_bc, m.w_rl) == (params.MixWeights().w_bc,
                                                 params.MixWeights().w_rl)
    assert m.alpha == advisor.Params().alpha == params.AdvisorParams().alpha
    assert study.PROFILES["default"].mixed.alpha == study.MAZE_ADVISOR_ALPHA
    assert study.PROFILES["smoke"].mixed.alpha == study.MAZE_ADVISOR_ALPHA


def test_importing_the_maze_loads_no_driving_package():
    """Every maze module imports without the driving layers (data, simulator, observation,
    policy, training, ...): a fresh interpreter imports them all and lists what it loaded."""
    driving = ("igdrivsim.data", "igdrivsim.simulator", "igdrivsim.observation",
               "igdrivsim.policy", "igdrivsim.envs", "igdrivsim.training",
               "igdrivsim.evaluation", "igdrivsim.report", "igdrivsim.pipeline")
    code = ("import importlib, pkgutil, sys, maze\n"
            "for m in pkgutil.iter_modules(maze.__path__):\n"
            "    importlib.import_module('maze.' + m.name)\n"
            f"loaded = sorted(m for m in sys.modules if m.startswith({driving!r}))\n"
            "assert 'maze.study' in sys.modules and not loaded, loaded\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
