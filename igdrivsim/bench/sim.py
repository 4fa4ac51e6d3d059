"""``igdrivsim bench sim``: scenario-steps/s of reset + 80 steps with observation and metrics.

Two implementations of the same episode (same metrics and observations, tested): **naive**
(Waymax's offroad metric: SDC box corners against every roadgraph point, non-edges masked) and
**igdrivsim** (the road edges compacted once at reset). Both run the discretised expert with
the ``--obs`` observation (kept as a checksum so that XLA cannot drop it); ``--agents log,idm``
also times igdrivsim under IDM sim agents (``igdrivsim+idm``). Results: docs/bench/.

Not on :func:`igdrivsim.simulator.rollout.run_episode` on purpose: the scan carries only what
changes and keeps the log and the roadgraph as loop constants.
"""

from __future__ import annotations

import argparse
import itertools
import json
import time
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from tqdm import tqdm

from igdrivsim.data import load_scenario, read_scenarios
from igdrivsim.errors import ConfigError, check_min
from igdrivsim.io import atomic_write_json
from igdrivsim.machine import machine_record
from igdrivsim.observation import ObservationConfig, get_setting, observe
from igdrivsim.observation.commands import _data_path
from igdrivsim.simulator import dynamics
from igdrivsim.simulator.agents import AGENTS
from igdrivsim.simulator.metrics import step_metrics
from igdrivsim.simulator.roadgraph import road_edges_from_roadgraph
from igdrivsim.simulator.rollout import expert_discrete_action
from igdrivsim.simulator.state import SimParams, SimState, reset, step, vmap_batch

DEFAULT_PARAMS = SimParams()


def naive_reset(scenario: Any, params: SimParams = DEFAULT_PARAMS) -> SimState:
    """Reset with every roadgraph slot a road-edge candidate (non-edges masked), as in Waymax."""
    sc = jax.tree.map(jnp.asarray, scenario)
    tiny = SimParams(dynamics=params.dynamics, edge_capacity=1,
                     offroad_method=params.offroad_method)
    state = reset(sc, tiny)
    edges = vmap_batch(road_edges_from_roadgraph, np.ndim(state.timestep))
    return state.replace(roadgraph=sc.roadgraph, road_edges=edges(sc.roadgraph))


IMPLS = ("naive", "igdrivsim")


def episode(scenario: Any, key: jax.Array, *, impl: str = "igdrivsim",
            setting_name: str = "full", params: SimParams = DEFAULT_PARAMS,
            obs_config: ObservationConfig | None = None, collect: bool = False):
    """``(per-step metrics [B, T], observation checksum [B, T])`` of reset + the expert's
    controlled steps on a batch ``[B]`` by ``impl``; with ``collect`` also the observations
    ``[B, T, ...]`` (for the equivalence test)."""
    setting = get_setting(setting_name)
    obs_config = obs_config or ObservationConfig()
    state = naive_reset(scenario, params) if impl == "naive" else reset(scenario, params)
    episode_keys = jax.random.split(key, state.timestep.shape[0])

    def body(carry, _):
        sdc, t, agents = carry
        st = state.replace(sdc=sdc, timestep=t, agents=agents)
        step_keys = jax.vmap(jax.random.fold_in)(episode_keys, st.timestep)
        obs = jax.vmap(lambda s, e, k: observe(s, setting, e, k, obs_config))(
            st, episode_keys, step_keys)
        action = dynamics.undiscretize(expert_discrete_action(st, params))
        st = step(st, action, params)
        checksum = (jnp.sum(obs.roadgraph, axis=(-1, -2)) + jnp.sum(obs.objects, axis=(-1, -2))
                    + obs.sdc_speed[..., 0])
        out = (step_metrics(st, params), checksum)
        return (st.sdc, st.timestep, st.agents), (out + (obs,) if collect else out)

    _, outs = jax.lax.scan(body, (state.sdc, state.timestep, state.agents), None,
                           length=params.num_controlled_steps)
    return jax.tree.map(lambda a: jnp.moveaxis(a, 0, 1), outs)


def _batch(pool: list[Any], size: int) -> Any:
    """A batch ``[size]`` of the scenarios of ``pool``, cycled (one scenario: tiled)."""
    return jax.tree.map(lambda *a: np.stack(a), *[pool[i % len(pool)] for i in range(size)])


def time_episode(fn, scenario, key, repeats: int) -> tuple[float, float, float, Any]:
    """``(compile s, best wall s per call, best process-CPU s per call, last output)`` of a
    jitted episode function (CPU time measures the work even on shared cores)."""
    t0 = time.perf_counter()
    out = jax.block_until_ready(fn(scenario, key))
    compile_s = time.perf_counter() - t0
    best, best_cpu = float("inf"), float("inf")
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        out = jax.block_until_ready(fn(scenario, key))
        best = min(best, time.perf_counter() - t0)
        best_cpu = min(best_cpu, time.process_time() - c0)
    return compile_s, best, best_cpu, out


