"""What a reproduction will run, over how many worker processes, and how long it should take.

The (setting, method) grid is split into *parts*, one training process each (its settings in
one program, one XLA thread on a CPU): :func:`split_grid` chooses as few parts as keep every
worker busy; :func:`estimate_seconds` prices them from :mod:`igdrivsim.training.cost`. The
numbers do not depend on the split, so a run may be resumed on another machine.
``igdrivsim plan`` prints the estimated wall time of the default run per core count.
"""

from __future__ import annotations

import argparse
import heapq
import os
import platform
import subprocess
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from igdrivsim.data.reader import available_cpus
from igdrivsim.names import METHODS, SETTINGS
from igdrivsim.training import cost
from igdrivsim.training.config import get_profile
from igdrivsim.training.methods import get_method

TOLERANCE = 1.05  # a split within 5% of the ideal wall time is not split further
# memory of one CPU worker: the default run's peak RSS with two workers, taken whole (an upper
# bound: each process holds the training records whatever its settings)
WORKER_MEMORY_GB = 5.2
# profiles whose network is the laptop's: the measured per-update costs apply
PRICED_PROFILES = ("laptop", "quick", "gpu")


@dataclass(frozen=True)
class Machine:
    """Where the run goes: CPU cores this process may use, CPU model, accelerator."""

    cores: int
    cpu: str
    accelerator: str | None = None  # e.g. "NVIDIA H200 x1"; None: CPU only
    memory_gb: float | None = None  # available memory (None: unknown)

    def label(self) -> str:
        base = f"{self.cpu}, {self.cores} core{'s' if self.cores != 1 else ''}"
        return f"{base}, {self.accelerator}" if self.accelerator else base


def _proc_value(path: str, key: str) -> str | None:
    """The value after ``key:`` on the first line of ``path`` that starts with ``key``."""
    try:
        with open(path, encoding="utf-8") as fh:
            return next((ln.split(":", 1)[1].strip() for ln in fh if ln.startswith(key)), None)
    except OSError:
        return None


def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo``; the platform's name elsewhere)."""
    return (_proc_value("/proc/cpuinfo", "model name") or platform.processor()
            or platform.machine() or "unknown CPU")


def accelerator_name() -> str | None:
    """``"<device kind> xN"`` of JAX's non-CPU devices, asked in a child (keeping no GPU memory)."""
    code = ("import jax; d = jax.devices(); "
            "print('' if d[0].platform == 'cpu' else f'{d[0].device_kind} x{len(d)}')")
    env = dict(os.environ, XLA_PYTHON_CLIENT_PREALLOCATE="false")
    try:
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                             env=env, timeout=300, check=True).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return None
    return out.splitlines()[-1] if out else None


def detect_machine() -> Machine:
    """Cores from the CPU affinity (``taskset`` counts), the accelerator from ``jax.devices()``."""
    return Machine(available_cpus(), cpu_model(), accelerator_name(), available_memory_gb())


def available_memory_gb() -> float | None:
    """``MemAvailable`` of ``/proc/meminfo`` in GB (None elsewhere)."""
    try:
        return int(_proc_value("/proc/meminfo", "MemAvailable:").split()[0]) / 1e6
    except (AttributeError, ValueError, IndexError):
        return None


