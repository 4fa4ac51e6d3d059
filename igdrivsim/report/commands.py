"""``igdrivsim report --evals DIR... --out DIR``: the report's tables and figures, the results
page, the README's block and the PDF's macros (``--from-tables``: only the last three, from
``OUT``'s tables). ``igdrivsim report ACTION``: a side tool (:data:`ACTIONS`), imported when run.
"""

from __future__ import annotations

import argparse
import importlib
import os
from pathlib import Path

from igdrivsim.cli_args import DefaultsFormatter
from igdrivsim.errors import ConfigError
from igdrivsim.evaluation.schema import EVAL_CONFIG
from igdrivsim.io import atomic_write_text, read_json, require_folder
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
    actions = parser.add_subparsers(dest="action", metavar="ACTION")
    for name, (help_, arguments, _) in ACTIONS.items():
        action = actions.add_parser(name, help=help_, description=help_,
                                    formatter_class=DefaultsFormatter)
        for flags, keywords in arguments:
            action.add_argument(*flags, **keywords)


def _provenance_from(eval_dirs: list[str]) -> tuple[str, str]:
    profiles, data = set(), set()
    for root in eval_dirs:
        for path in Path(root).rglob(EVAL_CONFIG):
            info = read_json(path)  # a DataError naming the file unless a JSON object
            if "profile" in info:
                profiles.add(str(info["profile"]))
            if "data" in info:
                data.add(os.path.basename(os.path.normpath(str(info["data"]))) or info["data"])
    return (", ".join(sorted(profiles)) or "unknown", ", ".join(sorted(data)) or "unknown")


def report_command(args: argparse.Namespace) -> int:
    if args.action:
        return ACTIONS[args.action][2](args) or 0
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
    _wrote(written + write_markdown(args.out, args.results, args.readme))
    return 0


def _module(name: str):
    return importlib.import_module(f"igdrivsim.report.{name}")


def _print_or_write(text: str, out: Path | None, end: str = "\n") -> None:
    if out:
        atomic_write_text(out, text)
    print(text, end=end)


def _wrote(paths) -> None:
    for path in paths:
        print(f"wrote {path}")


def _transfer(args) -> None:
    transfer = _module("transfer")
    found = transfer.evaluations(args.work)
    _print_or_write(transfer.markdown(
        transfer.against_constant_velocity(found), transfer.between_motions(found),
        transfer.code_lines(args.work), transfer.ego_by_ego(found)), args.out, end="")


REPO = Path(__file__).resolve().parents[2]
MARKDOWN_OUT = (("--out",), dict(type=Path, help="also write the markdown here"))
# igdrivsim report ACTION: (help, its arguments as ((flags...), add_argument keywords), command)
ACTIONS = {
    "compare": ("two runs' Table I conclusions side by side (OLD_TABLES NEW_TABLES)", (
        (("old",), dict(type=Path, help="report tables folder (summary.csv, tests.csv)")),
        (("new",), dict(type=Path, help="the same for the run compared with it")),
        (("--labels",), dict(nargs=2, default=("old", "new"), metavar=("OLD", "NEW"),
                             help="the two runs' names in the table")),
        MARKDOWN_OUT),
        lambda args: _print_or_write(_module("compare").compare_markdown(
            args.old, args.new, tuple(args.labels)), args.out)),
    "figures": ("redraw Fig. 3, 5 and 6 from the report's tables (PAPER/tables/*.csv)",
                ((("paper",), dict(nargs="?", default="paper", help="the report folder")),),
                lambda args: _wrote(_module("figures").redraw_from_tables(args.paper))),
    "provenance": ("check or record the entries of PAPER/provenance.json (which command wrote "
                   "each report file)", (
        (("task",), dict(choices=("check", "derived", "maze"), help="check the entries, record "
                         "derived files, or record a maze study run alone")),
        (("files",), dict(nargs="*", metavar="FILE",
                          help="derived: the files written (relative to --paper)")),
        (("--from",), dict(dest="source", default=None, metavar="SOURCE", help="derived: the "
                           "file (relative to --paper) whose numbers they hold")),
        (("--command",), dict(default=None, help="derived: the command that wrote them")),
        (("--paper",), dict(default=str(REPO / "paper"), help="the report folder"))),
        lambda args: _module("provenance").provenance_command(args, REPO)),
    "reactive": ("Table I's companion under IDM sim agents: tables/reactive.{md,csv}, Fig. 7", (
        (("--log",), dict(nargs="+", required=True, metavar="DIR",
                          help="evaluations with log-replay agents (Table I's)")),
        (("--idm",), dict(nargs="+", required=True, metavar="DIR",
                          help="the same drivers evaluated with --agents idm")),
        (("--out",), dict(required=True, help="report folder (tables/, figures/)"))),
        lambda args: _wrote(_module("reactive").build(args.log, args.idm, args.out))),
    "real-logs": ("synthetic-trained drivers on real logs: real_logs.{md,tex,csv}", (
        (("--real",), dict(required=True, help="evaluations on real logs (folder)")),
        (("--synthetic",), dict(dest="validation", default=None,
                                help="evaluations on the (synthetic) validation set (folder)")),
        (("--readouts",), dict(default=None, metavar="DIR", help="Full BC evaluated on the "
                               "real logs under other action read-outs (one folder each: "
                               "igdrivsim evaluate --actions greedy|mean)")),
        (("--out",), dict(required=True, help="tables folder")),
        (("--real-label",), dict(default="real scenarios", help="what the real data are")),
        (("--synthetic-label",), dict(dest="validation_label",
                                      default="synthetic validation scenarios",
                                      help="what the validation data are"))),
        lambda args: print("wrote " + ", ".join(map(str, _module("real_logs").write_tables(
            args.real, args.validation, args.out, args.real_label, args.validation_label,
            args.readouts))))),
    "sweep": ("a sweep of training variants in one table (compute and metrics)", (
        (("sweep",), dict(type=Path, help="sweep folder (runs/NAME, evals/NAME)")),
        (("--references",), dict(type=Path, default=None, metavar="EVAL_DIR", help="`igdrivsim "
                                 "evaluate --references` output on the same data (none: no "
                                 "ratio to constant velocity)")),
        MARKDOWN_OUT),
        lambda args: _print_or_write(_module("sweep").sweep_markdown(args.sweep,
                                                                     args.references), args.out)),
    "transfer": ("Full BC of each synthetic motion model against constant velocity, on "
                 "synthetic validation and real logs", (
        (("work",), dict(type=Path, help="the folder holding one sub-folder per motion")),
        (("--out",), dict(type=Path, default=None, help="the markdown file (none: print only)"))),
        _transfer),
}