def bench_sim_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--data", default=None,
                        help="WOMD file, or folder with --distinct (default: the real tf.Example "
                             "sample in ../shared)")
    parser.add_argument("--record", type=int, default=0,
                        help="index of the record of --data tiled over each batch")
    parser.add_argument("--distinct", action="store_true",
                        help="fill each batch with different scenarios of --data (cycled when it "
                             "has fewer) instead of tiling --record")
    parser.add_argument("--batch-sizes", dest="batches", default="1,16,64,256",
                        help="comma-separated batch sizes (scenarios per call)")
    parser.add_argument("--obs", dest="setting", default="full", metavar="SETTING",
                        help="observation setting")
    parser.add_argument("--impls", default=",".join(IMPLS),
                        help=f"implementations to time (default {','.join(IMPLS)})")
    parser.add_argument("--agents", default="log,idm",
                        help="sim agents to time the igdrivsim path under (comma list of "
                             "log, idm; the naive path runs under log only)")
    parser.add_argument("--repeats", type=int, default=2, help="timed calls per cell (best)")
    parser.add_argument("--skip-naive-above", type=int, default=10**9,
                        help="do not time the naive path above this batch size")
    parser.add_argument("--out", default=None, help="also write the results to this JSON file")


def bench_sim_command(args) -> int:
    try:
        batches = [int(b) for b in args.batches.split(",") if b.strip()]
    except ValueError as err:
        raise ConfigError(f"--batch-sizes must be comma-separated integers, got {args.batches!r}"
                          ) from err
    if not batches or min(batches) < 1:
        raise ConfigError(f"--batch-sizes must be positive integers, got {args.batches!r}")
    check_min("--repeats", args.repeats, 1)
    get_setting(args.setting)
    path = _data_path(args)
    if args.distinct:
        pool = list(itertools.islice(read_scenarios(path), max(batches)))
        if not pool:
            raise ConfigError(f"--distinct: no scenarios in {path}")
    else:
        pool = [load_scenario(path, args.record)]
    key = jax.random.PRNGKey(0)
    impls, agents = _subset("--impls", args.impls, IMPLS), _subset("--agents", args.agents, AGENTS)
    cells = [(i, a) for i in impls for a in agents if i != "naive" or a == "log"]
    sims = {a: SimParams(agents=a) for a in agents}
    fns = {label(i, a): jax.jit(lambda sc, k, impl=i, p=sims[a]: episode(
        sc, k, impl=impl, setting_name=args.setting, params=p)) for i, a in cells}
    steps = DEFAULT_PARAMS.num_controlled_steps
    rows: list[dict] = []
    with tqdm(total=len(batches) * len(fns), desc="bench sim", unit="cell") as bar:
        for b in batches:
            sc = _batch(pool, b)
            for name, fn in fns.items():
                if name == "naive" and b > args.skip_naive_above:
                    bar.update()
                    continue
                compile_s, sec, cpu, (metrics, _) = time_episode(fn, sc, key, args.repeats)
                rows.append({
                    "batch": b, "impl": name, "agents": "idm" if name.endswith("+idm") else "log",
                    "scenario_steps_per_s": round(b * steps / sec, 1),
                    "scenario_steps_per_cpu_s": round(b * steps / cpu, 1),
                    "seconds_per_call": round(sec, 4), "cpu_seconds_per_call": round(cpu, 4),
                    "first_call_s": round(compile_s, 2),
                    "overlap_steps": int(np.sum(metrics.overlap[0])),
                    "offroad_steps": int(np.sum(metrics.offroad[0])),
                    "device": jax.devices()[0].platform, "setting": args.setting})
                bar.update()
                tqdm.write(json.dumps(rows[-1]))
    names = list(fns)
    print("scenario-steps per second (wall clock):")
    print(format_table(rows, names))
    print("scenario-steps per CPU-second of this process (robust to a shared CPU):")
    print(format_table(rows, names, "scenario_steps_per_cpu_s"))
    if args.out:
        atomic_write_json(args.out, {"data": path, "distinct": args.distinct, "rows": rows,
                                     "jax": jax.__version__, "steps_per_episode": steps,
                                     "setting": args.setting, "machine": machine_record()})
    return 0


def _subset(option: str, text: str, allowed) -> list[str]:
    """The names of a comma list, each one of ``allowed`` (a one-line error otherwise)."""
    names = [n.strip() for n in text.split(",") if n.strip()]
    if not names or any(n not in allowed for n in names):
        raise ConfigError(f"{option} must be a comma-separated subset of {','.join(allowed)}")
    return names


def label(impl: str, agents: str) -> str:
    return impl if agents == "log" else f"{impl}+{agents}"


def format_table(rows: list[dict], impls: list[str], field: str = "scenario_steps_per_s") -> str:
    """A plain-text table: ``field`` per batch and implementation, the speedup over naive, and
    the cost of IDM agents (log / idm rate: how many times slower a step is under IDM)."""
    head = f"{'batch':>6}" + "".join(f" {i:>15}" for i in impls)
    others = ([i for i in impls if i != "naive" and not i.endswith("+idm")]
              if "naive" in impls else [])
    head += "".join(f" {i + '/naive':>12}" for i in others)
    idm = [i for i in impls if i.endswith("+idm") and i[:-4] in impls]
    head += "".join(f" {'idm cost':>9}" for _ in idm)
    lines = [head]
    for b in sorted({r["batch"] for r in rows}):
        rate = {r["impl"]: r[field] for r in rows if r["batch"] == b}
        line = f"{b:>6}" + "".join(
            f" {rate[i]:>15,.0f}" if i in rate else f" {'-':>15}" for i in impls)
        line += "".join(f" {rate[i] / rate['naive']:>11.1f}x" if "naive" in rate and i in rate
                        else f" {'-':>12}" for i in others)
        line += "".join(f" {rate[i[:-4]] / rate[i]:>8.2f}x" if i in rate and i[:-4] in rate
                        else f" {'-':>9}" for i in idm)
        lines.append(line)
    return "\n".join(lines)
