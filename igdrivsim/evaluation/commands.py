"""``igdrivsim evaluate``: every seed of trained runs and (``--references``) the discretised
expert and constant velocity on validation scenarios (:mod:`igdrivsim.evaluation.evaluate`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from igdrivsim.core.devices import maybe_init_distributed
from igdrivsim.data.egos import add_egos_argument
from igdrivsim.data.manifest import MANIFEST
from igdrivsim.errors import ConfigError
from igdrivsim.evaluation.evaluate import evaluate_references, evaluate_run
from igdrivsim.io import require_folder
from igdrivsim.policy.act import ACTION_MODES
from igdrivsim.simulator.agents import AGENTS
from igdrivsim.training.run import Run


def evaluate_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("runs", nargs="*", metavar="RUN_DIR",
                        help="training run folder(s) (config.json + checkpoints); one output "
                             "sub-folder per run when several are given")
    parser.add_argument("--data", required=True, nargs="+", metavar="DATA",
                        help=f"validation data: a filter output folder ({MANIFEST}) or "
                             "files of any format read (WOMD TFRecords, ScenarioNet .pkl, "
                             "GPUDrive .json; file, folder, glob, name@N); several locations "
                             "are read in turn, as one set")
    parser.add_argument("--out", required=True, help="output folder for the tidy CSVs")
    parser.add_argument("--actions", choices=ACTION_MODES, default="sample",
                        help="how the policy picks its action level: sample (the paper's "
                             "protocol), greedy (most likely), mean (expected level, a "
                             "diagnostic without the sampling noise)")
    parser.add_argument("--references", action="store_true",
                        help="also evaluate the discretised expert and constant velocity")
    parser.add_argument("--like", default=None, metavar="RUN_DIR",
                        help="for --references without RUN_DIR: use this run's data "
                             "capacities and simulator settings")
    parser.add_argument("--agents", choices=AGENTS, default=None,
                        help="who moves the other objects: log (replay, the paper's) or idm "
                             "(reactive IDM vehicles on their logged paths); default: the "
                             "run's own setting (log)")
    parser.add_argument("--limit", dest="max_scenarios", type=int, default=0, metavar="N",
                        help="evaluate at most N validation scenarios (0: all)")
    add_egos_argument(parser)
    parser.add_argument("--batch-size", type=int, default=32, help="scenarios per batch")
    parser.add_argument("--seed", type=int, default=0, help="evaluation key (actions, noise)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def evaluate_command(args: argparse.Namespace) -> int:
    if not args.runs and not args.references:
        raise ConfigError("give at least one RUN_DIR, or --references")
    require_folder(args.out)
    maybe_init_distributed()  # several hosts: the scenarios are spread over all their devices
    for run in args.runs:
        Run.open(run)  # every folder is a run before any is evaluated
    progress = not args.no_progress
    data = args.data[0] if len(args.data) == 1 else args.data  # several: read in turn
    for run in args.runs:
        out = Path(args.out) / Path(run).name if len(args.runs) > 1 else Path(args.out)
        evaluate_run(run, data, out, args.actions, args.max_scenarios, args.batch_size,
                     args.seed, progress, egos=args.egos, agents=args.agents)
        print(f"wrote {out}/per_step.csv, {out}/per_scenario.csv")
    if args.references:
        sim = caps = None
        like = args.runs[0] if args.runs else args.like
        if like:  # the same capacities and simulator settings as that run
            config = Run.open(like).config
            caps, sim = config.capacities, config.sim_params
        out = Path(args.out) / "references" if args.runs else Path(args.out)
        evaluate_references(data, out, caps, sim, args.max_scenarios, args.batch_size,
                            progress, egos=args.egos, agents=args.agents)
        print(f"wrote {out}/per_step.csv, {out}/per_scenario.csv")
    return 0
