"""The ``igdrivsim`` console script.

Each subcommand lives next to the code it drives; a command module defines
``<name>_arguments(parser)`` and ``<name>_command(args) -> int``. Modules are imported only when
their command runs, so ``igdrivsim --help`` stays instant.
"""

from __future__ import annotations

import argparse
import importlib
import sys
import warnings

from igdrivsim.cli_args import DefaultsFormatter
from igdrivsim.errors import run_command

# name -> (module, help)
COMMANDS: dict[str, tuple[str, str]] = {
    "inspect": ("igdrivsim.data.commands", "print one JSON line per scenario in WOMD files"),
    "generate": ("igdrivsim.data.synthetic.commands", "write synthetic WOMD-format shards"),
    "samples": ("igdrivsim.data.samples", "fetch and verify public real WOMD samples (pip)"),
    "filter": ("igdrivsim.data.commands", "apply the paper's scenario filter, write a manifest"),
    "stats": ("igdrivsim.data.stats_command", "scene statistics of any data, beside each other"),
    "cv-divergence": ("igdrivsim.data.synthetic.calibration",
                      "the logged SDC's constant-velocity divergence per data set"),
    "replay": ("igdrivsim.observation.replay", "replay the discretised expert, report metrics"),
    "render": ("igdrivsim.observation.commands", "draw the observation models and a rollout"),
    "train": ("igdrivsim.training.commands",
              "train policies with a registered learning method (--method)"),
    "teacher": ("igdrivsim.training.privileged",
                "pick DAgger's and ADVISOR's privileged teacher among finished runs"),
    "evaluate": ("igdrivsim.evaluation.commands", "evaluate a trained run on validation data"),
    "speed-walk": ("igdrivsim.evaluation.speed_walk",
                   "the speed random walk of the discretised expert's labels (no policy)"),
    "report": ("igdrivsim.report.commands", "aggregate evaluations into tables and figures"),
    "plan": ("igdrivsim.pipeline.planning", "a reproduction's estimated wall time per core count"),
}
# `igdrivsim bench NAME`
BENCHES: dict[str, tuple[str, str]] = {
    "data": ("igdrivsim.bench.data", "scenarios/s read and decoded"),
    "sim": ("igdrivsim.bench.sim", "scenario-steps/s of reset + 80 steps"),
    "train": ("igdrivsim.bench.train", "training updates/s and scenario-steps/s"),
    "pipeline": ("igdrivsim.bench.pipeline", "a reproduction's core-seconds per stage"),
}


def _add(sub, name: str, module: str, help_: str, prefix: str = "") -> None:
    parser = sub.add_parser(name, help=help_, description=help_, formatter_class=DefaultsFormatter)
    func = prefix + name.replace("-", "_")  # the module's <func>_arguments and <func>_command
    # _configure: only the chosen command's (heavy) module is imported, to add its arguments
    parser.set_defaults(_module=module, _name=func, _label=f"{prefix.replace('_', ' ')}{name}",
                        _configure=lambda p=parser: getattr(
                            importlib.import_module(module), f"{func}_arguments")(p))


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="igdrivsim", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    for name, (module, help_) in COMMANDS.items():
        _add(sub, name, module, help_)
    bench = sub.add_parser("bench", help="speed benchmarks",
                           description="speed benchmarks: igdrivsim bench {data,sim,train,pipeline}"
                           ).add_subparsers(dest="bench", required=True)
    for name, (module, help_) in BENCHES.items():
        _add(bench, name, module, help_, prefix="bench_")
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    # Two passes: find the command, let its module add arguments, then parse for real.
    first = [a for a in argv if a not in ("-h", "--help")]
    if not first or first == ["bench"]:
        parser.parse_args(argv)  # prints usage (or help) and exits
    known, _ = parser.parse_known_args(first)
    known._configure()
    args = parser.parse_args(argv)
    name = args._label
    # warnings (a skipped bad record, ...) as one line each, not with their source line
    warnings.formatwarning = lambda message, *_, **__: f"igdrivsim {name}: warning: {message}\n"
    try:
        return run_command(f"igdrivsim {name}", lambda: getattr(
            importlib.import_module(args._module), f"{args._name}_command")(args))
    except KeyboardInterrupt:
        print(f"igdrivsim {name}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