def default_workers(machine: Machine) -> int:
    """One worker per core on a CPU, as many as the memory holds (``WORKER_MEMORY_GB`` each);
    on an accelerator two (methods side by side share it)."""
    if machine.accelerator:
        return 2
    by_memory = machine.cores if machine.memory_gb is None else int(
        machine.memory_gb // WORKER_MEMORY_GB)
    return max(1, min(machine.cores, by_memory))


@dataclass(frozen=True)
class Part:
    """One training process of the grid: ``method`` on ``settings``, ``name`` its folder."""

    method: str
    settings: tuple[str, ...]
    name: str
    seconds: float = 0.0  # estimated, on one worker


def makespan(seconds: Sequence[float], workers: int) -> float:
    """Wall time of jobs taken longest first by ``workers`` workers (LPT)."""
    lanes = [0.0] * max(1, workers)
    for s in sorted(seconds, reverse=True):
        heapq.heapreplace(lanes, lanes[0] + s)
    return max(lanes)


def split_grid(methods: Sequence[str], settings: Sequence[str], workers: int,
               seconds: Callable[[str, int], float], extra: Sequence[float] = ()
               ) -> list[Part]:
    """Split each method's settings into parts for ``workers``: split the method of the most
    expensive part until the wall time is within ``TOLERANCE`` of the ideal, keeping the
    shortest (``seconds(method, n_settings)``: a part's cost; ``extra``: other jobs' costs)."""
    counts = dict.fromkeys(methods, 1)

    def parts() -> list[Part]:  # each method's settings in n contiguous groups, sizes within one
        return [Part(method, tuple(map(str, group)), method if n == 1 else f"{method}-{k + 1}of{n}",
                     seconds(method, len(group)))
                for method, n in counts.items()
                for k, group in enumerate(np.array_split(list(settings), n))]

    def wall(ps: list[Part]) -> float:
        return makespan([p.seconds for p in ps] + list(extra), workers)

    current = parts()
    best, best_wall = current, wall(current)
    floor = max([seconds(m, 1) for m in methods] + list(extra))  # a part has one setting at least
    ideal = max(floor, (sum(p.seconds for p in current) + sum(extra)) / max(1, workers))
    while best_wall > TOLERANCE * ideal:
        splittable = [p for p in current if counts[p.method] < len(settings)]
        if not splittable:
            break
        counts[max(splittable, key=lambda p: p.seconds).method] += 1
        current = parts()
        if wall(current) < best_wall:  # fewer parts win a tie: they were found first
            best, best_wall = current, wall(current)
    return best


def part_seconds(profile: str, seeds: int, updates: int, gpu: bool
                 ) -> Callable[[str, int], float]:
    """``seconds(method, n_settings)`` of one part from the measured per-update costs (equal
    weights for a profile without them)."""
    def seconds(method: str, n: int) -> float:
        rollout = get_method(method).rollout
        if profile not in PRICED_PROFILES:
            return float(n * (2 if rollout else 1))
        return cost.laptop_train_seconds(updates, n, seeds, rollout, gpu)

    return seconds


def estimate_seconds(profile: str, plain: Sequence[str], taught: Sequence[str],
                     settings: Sequence[str], seeds: int, updates: int, workers: int,
                     gpu: bool = False, left: Callable[[str], float] = lambda stage: 1.0
                     ) -> float | None:
    """Estimated wall seconds of the pipeline (None without measured costs): the parts and the
    maze over the workers, then the taught methods', then the other stages serially
    (``left(stage)``: the share of a stage still to run)."""
    if profile not in PRICED_PROFILES:
        return None
    seconds = part_seconds(profile, seeds, updates, gpu)
    maze = cost.GPU_MACHINE_MAZE_S if gpu else cost.MAZE_CPU_S
    first = split_grid(plain, settings, workers, seconds, [maze])
    total = makespan([p.seconds * left(f"train_{p.name}") for p in first]
                     + [maze * left("maze")], workers)
    if taught:
        second = split_grid(taught, [s for s in settings if s != "full"], workers, seconds)
        total += makespan([p.seconds * left(f"train_{p.name}") for p in second], workers)
    return total + cost.LAPTOP_OTHER_CPU_S * (not (left("report") == 0 and total == 0))


def hours_text(seconds: float) -> str:
    minutes = round(seconds / 60)
    return f"{minutes} min" if minutes < 90 else f"{seconds / 3600:.1f} h"


def plan_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--profile", default="laptop", choices=(*PRICED_PROFILES, "paper"),
                        help="the profile to estimate")
    parser.add_argument("--cores", default="1,2,4,8,16", help="comma-separated core counts")


def plan_command(args: argparse.Namespace) -> int:
    """Print the estimated wall time of a profile's default run per core count (for
    ``paper``: the cost of Table I at paper scale from the measured rates)."""
    if args.profile == "paper":
        print(cost.table1_text(gpu=True))
        return 0
    t = get_profile(args.profile).training
    print(f"profile {args.profile}: {t.num_updates} updates, {t.seeds} seeds, "
          f"{len(SETTINGS)} settings x {', '.join(METHODS)}; one XLA thread per worker")
    print("| cores | parts | estimated wall time |\n|---|---|---|")
    seconds = part_seconds(args.profile, t.seeds, t.num_updates, False)
    for cores in (int(c) for c in args.cores.split(",")):
        parts = split_grid(METHODS, SETTINGS, cores, seconds, [cost.MAZE_CPU_S])
        wall = estimate_seconds(args.profile, METHODS, (), SETTINGS, t.seeds, t.num_updates,
                                cores)
        print(f"| {cores} | {len(parts)} | {hours_text(wall or 0.0)} |")
    return 0
