"""The maze evaluation's early stop changes no number: it stops once every episode has ended,
with the returns and lengths of stepping ``max_steps`` times (small shapes: 7x7 maze, GRU-8).
The plateau test compares two points evaluated alike. A second process loads the programs the
first compiled from the persistent compilation cache."""

from __future__ import annotations

import dataclasses
import os
import shutil
import subprocess
import sys
import types

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest
from tqdm import tqdm

from igdrivsim.core.episode import run_episode
from maze import env as E
from maze import extended
from maze import study as S
from maze.network import init_stacked, make_policy
from maze.rollout import evaluate, policy_actor

P = E.make_params(size=7, max_steps=40)
MODEL = make_policy(8, P)


def evaluate_every_step(net_params, key, num_episodes, kind):
    """The reference: ``max_steps`` steps whether or not the episodes have ended."""
    key_reset, key_act = jax.random.split(key)
    state = jax.vmap(E.reset, (0, None))(jax.random.split(key_reset, num_episodes), P)

    def env_step(env_state, action):
        state, _, over = env_state
        nxt, reward, done = jax.vmap(E.step, (0, 0, None))(state, action, P)
        live = ~over
        state = jax.tree.map(
            lambda a, b: jnp.where(live.reshape(live.shape + (1,) * (a.ndim - 1)), a, b),
            nxt, state)
        return (state, jnp.zeros_like(over), over | done), (jnp.where(live, reward, 0.0), live)

    start = (state, jnp.ones(num_episodes, bool), jnp.zeros(num_episodes, bool))
    _, _, (reward, live) = run_episode(
        env_step, policy_actor(MODEL, net_params, P, kind), start, key_act, P.max_steps,
        carry=jnp.zeros((num_episodes, MODEL.hidden)), record=lambda step: step.out)
    return reward.sum(0).mean(), live.sum(0).mean()


@pytest.mark.parametrize("kind", ["full", "partial"])
def test_evaluation_stopping_early_gives_the_same_numbers(kind):
    nets = init_stacked(MODEL, jax.random.PRNGKey(0), 3, P.obs_dim)
    keys = jax.random.split(jax.random.PRNGKey(1), 3)
    fast = jax.jit(jax.vmap(lambda n, k: evaluate(MODEL, n, k, 32, P, kind)))(nets, keys)
    slow = jax.jit(jax.vmap(lambda n, k: evaluate_every_step(n, k, 32, kind)))(nets, keys)
    np.testing.assert_allclose(np.asarray(fast[0]), np.asarray(slow[0]), rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(np.asarray(fast[1]), np.asarray(slow[1]), rtol=1e-6)
    assert (np.asarray(fast[1]) > 0).all()


class _CountingStudy:
    """Stands in for :class:`maze.study.Study` in :func:`maze.study.run_rl`: training does
    nothing, each evaluation records its rounds."""

    def __init__(self, cfg):
        self.cfg, self.rounds = cfg, []

    def init_params(self, *_):
        return None

    def ppo_init(self, *_):
        return types.SimpleNamespace(params=None)

    def ppo_chunk(self, state):
        return state, None

    def eval_rows(self, _params, _partial, _key, rounds=1, seeds=None):
        self.rounds.append(rounds)
        n = len(seeds)
        return np.zeros(n), np.zeros(n)


@pytest.mark.parametrize("updates", [10, 40, 50, 80, 160, 480, 490])
def test_plateau_compares_points_evaluated_alike(updates):
    """The point the plateau test compares the final one with is evaluated with the final
    point's rounds (and no other point is)."""
    cfg = dataclasses.replace(S.StudyConfig(), seeds=2, rl_partial_updates=updates)
    fake = _CountingStudy(cfg)
    with tqdm(disable=True) as bar:
        rows = pd.DataFrame(S.run_rl(fake, "rl_partial", True, bar)["records"])
    chunks = updates // cfg.chunk_updates
    start = extended.plateau_start(cfg.ppo.anneal_lr)
    compared = extended.plateau_point(chunks, start)
    every = max(1, chunks // cfg.rl_curve_points)
    evaluated = sorted({c for c in range(0, chunks + 1, every)} | {compared, chunks})
    assert len(fake.rounds) == len(evaluated)
    assert [evaluated[i] for i, r in enumerate(fake.rounds) if r > 1] == sorted(
        {compared, chunks})
    assert set(fake.rounds) <= {1, cfg.final_eval_rounds}
    # the points' progress is their chunk's fraction of the run
    assert sorted(rows.progress.unique()) == pytest.approx([c / chunks for c in evaluated])
    # plateau() compares the final point with exactly that point
    rise = rows.assign(**{"return": rows.progress.map(
        lambda p: 1.0 if p == 1 else (0.5 if p == pytest.approx(compared / chunks) else 0.0))})
    assert extended.plateau(rise, "rl_partial", 0.1, start=start)["rise"] == pytest.approx(0.5)


COMPILE_ONE = """
import sys, jax.numpy as jnp
from maze.compiled import Program, use_compile_cache
use_compile_cache(sys.argv[1])
Program(lambda x: jnp.cumsum(x * 2.0) + 1.0).executable(jnp.ones(7))
"""


def test_a_second_run_loads_the_compiled_programs(tmp_path):
    """Every program compiled by one process is found by the next in a copy of the cache (no
    new entry)."""
    env = {k: v for k, v in os.environ.items() if k != "JAX_COMPILATION_CACHE_DIR"}
    first, second = tmp_path / "xla-cache", tmp_path / "moved" / "xla-cache"
    subprocess.run([sys.executable, "-c", COMPILE_ONE, str(first)], check=True, env=env)
    shutil.copytree(first, second)
    subprocess.run([sys.executable, "-c", COMPILE_ONE, str(second)], check=True, env=env)
    names = sorted(p.name for p in first.iterdir())
    assert names and sorted(p.name for p in second.iterdir()) == names
