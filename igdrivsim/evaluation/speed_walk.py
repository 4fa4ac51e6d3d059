"""Why sampled BC drifts along the road: the speed random walk of the discretised expert's labels
(``igdrivsim speed-walk``).

Relative to the constant-velocity level, the expert's ``dx`` label (which corrects the
quantisation error the imitator cannot see) is near-memoryless noise of +-1 level; sampling a
BC fit of it integrates it twice. Measured without a trained policy: the label offsets'
distribution and entropies (also given the previous offset), and four actors with the expert's
steering and ``dx`` from the expert, the constant-velocity level, that level plus an i.i.d.
offset, or plus an offset drawn given the actor's previous one.
"""

from __future__ import annotations

import argparse
import json
import sys

import jax
import jax.numpy as jnp
import numpy as np
from scipy.stats import entropy
from tqdm import tqdm

from igdrivsim.data import Capacities
from igdrivsim.data.source import load_validation
from igdrivsim.io import atomic_write_json
from igdrivsim.simulator import SimParams, dynamics, reset
from igdrivsim.simulator.rollout import Actor, expert_action, run_episode
from igdrivsim.simulator.state import _take

MIDDLE = dynamics.NUM_BINS // 2
PARAMS = SimParams()
ACTORS = ("expert", "expert_steering_constant_speed", "expert_steering_sampled_offsets",
          "expert_steering_offsets_given_previous")
OFFSETS = jnp.arange(-3, 4)  # the offsets the fourth actor draws (labels beyond are clipped)


def episode(state, key, actor: str, offsets: jax.Array, log_probs: jax.Array,
            log_probs_given_previous: jax.Array):
    """80 steps of one actor on a batch of states at reset: per-step ``(log divergence, offroad,
    overlap, valid, label offset)`` ``[80, B]`` (``log_probs_given_previous`` row ``i``: the
    next offset's distribution after ``OFFSETS[i]``)."""

    def act(s, previous, k):
        levels = dynamics.discretize(expert_action(s, PARAMS))
        vx, vy = _take(s.sdc.vel_x, s.timestep), _take(s.sdc.vel_y, s.timestep)
        cv = MIDDLE + dynamics.constant_speed_offset(jnp.hypot(vx, vy))  # keep the speed
        label_offset = levels[..., 0] - cv
        if actor == "expert_steering_constant_speed":
            levels = levels.at[..., 0].set(cv)
        elif actor == "expert_steering_sampled_offsets":
            draw = offsets[jax.random.categorical(k, log_probs, shape=cv.shape)]
            levels = levels.at[..., 0].set(cv + draw)
        elif actor == "expert_steering_offsets_given_previous":
            previous = OFFSETS[jax.random.categorical(k, log_probs_given_previous[previous + 3])]
            levels = levels.at[..., 0].set(cv + previous)
        return dynamics.undiscretize(levels), previous, label_offset

    # init: the previous offset, none before the first controlled step
    _, tr = run_episode(state, Actor(step=act, init=lambda s, k: jnp.zeros(
        jnp.shape(s.timestep), jnp.int32)), key, PARAMS)
    m = tr.metrics
    return m.log_divergence, m.offroad, m.overlap, m.valid, tr.extras


def label_statistics(offsets: np.ndarray, valid: np.ndarray) -> dict:
    """Distribution and entropies of the label offsets ``[T, B]`` (valid steps only)."""
    values, counts = np.unique(offsets[valid], return_counts=True)
    both = valid[1:] & valid[:-1]
    prev, cur = offsets[:-1][both], offsets[1:][both]
    conditional = sum(len(cur[prev == v]) / len(cur)
                      * entropy(np.unique(cur[prev == v], return_counts=True)[1])
                      for v in np.unique(prev))
    return {"offset_levels": values.tolist(),
            "offset_probability": (counts / counts.sum()).round(4).tolist(),
            "entropy_nats": round(float(entropy(counts)), 3),
            "entropy_given_previous_nats": round(float(conditional), 3)}


def transition_log_probs(offsets: np.ndarray, valid: np.ndarray, min_count: int = 20
                         ) -> np.ndarray:
    """``[7, 7]`` log-probabilities of the next label offset given the previous one (the
    unconditional distribution after one seen fewer than ``min_count`` times)."""
    both = valid[1:] & valid[:-1]
    prev = np.clip(offsets[:-1][both], -3, 3) + 3
    cur = np.clip(offsets[1:][both], -3, 3) + 3
    counts = np.zeros((7, 7))
    np.add.at(counts, (prev, cur), 1.0)
    total = counts.sum(1, keepdims=True)
    marginal = counts.sum(0) / counts.sum()
    probs = np.where(total >= min_count, counts / np.maximum(total, 1.0), marginal)
    return np.log(np.maximum(probs, 1e-12))


