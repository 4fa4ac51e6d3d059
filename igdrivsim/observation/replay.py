"""``igdrivsim replay``: replay an actor (the discretised expert by default) on WOMD scenarios.

Prints one JSON line per scenario: where the *logged* SDC overlaps / is offroad (timesteps
11..90) next to the same for the replay, and the replay's mean and max log divergence; then a
summary on stderr. ``--out DIR`` also writes ``DIR/replay.jsonl``, ``DIR/summary.json`` and the
resolved ``DIR/config.json`` (atomically). ``--gif PATH`` animates the first scenario's replay.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import functools
import json
import os
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np
from tqdm import tqdm

from igdrivsim.data import decode_scenario_id
from igdrivsim.data.egos import add_egos_argument
from igdrivsim.data.source import count_scenarios, open_scenarios
from igdrivsim.errors import ConfigError, DataError
from igdrivsim.io import atomic_path, atomic_write_json, require_folder
from igdrivsim.observation import render
from igdrivsim.simulator.metrics import StepMetrics, mean_log_divergence
from igdrivsim.simulator.rollout import ACTORS, log_metrics, run_episode
from igdrivsim.simulator.state import SimParams, SimState, check_scenario, reset

DEFAULT_PARAMS = SimParams()


@functools.cache
def replay_fn(actor: str = "expert", params: SimParams = DEFAULT_PARAMS):
    """Jitted ``f(scenario, key) -> (final_state, replay_metrics [80], log_metrics [80])`` for one
    scenario, cached per ``(actor, params)``."""
    policy = ACTORS[actor](params)

    @jax.jit
    def run(scenario, key):
        state = reset(scenario, params)
        final, tr = run_episode(state, policy, key, params)
        return final, tr.metrics, log_metrics(state, params)

    return run


def scenario_record(scenario_id: str, replay: StepMetrics, log: StepMetrics) -> dict:
    """The JSON record of one replayed scenario (host metrics ``[80]`` of timesteps 11..90)."""
    div = np.where(np.asarray(replay.valid), np.asarray(replay.log_divergence), 0.0)
    return {
        "scenario_id": scenario_id,  # then log_overlap_steps .. replay_offroad_steps
        **{f"{who}_{rule}_steps": [11 + int(i)
                                   for i in np.flatnonzero(np.asarray(getattr(m, rule)))]
           for who, m in (("log", log), ("replay", replay)) for rule in ("overlap", "offroad")},
        "replay_mean_log_divergence": round(float(mean_log_divergence(replay)), 5),
        "replay_max_log_divergence": round(float(div.max(initial=0.0)), 5),
        "valid_steps": int(np.sum(replay.valid)),
    }


def summarize(records: list[dict], num_steps: int) -> dict:
    """Averages over scenarios (rates in %), as in the paper's Table I."""
    n = len(records)
    if n == 0:
        return {"scenarios": 0}

    def pct(key, any_step=True):
        vals = [(len(r[key]) > 0) if any_step else len(r[key]) / num_steps for r in records]
        return round(100.0 * float(np.mean(vals)), 3)

    return {
        "scenarios": n,
        "mean_log_divergence": round(float(np.mean([r["replay_mean_log_divergence"]
                                                    for r in records])), 5),
        "max_log_divergence": round(float(np.mean([r["replay_max_log_divergence"]
                                                   for r in records])), 5),
        "overlap_rate_pct": pct("replay_overlap_steps"),
        "offroad_rate_pct": pct("replay_offroad_steps"),
        "overlap_pct": pct("replay_overlap_steps", False),
        "offroad_pct": pct("replay_offroad_steps", False),
        "log_overlap_rate_pct": pct("log_overlap_steps"),
        "log_offroad_rate_pct": pct("log_offroad_steps"),
        "same_as_log": sum(r["replay_overlap_steps"] == r["log_overlap_steps"]
                           and r["replay_offroad_steps"] == r["log_offroad_steps"]
                           for r in records),
    }


