"""CLI commands of the data part: ``igdrivsim inspect`` and ``igdrivsim filter``."""

from __future__ import annotations

import argparse
import json
import os
import sys

import numpy as np

from igdrivsim.data.egos import add_egos_argument
from igdrivsim.data.filter import (
    FilterConfig,
    intersecting_objects,
    merge,
    parse_part,
    run_filter,
    sdc_mean_speed,
)
from igdrivsim.data.manifest import COUNTS, MANIFEST
from igdrivsim.data.reader import ReadStats, available_cpus
from igdrivsim.data.scenario import (
    CURRENT_INDEX,
    RG_ROAD_EDGE_TYPES,
    Scenario,
    decode_scenario_id,
)
from igdrivsim.data.source import open_scenarios
from igdrivsim.errors import ConfigError, DataError, check_min
from igdrivsim.io import require_folder


def describe(scenario: Scenario) -> dict:
    """Summary of one unbatched scenario (what ``igdrivsim inspect`` prints)."""
    md, rg = scenario.metadata, scenario.roadgraph
    rg_valid = np.asarray(rg.valid, bool)
    types = np.asarray(md.object_type)[np.asarray(md.valid, bool)]
    return {
        "scenario_id": decode_scenario_id(scenario.scenario_id),
        "num_object_slots": scenario.num_objects,
        "num_valid_objects": int(np.asarray(md.valid, bool).sum()),
        "num_valid_at_current": int(np.asarray(scenario.trajectory.valid)[:, CURRENT_INDEX].sum()),
        "object_types": {str(t): int((types == t).sum()) for t in np.unique(types)},
        "sdc_index": int(np.argmax(np.asarray(md.is_sdc))),
        "num_roadgraph_points": int(rg_valid.sum()),
        "num_road_edge_points": int((rg_valid & np.isin(rg.type, RG_ROAD_EDGE_TYPES)).sum()),
        "num_traffic_lights": int(np.asarray(scenario.traffic_lights.valid).any(-1).sum()),
        "sdc_mean_speed": round(sdc_mean_speed(scenario), 4),
        "interactive": bool(intersecting_objects(scenario).any()),
        "objects_of_interest": int(np.asarray(md.objects_of_interest).sum()),
        "tracks_to_predict": int(np.asarray(md.tracks_to_predict).sum()),
    }


def inspect_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("files", nargs="+", metavar="FILE",
                        help="TFRecord files, folders, globs or name@N (either WOMD format), "
                             "ScenarioNet .pkl files / dataset folders, GPUDrive .json files")
    parser.add_argument("--limit", type=int, default=None, help="stop after N scenarios")
    parser.add_argument("--skip-bad", action="store_true",
                        help="warn about and count bad records instead of stopping")
    parser.add_argument("--workers", type=int, default=1,
                        help="N worker processes (1: in this process, which starts printing at "
                             "once)")
    add_egos_argument(parser)


def inspect_command(args: argparse.Namespace) -> int:
    """Print one JSON line per scenario: where it is, its format and :func:`describe`."""
    check_min("--limit", args.limit, 0)
    check_min("--workers", args.workers, 1)
    stats = ReadStats()
    shown = 0
    for rec in open_scenarios(args.files, caps=None, skip_bad=args.skip_bad, stats=stats,
                              workers=args.workers, egos=args.egos):
        if args.limit is not None and shown >= args.limit:
            break
        line = {"file": rec.file, "record": rec.record, "format": rec.format,
                **(rec.source or {}), **describe(rec.scenario),
                **({} if rec.ego is None else {"logged_sdc": rec.ego["logged_sdc"]})}
        print(json.dumps(line), flush=True)
        shown += 1
    if stats.skipped:
        print(f"igdrivsim inspect: skipped {len(stats.skipped)} bad record(s)", file=sys.stderr)
    if shown == 0 and args.limit != 0:
        raise DataError(f"no records in {' '.join(args.files)}")
    return 0


def filter_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("inputs", nargs="+", metavar="INPUT",
                        help="scenario files of any format read (WOMD shards, ScenarioNet, "
                             "GPUDrive JSON: files, folders, globs, name@N); with --merge: the "
                             "output folders of earlier (--part) runs")
    parser.add_argument("--out", required=True, help=f"output folder ({MANIFEST}, "
                                                     f"{COUNTS}, shards/)")
    parser.add_argument("--criterion", choices=("paper", "objects_of_interest"), default=None,
                        help="interactive = SDC path crosses another object's path (paper, "
                             "default) or WOMD's objects_of_interest flag")
    parser.add_argument("--min-speed", type=float, default=None,
                        help="minimum SDC mean speed over its valid steps, m/s (default 0.7)")
    parser.add_argument("--workers", type=int, default=available_cpus(),
                        help="N worker processes, one shard each at a time (1: in this process; "
                             "default: all CPUs)")
    parser.add_argument("--part", default=None, metavar="i/n",
                        help="process only shards i, i+n, ... (0 <= i < n) for cluster arrays; "
                             "join the parts with --merge")
    parser.add_argument("--merge", action="store_true",
                        help="join the per-shard results in the INPUT folders into --out")
    add_egos_argument(parser)
    parser.add_argument("--skip-bad", action="store_true",
                        help="warn about and count bad records instead of stopping")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def filter_command(args: argparse.Namespace) -> int:
    require_folder(args.out)
    explicit = args.criterion is not None or args.min_speed is not None
    config = FilterConfig(criterion=args.criterion or "paper",
                          min_speed=0.7 if args.min_speed is None else args.min_speed)
    if args.merge:
        if args.part is not None:
            raise ConfigError("--merge and --part do not go together")
        counts = merge(args.inputs, args.out, config if explicit else None)
    else:
        part = parse_part(args.part)
        check_min("--workers", args.workers, 0)
        counts = run_filter(args.inputs, args.out, config, workers=args.workers, part=part,
                            skip_bad=args.skip_bad, progress=not args.no_progress, egos=args.egos)
        if counts is None:
            print(f"igdrivsim filter: part {args.part} done; join the parts with "
                  f"`igdrivsim filter --merge {args.out} ... --out DIR`", file=sys.stderr)
            return 0
    if counts.get("bad_records"):
        print(f"igdrivsim filter: warning: skipped {counts['bad_records']} bad record(s), listed "
              f"in {os.path.join(args.out, 'bad_records.jsonl')}", file=sys.stderr)
    print(json.dumps(counts))
    return 0
