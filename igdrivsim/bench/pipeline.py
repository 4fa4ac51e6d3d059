"""``igdrivsim bench pipeline``: where a reproduction's core-seconds go, stage by stage.

Runs the reproduction of ``--profile`` at ``--updates`` updates per training run (or reads
``--from-work``) and groups each stage's stamped wall and CPU seconds; a training stage's CPU
beyond its updates' (``bench train --parts``) is what it does besides updating.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

from igdrivsim.errors import ConfigError, check_min
from igdrivsim.io import atomic_write_json, read_json, require_file_target
from igdrivsim.machine import machine_record
from igdrivsim.pipeline.profiles import PROFILES

GROUPS = ("data", "filter", "train", "evaluate", "maze")  # by a stage name's first word


def bench_pipeline_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--profile", choices=tuple(PROFILES), default="laptop",
                        help="reproduction profile (default: %(default)s)")
    parser.add_argument("--updates", type=int, default=20,
                        help="updates per training run (default: %(default)s; the profile's "
                             "own are far more, priced from the measured update)")
    parser.add_argument("--methods", default="bc,bc_rl", help="methods trained")
    parser.add_argument("--work", default=None, metavar="DIR",
                        help="work folder of the run (default: a temporary one, removed)")
    parser.add_argument("--from-work", default=None, metavar="DIR",
                        help="do not run: read the stage stamps of this finished run")
    parser.add_argument("--parts-updates", type=int, default=2,
                        help="updates timed by bench train per method (0: skip)")
    parser.add_argument("--out", default=None, metavar="FILE",
                        help="also write the record and the machine it ran on to this JSON file")


def group_of(stage: str) -> str:
    head = stage.split("_")[0]
    return head if head in GROUPS else "other"


def stage_costs(work: Path) -> list[dict]:
    """``[{stage, group, seconds, cpu_seconds}]`` from ``WORK/stages/*.json``, in finish order."""
    stamps = sorted((read_json(p) for p in (work / "stages").glob("*.json")),
                    key=lambda s: s.get("finished", ""))
    return [{"stage": s["stage"], "group": group_of(s["stage"]), "seconds": s["seconds"],
             "cpu_seconds": s.get("cpu_seconds")} for s in stamps]


def summarise(stages: list[dict]) -> dict:
    """CPU seconds and share per group (a stamp without CPU seconds counts its wall seconds)."""
    cpu: Counter[str] = Counter()
    for s in stages:
        cpu[s["group"]] += float(s["cpu_seconds"] if s["cpu_seconds"] is not None else s["seconds"])
    total = sum(cpu.values()) or 1.0
    return {g: {"cpu_seconds": round(v, 1), "share": round(v / total, 3)}
            for g, v in sorted(cpu.items(), key=lambda kv: -kv[1])}


def training_inside(profile: str, method: str, updates: int, train_cpu: float,
                    parts_updates: int) -> dict:
    """One method's training CPU: its updates (timed alone, with their parts) and the rest."""
    from igdrivsim.bench.train import bench_profile  # JAX: only when timing

    rec = bench_profile(profile, method, updates=parts_updates, parts=True)
    runs = rec["settings"] * rec["seeds"]  # the parts are timed for one setting and seed
    updating = updates * rec["cpu_seconds_per_update"]
    return {"method": method, "train_cpu_seconds": round(train_cpu, 1),
            "cpu_seconds_per_update": rec["cpu_seconds_per_update"],
            "updates_cpu_seconds": round(updating, 1),
            "outside_updates_cpu_seconds": round(train_cpu - updating, 1),
            "update_parts_s": {k: round(v * runs, 4) for k, v in rec["parts_s"].items()},
            "parts_note": f"wall seconds of one setting and seed's part x {runs} (settings x "
                          "seeds), each timed alone"}


def run_pipeline(profile: str, updates: int, methods: str, work: Path) -> dict:
    """Run the reproduction into ``work``; its wall and CPU seconds."""
    argv = [sys.executable, "-m", "igdrivsim.pipeline", "--profile", profile, "--methods",
            methods, "--set", f"training.num_updates={updates}", "--out", str(work),
            "--no-progress"]
    start = time.perf_counter()
    proc = subprocess.Popen(argv)
    _, status, usage = os.wait4(proc.pid, 0)
    if os.waitstatus_to_exitcode(status) != 0:
        raise ConfigError(f"the reproduction failed: {' '.join(argv)} (read {work}/logs)")
    return {"command": argv[1:], "wall_s": round(time.perf_counter() - start, 1),
            "cpu_seconds": round(usage.ru_utime + usage.ru_stime, 1)}


def bench_pipeline_command(args: argparse.Namespace) -> int:
    check_min("--updates", args.updates, 1)
    check_min("--parts-updates", args.parts_updates, 0)
    if args.out:
        require_file_target(args.out)
    record: dict = {"profile": args.profile, "updates": args.updates}
    with tempfile.TemporaryDirectory(prefix="igdrivsim-bench-pipeline-") as tmp:
        if args.from_work:
            work = Path(args.from_work)
            if not (work / "stages").is_dir():
                raise ConfigError(f"no stage stamps in {work}/stages (not a reproduction's "
                                  "work folder?)")
        else:
            work = Path(args.work or tmp)
            record["run"] = run_pipeline(args.profile, args.updates, args.methods, work)
        record["stages"] = stage_costs(work)
    record["groups"] = summarise(record["stages"])
    if args.parts_updates:
        record["training"] = inside = []
        for method in [m.strip() for m in args.methods.split(",") if m.strip()]:
            cpu = sum(s["cpu_seconds"] or s["seconds"] for s in record["stages"]
                      if s["stage"] == f"train_{method}"
                      or s["stage"].startswith(f"train_{method}-"))
            inside.append(training_inside(args.profile, method, args.updates, cpu,
                                          args.parts_updates))
            print(json.dumps(inside[-1]), flush=True)
    print(json.dumps({"groups": record["groups"]}), flush=True)
    if args.out:
        atomic_write_json(args.out, {**record, "machine": machine_record()}, indent=2)
    return 0
