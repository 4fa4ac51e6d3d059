"""``igdrivsim evaluate`` and ``igdrivsim report``.

``igdrivsim evaluate RUN_DIR --data DIR --out DIR [--actions sample|greedy|mean]
[--references]`` evaluates every seed of a trained run on the validation scenarios of ``DIR``
under the run's own observation setting and writes ``OUT/per_step.csv``,
``OUT/per_scenario.csv`` and ``OUT/eval_config.json``.
``--references`` also (or, without RUN_DIR, only) evaluates the discretised expert replay and the
constant-velocity baseline (into ``OUT/references/`` when a run is evaluated too).

``igdrivsim report --evals DIR... --out DIR`` aggregates every evaluation found under the
``--evals`` folders into Table I, the comparison with the paper and Fig. 3, then writes the
run's results page (``--results``, default ``OUT/results.md``) and, with ``--readme FILE``, fills
that file's results block, and the PDF's result macros (``OUT/generated/results.tex``,
``OUT/generated/maze.tex``); ``--from-tables`` rewrites only those from ``OUT``'s tables.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
from pathlib import Path

import jax
from tqdm import tqdm

from igdrivsim.cli_args import deprecated_alias
from igdrivsim.data import Capacities
from igdrivsim.data.validation import load_validation
from igdrivsim.errors import ConfigError, DataError
from igdrivsim.evaluation.results_doc import write_markdown, write_run_times
from igdrivsim.evaluation.rollout import (
    evaluate_policy,
    reference_frames,
    scenario_ids_of,
    tidy_frames,
)
from igdrivsim.io import atomic_write_csv, atomic_write_json, require_folder
from igdrivsim.observation import ObservationConfig
from igdrivsim.policy.act import ACTION_MODES
from igdrivsim.simulator import SimParams
from igdrivsim.training.config import from_dict
from igdrivsim.training.update import run_settings, sim_params

EVAL_CONFIG = "eval_config.json"


# ------------------------------------------------------------------------------ data, runs
def load_trained(run_dir: str):
    """``(RunConfig, stacked parameters [G, S], seed list)`` of a training run folder."""
    # lazy: the training loop pulls in orbax and grain; `report` needs neither
    from igdrivsim.training.loop import load_run

    config, params = load_run(run_dir)
    seeds = list(range(config.training.seed_offset,
                       config.training.seed_offset + config.training.seeds))
    return config, params, seeds


def data_capacities(config):
    return Capacities(max_objects=config.data.max_objects,
                      max_roadgraph_points=config.data.max_roadgraph_points)


def _bar(total: int, desc: str, enabled: bool):
    return tqdm(total=total, desc=desc, unit="scenario", disable=not enabled,
                file=sys.stderr, dynamic_ncols=True)


# -------------------------------------------------------------------------------- evaluate
def evaluate_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("runs", nargs="*", metavar="RUN_DIR",
                        help="training run folder(s) (config.json + checkpoints); one output "
                             "sub-folder per run when several are given")
    parser.add_argument("--data", required=True,
                        help="validation data: a filter output folder (manifest.jsonl) or WOMD "
                             "files (file, folder, glob, name@N)")
    parser.add_argument("--out", required=True, help="output folder for the tidy CSVs")
    parser.add_argument("--actions", choices=ACTION_MODES, default="sample",
                        help="how the policy picks its action level: sample (the paper's "
                             "protocol), greedy (most likely), mean (expected level, a "
                             "diagnostic without the sampling noise)")
    parser.add_argument("--greedy", dest="actions", action="store_const", const="greedy",
                        help="same as --actions greedy")
    parser.add_argument("--references", action="store_true",
                        help="also evaluate the discretised expert and constant velocity")
    parser.add_argument("--like", default=None, metavar="RUN_DIR",
                        help="for --references without RUN_DIR: use this run's data "
                             "capacities and simulator settings")
    parser.add_argument("--limit", dest="max_scenarios", type=int, default=0, metavar="N",
                        help="evaluate at most N validation scenarios (0: all)")
    deprecated_alias(parser, "--max-scenarios", "max_scenarios", type=int)
    parser.add_argument("--batch-size", type=int, default=32, help="scenarios per batch")
    parser.add_argument("--seed", type=int, default=0, help="evaluation key (actions, noise)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def _check_sizes(max_scenarios: int, batch_size: int) -> None:
    """``--limit`` (0: every scenario) and ``--batch-size`` before anything is read."""
    if max_scenarios < 0:
        raise ConfigError(f"--limit must be >= 1 (or 0 for every scenario), got {max_scenarios}")
    if batch_size < 1:
        raise ConfigError(f"--batch-size must be >= 1, got {batch_size}")


def evaluate_run(run_dir: str, data: str, out: str | Path, actions: str = "sample",
                 max_scenarios: int = 0, batch_size: int = 32, seed: int = 0,
                 progress: bool = True, scenarios=None) -> Path:
    """Evaluate every seed of ``run_dir``; write the tidy CSVs and ``eval_config.json``.

    ``scenarios`` (stacked, already fitted to the run's capacities) skips reading ``data``.
    """
    import pandas as pd  # heavy: pandas is needed only here

    _check_sizes(max_scenarios, batch_size)
    config, params, seeds = load_trained(run_dir)
    if scenarios is None:
        scenarios = load_validation(data, data_capacities(config), max_scenarios, progress)
    ids = scenario_ids_of(scenarios)
    settings, method = run_settings(config), config.training.method
    obs_config = ObservationConfig(config.observation.num_objects,
                                   config.observation.num_roadgraph_points)
    label = ",".join(settings)
    with _bar(len(ids), f"evaluate {label}/{method}", progress) as bar:
        outputs = evaluate_policy(params, scenarios, policy_config=config.policy,
                                  setting=settings, obs_config=obs_config,
                                  params=sim_params(config), actions=actions,
                                  batch_size=batch_size, seed=seed, progress=bar.update,
                                  episode_metrics=True)
    frames = [tidy_frames(outputs.map(lambda a, g=g: a[g]), ids, name, method, seeds)
              for g, name in enumerate(settings)]
    per_step = pd.concat([f[0] for f in frames], ignore_index=True)
    per_scenario = pd.concat([f[1] for f in frames], ignore_index=True)
    return _write(out, per_step, per_scenario, dict(
        run=str(run_dir), data=str(data), setting=label, settings=settings, method=method,
        seeds=seeds, profile=config.profile, actions=actions, eval_seed=seed,
        num_scenarios=len(ids), sim=dataclasses.asdict(sim_params(config))))


def evaluate_references(data: str, out: str | Path, caps=None, sim=None,
                        max_scenarios: int = 0, batch_size: int = 32, progress: bool = True,
                        scenarios=None) -> Path:
    """Evaluate the discretised expert and constant velocity; write their tidy CSVs."""
    _check_sizes(max_scenarios, batch_size)
    caps = caps or Capacities()
    sim = sim or SimParams()
    if scenarios is None:
        scenarios = load_validation(data, caps, max_scenarios, progress)
    n = int(scenarios.scenario_id.shape[0])
    with _bar(2 * n, "evaluate references", progress) as bar:
        per_step, per_scenario = reference_frames(scenarios, sim, batch_size,
                                                  progress=bar.update)
    return _write(out, per_step, per_scenario, dict(
        references=True, data=str(data), num_scenarios=n, sim=dataclasses.asdict(sim)))


def _read_json(path: Path) -> dict:
    try:
        return json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise DataError(f"cannot read JSON ({err})", file=str(path)) from err


def _write(out, per_step, per_scenario, info: dict) -> Path:
    """Write the tidy CSVs and the evaluation record (process 0 only when several processes
    evaluate together: they all hold the same gathered outputs)."""
    out = Path(out)
    if jax.process_index() != 0:
        return out
    atomic_write_csv(out / "per_step.csv", per_step.round(6))
    atomic_write_csv(out / "per_scenario.csv", per_scenario.round(6))
    atomic_write_json(out / EVAL_CONFIG, info, indent=2, sort_keys=True)
    return out


def evaluate_command(args: argparse.Namespace) -> int:
    if not args.runs and not args.references:
        raise ConfigError("give at least one RUN_DIR, or --references")
    require_folder(args.out)
    # lazy: with the training loop (orbax, grain), which `report` does not need
    from igdrivsim.training.commands import maybe_init_distributed

    maybe_init_distributed()  # several hosts: the scenarios are spread over all their devices
    for run in args.runs:
        if not (Path(run) / "config.json").is_file():
            raise DataError("not a training run folder (no config.json)", file=run)
    progress = not args.no_progress
    for run in args.runs:
        out = Path(args.out) / Path(run).name if len(args.runs) > 1 else Path(args.out)
        evaluate_run(run, args.data, out, args.actions, args.max_scenarios, args.batch_size,
                     args.seed, progress)
        print(f"wrote {out}/per_step.csv, {out}/per_scenario.csv")
    if args.references:
        sim = caps = None
        like = args.runs[0] if args.runs else args.like
        if like:  # the same capacities and simulator settings as that run
            record = _read_json(Path(like) / "config.json")
            config = from_dict(record.get("config", record))
            caps, sim = data_capacities(config), sim_params(config)
        out = Path(args.out) / "references" if args.runs else Path(args.out)
        evaluate_references(args.data, out, caps, sim, args.max_scenarios, args.batch_size,
                            progress)
        print(f"wrote {out}/per_step.csv, {out}/per_scenario.csv")
    return 0


# ---------------------------------------------------------------------------------- report
def report_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--evals", nargs="+", default=None, metavar="DIR",
                        help="folders holding per_scenario.csv / per_step.csv (searched "
                             "recursively); required unless --from-tables")
    parser.add_argument("--from-tables", action="store_true",
                        help="only rewrite the markdown (--results, --readme) and the PDF's "
                             "result macros (generated/results.tex, generated/maze.tex) from the "
                             "tables already in --out, without the evaluations")
    parser.add_argument("--results", default=None, metavar="FILE",
                        help="the run's results page (markdown; default: OUT/results.md)")
    parser.add_argument("--readme", default=None, metavar="FILE",
                        help="also fill this file's <!-- results:begin/end --> block with the "
                             "headline table (e.g. README.md)")
    parser.add_argument("--work", default=None, metavar="DIR",
                        help="the pipeline's work folder: its stage times go into "
                             "OUT/tables/run_times.csv")
    parser.add_argument("--out", default="paper",
                        help="report folder: writes OUT/tables/* and OUT/figures/fig3_metrics.* "
                             "(default: paper)")
    parser.add_argument("--profile", default=None,
                        help="profile named in the tables (default: read from the evaluations)")
    parser.add_argument("--data-label", default=None,
                        help="data named in the tables (default: read from the evaluations)")
    parser.add_argument("--runs", nargs="+", default=None, metavar="DIR",
                        help="training runs (or folders of runs) whose curves.jsonl make the "
                             "learning-curve figure (default: the runs/ folder next to each "
                             "--evals folder)")


def _provenance_from(eval_dirs: list[str]) -> tuple[str, str]:
    profiles, data = set(), set()
    for root in eval_dirs:
        for path in Path(root).rglob(EVAL_CONFIG):
            info = _read_json(path)
            if not isinstance(info, dict):
                raise DataError("not an evaluation record (expected a JSON object)",
                                file=str(path))
            if "profile" in info:
                profiles.add(str(info["profile"]))
            if "data" in info:
                data.add(os.path.basename(os.path.normpath(str(info["data"]))) or info["data"])
    return (", ".join(sorted(profiles)) or "unknown", ", ".join(sorted(data)) or "unknown")


def report_command(args: argparse.Namespace) -> int:
    require_folder(args.out)
    written = []
    if not args.from_tables:
        if not args.evals:
            raise ConfigError("report: give --evals DIR... (or --from-tables to rewrite only "
                              "the markdown from OUT's tables)")
        # lazy: the report's figures module sets matplotlib's backend when imported
        from igdrivsim.evaluation.report import Provenance, build_report

        profile, data = _provenance_from(args.evals)
        prov = Provenance(profile=args.profile or profile, data=args.data_label or data)
        written = build_report(args.evals, args.out, prov, run_dirs=args.runs)
        if args.work:
            written += write_run_times(args.work, Path(args.out) / "tables")
    written += write_markdown(args.out, args.results, args.readme)
    for path in written:
        print(f"wrote {path}")
    return 0
