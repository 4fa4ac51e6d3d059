"""Speed of the maze study's parts: ``python -m maze.bench [--seeds 5] [--hidden 32]``.

Prints one JSON line per measurement: batched environment steps/s (random actions, auto-reset,
observation included), recurrent-PPO training env steps/s (the study's PPO update, ``vmap`` over
seeds) and the rate of the GRU's matrix products over one PPO minibatch, forward and with its
gradient (:func:`igdrivsim.core.nn.gru_scan`): what bounds the study's time. Compile time is
measured separately and excluded from the rates.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import jax
import jax.numpy as jnp

from igdrivsim.cli_args import DefaultsFormatter
from igdrivsim.core.nn import gru_scan, matmul_flops
from maze import env as maze_env
from maze.compiled import Program
from maze.network import init_stacked, make_policy
from maze.ppo import PPOConfig, make_ppo
from maze.study import StudyConfig


def bench_env(num_envs: int, num_steps: int, repeats: int = 3) -> dict:
    params = maze_env.make_params()

    @jax.jit
    def run(key):
        keys = jax.random.split(key, num_envs)
        state = jax.vmap(maze_env.reset, (0, None))(keys, params)

        def one(carry, key):
            state, total = carry
            action = jax.random.randint(key, (num_envs,), 0, 4)
            state, reward, _ = jax.vmap(maze_env.auto_step, (0, 0, None))(state, action, params)
            obs = jax.vmap(maze_env.observe, (0, None, None))(state, params, "partial")
            return (state, total + reward.sum() + obs[:, -1].sum() * 0.0), None

        (_, total), _ = jax.lax.scan(one, (state, 0.0), jax.random.split(key, num_steps))
        return total

    t = time.perf_counter()
    run(jax.random.PRNGKey(0)).block_until_ready()
    compile_s = time.perf_counter() - t
    best = float("inf")
    for r in range(repeats):
        t = time.perf_counter()
        run(jax.random.PRNGKey(r + 1)).block_until_ready()
        best = min(best, time.perf_counter() - t)
    return {"what": "env_steps_per_s", "value": num_envs * num_steps / best,
            "num_envs": num_envs, "num_steps": num_steps, "compile_s": compile_s}


def bench_ppo(seeds: int, hidden: int, updates: int, partial: bool) -> dict:
    params = maze_env.make_params()
    model = make_policy(hidden, params)
    cfg = PPOConfig()
    init, chunk = make_ppo(model, params, cfg, updates)
    net = init_stacked(model, jax.random.PRNGKey(0), seeds, params.obs_dim)
    state = jax.jit(jax.vmap(init))(jax.random.split(jax.random.PRNGKey(1), seeds), net,
                                    jnp.full(seeds, partial), jnp.full(seeds, 10 * updates))
    train = Program(jax.vmap(chunk))  # compiled as the study compiles it
    t = time.perf_counter()
    state, metrics = train(state)
    jax.block_until_ready(metrics)
    first_s = time.perf_counter() - t
    t = time.perf_counter()
    state, metrics = train(state)
    jax.block_until_ready(metrics)
    seconds = time.perf_counter() - t
    steps = seeds * updates * cfg.steps_per_update
    return {"what": "ppo_env_steps_per_s", "value": steps / seconds, "seeds": seeds,
            "hidden": hidden, "updates": updates, "obs": "partial" if partial else "full",
            "compile_plus_first_chunk_s": first_s}


def bench_gru(seeds: int, hidden: int, repeats: int = 20) -> dict:
    """GFLOP/s of the GRU's products (:func:`igdrivsim.core.nn.matmul_flops`) over one PPO
    minibatch (``seeds`` x ``num_steps`` x ``num_envs / num_minibatches`` streams), forward and
    with the gradient."""
    cfg = PPOConfig()
    rows, steps = cfg.num_envs // cfg.num_minibatches, cfg.num_steps
    key = jax.random.PRNGKey(0)
    args = (jax.random.normal(key, (seeds, steps, rows, 3 * hidden)),
            0.1 * jax.random.normal(key, (seeds, hidden, 3 * hidden)), jnp.zeros((seeds, hidden)))
    first = jnp.zeros((seeds, steps, rows), bool).at[:, 0].set(True)
    h0 = jnp.zeros((seeds, rows, hidden))

    def loss(x, w_h, b_hn):
        return jax.vmap(lambda *a: gru_scan(*a)[1].sum())(x, first, h0, w_h, b_hn).sum()

    out = {"what": "gru_gflop_per_s", "seeds": seeds, "hidden": hidden, "rows": rows,
           "steps": steps}
    for name, fn in (("forward", jax.jit(loss)),
                     ("with_gradient", jax.jit(jax.grad(loss, (0, 1, 2))))):
        jax.block_until_ready(fn(*args))
        t = time.perf_counter()
        for _ in range(repeats):
            result = fn(*args)
        jax.block_until_ready(result)
        out[name] = matmul_flops(fn, *args) * repeats / (time.perf_counter() - t) / 1e9
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m maze.bench", description=__doc__.split(
        "\n")[0], formatter_class=DefaultsFormatter)
    parser.add_argument("--envs", type=int, default=4096, help="batched environments")
    parser.add_argument("--steps", type=int, default=500, help="steps per environment")
    parser.add_argument("--seeds", type=int, default=5, help="PPO seeds trained at once")
    parser.add_argument("--hidden", type=int, nargs="+", default=[StudyConfig.hidden],
                        help="GRU widths")
    parser.add_argument("--updates", type=int, default=3, help="PPO updates timed")
    parser.add_argument("--skip-ppo", action="store_true", help="time only the environment")
    args = parser.parse_args(argv)
    print(json.dumps(bench_env(args.envs, args.steps)), flush=True)
    if not args.skip_ppo:
        for hidden in args.hidden:
            print(json.dumps(bench_ppo(args.seeds, hidden, args.updates, True)), flush=True)
            print(json.dumps(bench_gru(args.seeds, hidden)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
