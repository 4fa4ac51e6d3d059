"""Evaluate a trained run (every seed) or the reference actors on validation scenarios and
write the tidy ``per_step.csv``, ``per_scenario.csv`` and ``eval_config.json``."""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import jax
import pandas as pd
from tqdm import tqdm

from igdrivsim.data import Capacities
from igdrivsim.data.source import load_scenarios
from igdrivsim.errors import ConfigError, check_min
from igdrivsim.evaluation import registry
from igdrivsim.evaluation.rollout import (
    reference_frames,
    scenario_ids_of,
    tidy_frames,
    with_origins,
)
from igdrivsim.evaluation.schema import EVAL_CONFIG, PER_SCENARIO_FILE, PER_STEP_FILE
from igdrivsim.io import atomic_write_csv, atomic_write_json
from igdrivsim.machine import code_state
from igdrivsim.policy.closed_loop import evaluate_policy
from igdrivsim.simulator import SimParams
from igdrivsim.training.run import Run

# what the evaluation record says of the code, scenarios and updates that trained the run
TRAINED_KEYS = ("code", "code_resumed", "num_scenarios", "num_updates")


def _bar(total: int, desc: str, enabled: bool):
    return tqdm(total=total, desc=desc, unit="scenario", disable=not enabled,
                file=sys.stderr, dynamic_ncols=True)


def _check_sizes(max_scenarios: int, batch_size: int) -> None:
    """``--limit`` (0: every scenario) and ``--batch-size`` before anything is read."""
    if max_scenarios < 0:
        raise ConfigError(f"--limit must be >= 1 (or 0 for every scenario), got {max_scenarios}")
    check_min("--batch-size", batch_size, 1)


def evaluate_run(run_dir: str, data, out: str | Path, actions: str = "sample",
                 max_scenarios: int = 0, batch_size: int = 32, seed: int = 0,
                 progress: bool = True, egos: str = "sdc", agents: str | None = None) -> Path:
    """Evaluate every seed of ``run_dir``; write the tidy CSVs and ``eval_config.json``."""
    _check_sizes(max_scenarios, batch_size)
    run = Run.open(run_dir)
    config, params, seeds = run.config, run.params(), list(run.config.seeds)
    sim = with_agents(config.sim_params, agents)
    # origins: where each scenario comes from (the per-scenario rows' source)
    scenarios, origins = load_scenarios(data, config.capacities, max_scenarios, progress, egos)
    ids = scenario_ids_of(scenarios)
    settings, method = list(config.settings), config.training.method
    label = ",".join(settings)
    with _bar(len(ids), f"evaluate {label}/{method}", progress) as bar:
        outputs = evaluate_policy(params, scenarios, policy_config=config.policy,
                                  setting=settings, obs_config=config.obs_config, params=sim,
                                  actions=actions, batch_size=batch_size, seed=seed,
                                  progress=bar.update, episode_metrics=registry.episode_values)
    frames = [tidy_frames(outputs.map(lambda a, g=g: a[g]), ids, name, method, seeds)
              for g, name in enumerate(settings)]
    steps, scens = zip(*frames, strict=True)
    return _write(
        out, pd.concat(steps, ignore_index=True), pd.concat(scens, ignore_index=True), origins,
        egos, run=str(run_dir), data=str(data), setting=label, settings=settings, method=method,
        seeds=seeds, profile=config.profile, actions=actions, eval_seed=seed,
        num_scenarios=len(ids), sim=dataclasses.asdict(sim),
        trained={k: run.record[k] for k in TRAINED_KEYS if k in run.record})


def evaluate_references(data, out: str | Path, caps=None, sim=None,
                        max_scenarios: int = 0, batch_size: int = 32, progress: bool = True,
                        egos: str = "sdc", agents: str | None = None) -> Path:
    """Evaluate the discretised expert and constant velocity (``agents`` None: ``sim``'s)."""
    _check_sizes(max_scenarios, batch_size)
    caps = caps or Capacities()
    sim = with_agents(sim or SimParams(), agents)
    scenarios, origins = load_scenarios(data, caps, max_scenarios, progress, egos)
    n = int(scenarios.scenario_id.shape[0])
    with _bar(2 * n, "evaluate references", progress) as bar:
        per_step, per_scenario = reference_frames(scenarios, sim, batch_size,
                                                  progress=bar.update)
    return _write(out, per_step, per_scenario, origins, egos, references=True, data=str(data),
                  num_scenarios=n, sim=dataclasses.asdict(sim))


def with_agents(sim: SimParams, agents: str | None) -> SimParams:
    return sim if agents is None else dataclasses.replace(sim, agents=agents)


def _write(out, per_step, per_scenario, origins, egos: str, **info) -> Path:
    """Write the tidy CSVs (with the ``origins``) and the record ``info`` (process 0 only)."""
    out = Path(out)
    if jax.process_index() != 0:
        return out
    atomic_write_csv(out / PER_STEP_FILE, per_step.round(6))
    atomic_write_csv(out / PER_SCENARIO_FILE, with_origins(per_scenario, origins).round(6))
    if egos != "sdc":
        info["egos"] = egos
    atomic_write_json(out / EVAL_CONFIG, {**info, "code": code_state()}, indent=2,
                      sort_keys=True)
    return out
