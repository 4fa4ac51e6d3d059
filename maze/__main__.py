"""``python -m maze --out DIR [--seeds 10] [--quick]``: the maze study (see :mod:`maze.study`).

``--quick`` runs the seconds-long smoke profile. The final returns per curve are in
``DIR/tables/maze_summary.csv`` (``curve,final_return_mean,final_return_ci95,final_length_mean,
final_length_ci95,seeds``).
"""

from __future__ import annotations

import argparse
import sys

from igdrivsim.cli_args import DefaultsFormatter
from igdrivsim.errors import run_command
from maze import study


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m maze", description=__doc__.split("\n")[0],
                                     formatter_class=DefaultsFormatter)
    study.study_arguments(parser)
    parser.add_argument("--quick", action="store_true", help="tiny smoke run (seconds)")
    args = parser.parse_args(argv)
    if args.quick:
        args.profile = "smoke"

    def body() -> None:
        if args.compile_cache:
            study.use_compile_cache(args.work / "xla-cache")
        study.run_study(study.resolve(args), args.out, args.work, args.force,
                        progress=not args.no_progress,
                        command=study.command_text("python -m maze", argv))

    return run_command("maze", body)


if __name__ == "__main__":
    sys.exit(main())
