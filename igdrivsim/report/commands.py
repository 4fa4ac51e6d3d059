"""``igdrivsim report --evals DIR... --out DIR`` aggregates every evaluation found under the
``--evals`` folders into Table I, the comparison with the paper and Fig. 3, then writes the
run's results page (``--results``, default ``OUT/results.md``) and, with ``--readme FILE``, fills
that file's results block, and the PDF's result macros (``OUT/generated/results.tex``,
``OUT/generated/maze.tex``); ``--from-tables`` rewrites only those from ``OUT``'s tables.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from igdrivsim.errors import ConfigError, DataError
from igdrivsim.evaluation.schema import EVAL_CONFIG
from igdrivsim.io import read_json, require_folder
from igdrivsim.report.results_doc import write_markdown, write_run_times


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
            info = read_json(path)
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
        from igdrivsim.report.build import Provenance, build_report

        profile, data = _provenance_from(args.evals)
        prov = Provenance(profile=args.profile or profile, data=args.data_label or data)
        written = build_report(args.evals, args.out, prov, run_dirs=args.runs)
        if args.work:
            written += write_run_times(args.work, Path(args.out) / "tables")
    written += write_markdown(args.out, args.results, args.readme)
    for path in written:
        print(f"wrote {path}")
    return 0
