"""``igdrivsim generate``: write synthetic scenarios as WOMD-named tf.Example shards
(``DIR/{split}/{split}_tfexample.tfrecord-0000k-of-0000K``) and ``DIR/generator_config.json``.

Shards are written atomically: a re-run skips those that exist (same configuration). Scenario
``i`` depends only on ``(seed, split, i)``, not on the shard or worker count.
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import time

from tqdm.auto import tqdm

from igdrivsim.data.reader import available_cpus, pool_map
from igdrivsim.data.scenario import trim_padding
from igdrivsim.data.synthetic.generator import GeneratorConfig, generate_scenario
from igdrivsim.data.synthetic.motion import MOTIONS
from igdrivsim.data.synthetic.plot import save_pictures
from igdrivsim.data.tfexample import encode_tfexample
from igdrivsim.data.tfrecord import write_records
from igdrivsim.errors import ConfigError, check_min
from igdrivsim.io import atomic_write_json, read_json, require_folder
from igdrivsim.machine import process_cpu_seconds

CHUNK = 8  # scenarios per worker task


def shard_paths(out: str, split: str, shards: int) -> list[str]:
    return [os.path.join(out, split, f"{split}_tfexample.tfrecord-{k:05d}-of-{shards:05d}")
            for k in range(shards)]


def shard_ranges(count: int, shards: int) -> list[range]:
    """Contiguous scenario index ranges, one per shard (sizes differ by at most one)."""
    return [range(count * k // shards, count * (k + 1) // shards) for k in range(shards)]


def _encode_chunk(seed: int, split: str, start: int, stop: int, config: GeneratorConfig,
                  compact: bool):
    scenarios = (generate_scenario(seed, i, split, config) for i in range(start, stop))
    return [encode_tfexample(trim_padding(s) if compact else s) for s in scenarios]


def generate_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", required=True, help="output folder")
    parser.add_argument("--train", type=int, default=1000, help="training scenarios")
    parser.add_argument("--val", type=int, default=200, help="validation scenarios")
    parser.add_argument("--seed", type=int, default=0,
                        help="base seed; scenario i of a split depends only on (seed, split, i)")
    parser.add_argument("--shards", type=int, default=None,
                        help="shards per split (default: about 250 scenarios per shard)")
    parser.add_argument("--workers", type=int, default=available_cpus(),
                        help="N worker processes (1: in this process; default: all CPUs)")
    parser.add_argument("--p-intersection", type=float, default=GeneratorConfig.p_intersection,
                        help="fraction of intersection maps (others are curved roads)")
    parser.add_argument("--motion", choices=MOTIONS, default=GeneratorConfig.motion,
                        help="how the agents drive: as the generator always has, or 'calibrated' "
                             "towards real logs (docs/synthetic.md, Calibrated motion)")
    parser.add_argument("--plot", type=int, default=0, metavar="N",
                        help="also draw the first N training scenarios to DIR/pictures/")
    parser.add_argument("--compact", action="store_true",
                        help="drop trailing padding slots (about 5x smaller files that igdrivsim "
                             "reads back identically; other WOMD readers expect fixed sizes)")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace shards written with a different configuration")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def generate_command(args: argparse.Namespace) -> int:
    """Generate the requested splits; print one JSON summary line."""
    if args.train < 0 or args.val < 0:
        raise ConfigError(f"--train/--val must be >= 0, got {args.train}/{args.val}")
    check_min("--shards", args.shards, 1)
    if not 0.0 <= args.p_intersection <= 1.0:
        raise ConfigError(f"--p-intersection must be in [0, 1], got {args.p_intersection}")
    check_min("--seed", args.seed, 0)
    check_min("--workers", args.workers, 1)
    check_min("--plot", args.plot, 0)
    require_folder(args.out)
    config = GeneratorConfig(seed=args.seed, p_intersection=args.p_intersection,
                             motion=args.motion)
    splits = {split: {"scenarios": count,
                      "shards": min(args.shards or max(1, round(count / 250)), count)}
              for split, count in (("training", args.train), ("validation", args.val)) if count}
    resolved = {"generator": config.to_dict(), "compact": args.compact, "splits": splits}
    os.makedirs(args.out, exist_ok=True)
    config_path = os.path.join(args.out, "generator_config.json")
    if os.path.exists(config_path) and not args.overwrite and read_json(config_path) != resolved:
        raise ConfigError(f"{config_path} holds a different configuration; use another --out "
                          "or --overwrite")
    if args.overwrite:  # before the new config: no shard of the old one may stay to be reused
        for split in ("training", "validation"):
            for stale in glob.glob(os.path.join(args.out, split, f"{split}_tfexample.tfrecord-*")):
                os.remove(stale)
    atomic_write_json(config_path, resolved, indent=2)

    todo = [(split, path, indices) for split, n in splits.items()
            for path, indices in zip(shard_paths(args.out, split, n["shards"]),
                                     shard_ranges(n["scenarios"], n["shards"]), strict=True)
            if args.overwrite or not os.path.exists(path)]
    total = sum(len(r) for _, _, r in todo)
    start, cpu = time.perf_counter(), process_cpu_seconds()
    # One stream of chunks over all shards (no worker waits); shards are written in order.
    chunks = [[(args.seed, split, i, min(i + CHUNK, indices.stop), config, args.compact)
               for i in range(indices.start, indices.stop, CHUNK)] for split, _, indices in todo]
    results = pool_map(_encode_chunk, [chunk for shard in chunks for chunk in shard], args.workers)
    try:
        with tqdm(total=total, desc="generating", unit="scn", disable=args.no_progress) as bar:
            for (_, path, _), shard in zip(todo, chunks, strict=True):
                os.makedirs(os.path.dirname(path), exist_ok=True)

                def records(shard=shard):
                    for _ in shard:
                        chunk = next(results)
                        yield from chunk
                        bar.update(len(chunk))

                write_records(path, records())
    finally:
        results.close()  # the worker processes end here: their CPU time is counted below
    seconds, cpu = time.perf_counter() - start, process_cpu_seconds() - cpu
    if args.plot:
        scenarios = [generate_scenario(args.seed, i, "training", config)
                     for i in range(min(args.plot, args.train))]
        save_pictures(scenarios, os.path.join(args.out, "pictures"))
    print(json.dumps({"out": args.out, "generated": total, "seconds": round(seconds, 2),
                      "scenarios_per_s": round(total / seconds, 2) if total else None,
                      "cpu_seconds": round(cpu, 2),
                      "cpu_ms_per_scenario": round(1000 * cpu / total, 1) if total else None,
                      "skipped_shards": sum(n["shards"] for n in splits.values()) - len(todo)}))
    return 0
