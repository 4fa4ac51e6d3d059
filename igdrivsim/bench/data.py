"""``igdrivsim bench data``: scenarios/s read + decoded (+ fitted to capacities) and filtered.

Default input: the real WOMD samples in ``../shared/data/womd`` tiled ``--limit`` times into
temporary shards (the Scenario-protobuf sample a tenth as often). Each run is timed in one
process and with ``--workers``, with and without start-up, and in CPU time per scenario.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

from igdrivsim.data import tfrecord
from igdrivsim.data.filter import run_filter
from igdrivsim.data.manifest import write_json
from igdrivsim.data.reader import available_cpus, iter_scenarios
from igdrivsim.errors import DataError, check_min
from igdrivsim.io import require_file_target
from igdrivsim.machine import machine_record, process_cpu_seconds

DEFAULT_SAMPLES = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "womd"


def bench_data_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("paths", nargs="*", metavar="PATH",
                        help="WOMD files/folders/globs/name@N (default: tiled real samples)")
    parser.add_argument("--samples", default=str(DEFAULT_SAMPLES),
                        help="folder with the real samples to tile (default: %(default)s)")
    parser.add_argument("--limit", dest="records", type=int, default=400, metavar="N",
                        help="tf.Example records to tile (default: %(default)s)")
    parser.add_argument("--shards", type=int, default=4, help="shards to tile them into")
    parser.add_argument("--workers", type=int, default=available_cpus(),
                        help="N worker processes for the parallel runs (default: all CPUs)")
    parser.add_argument("--out", default=None, help="also write the results to this JSON file")


def _tile(samples: Path, records: int, shards: int, folder: str) -> dict[str, list[str]]:
    """Write the real samples repeated into ``folder``: ``{format: [shard paths]}``."""
    out = {}
    for fmt, name, n in (("tf_example", "motion_data_one_example.tfrecord", records),
                         ("scenario_proto", "motion_data_one_scenario.tfrecord",
                          max(1, records // 10))):
        path = samples / name
        if not path.is_file():
            raise DataError("real sample not found (pass PATH or --samples)", file=str(path))
        data = tfrecord.read_record(path, 0)
        k = max(1, min(shards, n))
        files = [os.path.join(folder, f"{fmt}.tfrecord-{i:05d}-of-{k:05d}") for i in range(k)]
        for i, f in enumerate(files):
            tfrecord.write_records(f, [data] * (n // k + (i < n % k)))
        out[fmt] = files
    return out


def _time_read(paths, workers: int) -> dict:
    start = time.perf_counter()
    arrivals = [time.perf_counter() for _ in iter_scenarios(paths, workers=workers, chunk=8)]
    end = time.perf_counter()
    n = len(arrivals)
    steady = max(n - 1, 0)  # after the first scenario: the workers have started
    return {"scenarios": n, "wall_s": round(end - start, 3),
            "scenarios_per_s": round(n / (end - start), 1),
            "scenarios_per_s_after_startup": (round(steady / (end - arrivals[0]), 1) if steady
                                              else None)}


def _time_filter(paths, workers: int, folder: str) -> dict:
    out = tempfile.mkdtemp(prefix="filter-", dir=folder)
    start = time.perf_counter()
    counts = run_filter(paths, out, workers=workers, progress=False)
    wall = time.perf_counter() - start
    return {"scenarios": counts["scenarios"], "wall_s": round(wall, 3),
            "scenarios_per_s": round(counts["scenarios"] / wall, 1)}


def bench_data_command(args: argparse.Namespace) -> int:
    for option, value in (("--limit", args.records), ("--shards", args.shards),
                          ("--workers", args.workers)):
        check_min(option, value, 1)
    if args.out:
        require_file_target(args.out)
    results = {"cpu_count": available_cpus(), "workers": args.workers, "runs": []}
    with tempfile.TemporaryDirectory(prefix="igdrivsim-bench-data-") as folder:
        inputs = ({"given": list(args.paths)} if args.paths
                  else _tile(Path(args.samples), args.records, args.shards, folder))
        for fmt, paths in inputs.items():
            for what, fn in (("read", _time_read),
                             ("filter", lambda p, w: _time_filter(p, w, folder))):
                for workers in sorted({1, args.workers}):
                    cpu = process_cpu_seconds()
                    row = {"input": fmt, "what": what, "workers": workers,
                           **fn(paths, workers if workers > 1 else 0)}
                    row["cpu_ms_per_scenario"] = round(
                        1000 * (process_cpu_seconds() - cpu) / max(row["scenarios"], 1), 2)
                    results["runs"].append(row)
                    print(json.dumps(row), flush=True)
    if args.out:
        write_json(args.out, {**results, "machine": machine_record()})
    return 0