def replay_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("files", nargs="+", metavar="FILE",
                        help="scenario files of any format read (WOMD, ScenarioNet, GPUDrive "
                             "JSON): files, directories, globs or name@N shards")
    parser.add_argument("--limit", type=int, default=None, help="replay at most N scenarios")
    parser.add_argument("--actor", choices=sorted(ACTORS), default="expert",
                        help="expert: the discretised expert; constant_velocity: a baseline")
    parser.add_argument("--offroad", choices=["point", "segment"], default="point",
                        help="offroad rule: Waymax's nearest point (default) or edge segments")
    parser.add_argument("--json", action="store_true", help="JSON lines only (no summary)")
    parser.add_argument("--out", default=None, metavar="DIR",
                        help="also write replay.jsonl, summary.json and config.json here")
    parser.add_argument("--gif", nargs="?", const="", default=None, metavar="PATH",
                        help="also write an animation of the first scenario's replay to PATH "
                             "(default when given without PATH: OUT/replay.gif, or replay.gif)")
    parser.add_argument("--seed", type=int, default=0, help="PRNG seed")
    add_egos_argument(parser)
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def _write_gif(path: str, final: SimState, progress: bool = True) -> None:
    states = [final.replace(timestep=jnp.int32(t)) for t in range(10, int(final.timestep) + 1)]
    render.write_rollout_animation(states, "full", path, jax.random.key(0), progress=progress)


def _replay_total(files: list[str], limit: int | None, egos: str = "sdc") -> int | None:
    """The replay bar's total: the scenarios of ``files`` up to ``limit`` (``limit`` if dear)."""
    total = count_scenarios(files, limit or 0, egos)
    return limit if total is None else total


def replay_command(args: argparse.Namespace) -> int:
    if args.out:
        require_folder(args.out)
    if args.limit is not None and args.limit < 1:
        raise ConfigError(f"--limit must be positive, got {args.limit}")
    params = SimParams(offroad_method=args.offroad)
    run = replay_fn(args.actor, params)
    key = jax.random.key(args.seed)
    records, t0 = [], time.perf_counter()
    with contextlib.ExitStack() as stack:
        # replay.jsonl is streamed into a temp file, published only if every scenario replayed
        out = (stack.enter_context(atomic_path(os.path.join(args.out, "replay.jsonl"), "w"))
               if args.out else None)
        quiet = args.json or args.no_progress
        total = None if quiet else _replay_total(args.files, args.limit, args.egos)
        bar = stack.enter_context(tqdm(total=total, desc="replay", unit="scn", file=sys.stderr,
                                       disable=quiet))
        for rec in open_scenarios(args.files, egos=args.egos):
            if args.limit is not None and len(records) >= args.limit:
                break
            try:
                check_scenario(rec.scenario)
            except DataError as err:
                raise DataError(err.problem, file=rec.file, record=rec.record) from None
            final, replay, log = jax.device_get(
                run(rec.scenario, jax.random.fold_in(key, len(records))))
            sid = decode_scenario_id(rec.scenario.scenario_id)
            record = {**scenario_record(sid, replay, log), "file": rec.file,
                      "record": rec.record, **(rec.source or {}),
                      **({} if rec.ego is None else {"logged_sdc": rec.ego["logged_sdc"]})}
            line = json.dumps(record)
            print(line, flush=True)
            if out is not None:
                out.write(line + "\n")
            if args.gif is not None and not records:
                _write_gif(args.gif or os.path.join(args.out or ".", "replay.gif"), final,
                           progress=not quiet)
            records.append(record)
            bar.update(1)
    elapsed = time.perf_counter() - t0
    summary = {**summarize(records, params.num_controlled_steps), "actor": args.actor,
               "offroad_method": args.offroad, "seconds": round(elapsed, 2)}
    if not args.json:
        print("summary: " + json.dumps(summary), file=sys.stderr)
    if args.out:
        config = {"command": "replay", "files": args.files, "limit": args.limit,
                  "actor": args.actor, "seed": args.seed, "sim_params": dataclasses.asdict(params),
                  **({} if args.egos == "sdc" else {"egos": args.egos})}
        atomic_write_json(os.path.join(args.out, "config.json"), config, indent=2)
        atomic_write_json(os.path.join(args.out, "summary.json"), summary, indent=2)
    return 0