def measure(scenarios, seed: int = 0, batch_size: int = 64, progress: bool = False) -> dict:
    """The label statistics (a first pass) and the actors' mean metrics on stacked scenarios
    ``[N]``, in batches of ``batch_size``."""
    n = int(np.shape(scenarios.scenario_id)[0])
    run = jax.jit(episode, static_argnames="actor")
    start = jax.jit(jax.vmap(reset))
    batches = range(0, n, batch_size)
    bar = tqdm(total=len(batches) * len(ACTORS), desc="speed walk", unit="batch",
               file=sys.stderr, disable=not progress, dynamic_ncols=True)

    def over_batches(actor: str, table) -> list[np.ndarray]:
        parts = []
        bar.set_postfix_str(actor)
        for i in batches:
            state = start(jax.tree.map(lambda x, i=i: x[i:i + batch_size], scenarios))
            key = jax.random.fold_in(jax.random.key(seed), i)
            parts.append([np.asarray(a) for a in run(state, key, actor, *table)])
            bar.update()
        return [np.concatenate(k, axis=1) for k in zip(*parts, strict=True)]

    with bar:
        cat = {"expert": over_batches("expert", (jnp.zeros(1, jnp.int32), jnp.zeros(1),
                                                  jnp.zeros((7, 7))))}
        stats = label_statistics(cat["expert"][4], cat["expert"][3])
        table = (jnp.asarray(stats["offset_levels"], jnp.int32),
                 jnp.log(jnp.asarray(stats["offset_probability"])),
                 jnp.asarray(transition_log_probs(cat["expert"][4], cat["expert"][3])))
        for actor in ACTORS[1:]:
            cat[actor] = over_batches(actor, table)
    actors = {}
    for actor in ACTORS:
        ld, off, ov, v, _ = cat[actor]
        actors[actor] = {"log_divergence_m": round(float(ld[v].mean()), 3),
                         "offroad_pct_steps": round(100 * float(off[v].mean()), 2),
                         "overlap_pct_steps": round(100 * float(ov[v].mean()), 2)}
    return {"scenarios": n, "label_offsets": stats, "actors": actors}


RESULT_FILE = "speed_walk.json"  # what the pipeline writes into WORK/evals


def report_tex(result: dict) -> str:
    """LaTeX macros of a result for the report (``\\SpeedWalk...``)."""
    stats, actors = result["label_offsets"], result["actors"]
    probs = dict(zip(stats["offset_levels"], stats["offset_probability"], strict=True))
    macros = {
        "SpeedWalkProbs": ", ".join(f"{probs.get(k, 0.0):.2f}" for k in (-1, 0, 1)),
        "SpeedWalkEntropy": f"{stats['entropy_nats']:.2f}",
        "SpeedWalkEntropyPrev": f"{stats['entropy_given_previous_nats']:.2f}",
        "SpeedWalkSampled": f"{actors[ACTORS[2]]['log_divergence_m']:.2f}",
        "SpeedWalkSampledOverlap": f"{actors[ACTORS[2]]['overlap_pct_steps']:.2f}",
        "SpeedWalkConstant": f"{actors[ACTORS[1]]['log_divergence_m']:.2f}",
        "SpeedWalkHistory": f"{actors[ACTORS[3]]['log_divergence_m']:.2f}",
        "SpeedWalkHistoryOverlap": f"{actors[ACTORS[3]]['overlap_pct_steps']:.2f}",
        "SpeedWalkScenarios": str(result["scenarios"]),
    }
    lines = ["% Generated by `igdrivsim report` from speed_walk.json; do not edit."]
    lines += [rf"\newcommand{{\{k}}}{{{v}}}" for k, v in macros.items()]
    return "\n".join(lines) + "\n"


def report_markdown(result: dict) -> str:
    """The result as a Markdown table (``tables/speed_walk.md``)."""
    stats = result["label_offsets"]
    pairs = ", ".join(f"{k:+d}: {p:.3f}" for k, p in zip(
        stats["offset_levels"], stats["offset_probability"], strict=True))
    lines = [f"Speed walk on {result['scenarios']} scenarios "
             "(`igdrivsim speed-walk`).", "",
             f"Expert dx label minus the constant-velocity level: {pairs}; entropy "
             f"{stats['entropy_nats']:.3f} nats, {stats['entropy_given_previous_nats']:.3f} "
             "given the previous offset.", "",
             "| actor (expert steering) | log divergence (m) | offroad (% steps) | "
             "overlap (% steps) |", "|---|---|---|---|"]
    for name, m in result["actors"].items():
        lines.append(f"| {name} | {m['log_divergence_m']:.2f} | {m['offroad_pct_steps']:.2f} | "
                     f"{m['overlap_pct_steps']:.2f} |")
    return "\n".join(lines) + "\n"


def speed_walk_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--data", required=True,
                        help="scenarios: a filter output folder or WOMD files")
    parser.add_argument("--limit", type=int, default=0, help="at most N scenarios (0: all)")
    parser.add_argument("--out", default=None, help="also write the result to this JSON file")
    parser.add_argument("--seed", type=int, default=0, help="key of the sampled offsets")
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")


def speed_walk_command(args: argparse.Namespace) -> int:
    scenarios = load_validation(args.data, Capacities(max_objects=32, max_roadgraph_points=10_240),
                                args.limit, progress=not args.no_progress)
    result = measure(scenarios, args.seed, progress=not args.no_progress)
    print(json.dumps(result, indent=2))
    if args.out:
        atomic_write_json(args.out, result)
    return 0
