"""A cost model of a training run: episodes trained per second on one device -> hours.

An *episode* is one (setting, seed, scenario) of an update. The paper network costs ``updates x
settings x seeds x batch x seconds per episode / devices`` (data parallel, communication
ignored; :func:`table1_hours`); the laptop network is priced per (setting x update) of one
training process from whole measured runs (:func:`laptop_train_seconds`).
"""

from __future__ import annotations

import sys

from igdrivsim.names import GPU_SEEDS
from igdrivsim.training.config import RunConfig, get_profile

# Paper network on the 2-core AMD EPYC, 8 scenarios x 1 seed per update: `igdrivsim bench train
# --profiles paper` (docs/bench/train_paper_bc_cpu.json, train_paper_bc_rl_cpu.json) / 8.
CPU_SECONDS_PER_EPISODE = 2.0966 / 8  # teacher-forced methods (BC): one Adam step per batch
CPU_SECONDS_PER_ROLLOUT_EPISODE = 12.3355 / 8  # methods that drive (BC-RL: 4 x 4 PPO steps)
PAPER_SCENARIOS = 152_808  # filtered WOMD training scenarios
# Laptop network, 3 seeds, 16 scenarios per update: seconds per update of ONE setting in one
# one-XLA-thread worker on 2 busy cores, the whole training stage included (loading, records,
# compile, validation), from the default `bash scripts/reproduce.sh` (2026-11-27): BC 6
# settings x 1,000 updates in 5,135 s; BC-RL 2 settings x 1,000 updates in 4,290 s.
LAPTOP_CPU_S_PER_SETTING_UPDATE = 5135 / (6 * 1000)  # teacher-forced methods (BC)
LAPTOP_CPU_S_PER_SETTING_UPDATE_ROLLOUT = 4290 / (2 * 1000)  # methods that drive (BC-RL, ...)
LAPTOP_SEEDS = 3  # the seeds of those measurements (cost scales with seeds)
# The default pipeline but training and the maze study (a stage of its own), in CPU-s: the
# 1,211 CPU-s of a whole run (README at 6ae8db5) beyond training, less the maze's 534.
LAPTOP_OTHER_CPU_S = 1211.0 - 534.0
# The maze study with its converged references and baselines, `python -m maze` on 2 quiet cores
# (`this_invocation_cpu_s` of paper/maze_config.json: 234.9).
MAZE_CPU_S = 235.0
# One H200, laptop network, the gpu profile's 12 seeds (3 do not fill a GPU), 6 settings per
# update: docs/bench/train_gpu_bc_h200.json, train_gpu_bc_rl_h200.json (compiling included).
GPU_S_PER_SETTING_UPDATE = 0.0513 / 6
GPU_S_PER_SETTING_UPDATE_ROLLOUT = 0.1994 / 6
GPU_COMPILE_S = 46.7
# The maze study on that machine beside the training lanes
# (docs/bench/reproduce_gpu_h200_slow_compile.log).
GPU_MACHINE_MAZE_S = 86.0


def laptop_train_seconds(updates: int, settings: int, seeds: int, rollout: bool,
                         gpu: bool = False) -> float:
    """Seconds of one training process of the laptop network: CPU-s on one core (``gpu``
    False), or seconds on one H200 (compile included; seeds scale linearly from the measured
    12, a lower bound for fewer seeds on a GPU that is not filled)."""
    if gpu:
        per = GPU_S_PER_SETTING_UPDATE_ROLLOUT if rollout else GPU_S_PER_SETTING_UPDATE
        return GPU_COMPILE_S + updates * settings * per * seeds / GPU_SEEDS
    per = LAPTOP_CPU_S_PER_SETTING_UPDATE_ROLLOUT if rollout else LAPTOP_CPU_S_PER_SETTING_UPDATE
    return updates * settings * per * seeds / LAPTOP_SEEDS


def table1_hours(bc_seconds: float, rollout_seconds: float) -> dict[str, float]:
    """Device-hours of the paper's Table I (6 settings x 3 seeds of BC and of BC-RL, the paper
    profile over ``PAPER_SCENARIOS``) at ``bc_seconds`` / ``rollout_seconds`` per episode:
    ``{"teacher_forced", "rollout", "total"}``."""
    config = get_profile("paper")
    t = config.training
    episodes = config.total_updates(PAPER_SCENARIOS) * 6 * t.seeds * config.data.batch_size
    out = {"teacher_forced": episodes * bc_seconds / 3600,
           "rollout": episodes * rollout_seconds / 3600}
    return out | {"total": out["teacher_forced"] + out["rollout"]}


def table1_text(gpu: bool) -> str:
    """One line: what Table I at paper scale costs at the CPU rates (``gpu``: say that the GPU
    rate of the paper network is not measured yet)."""
    config = get_profile("paper")
    updates = config.total_updates(PAPER_SCENARIOS)
    head = (f"Table I at paper scale (6 settings x {{BC, BC-RL}} x {config.training.seeds} "
            f"seeds, {updates:,} updates of {config.data.batch_size} scenarios each, "
            f"{PAPER_SCENARIOS:,} scenarios x {config.training.epochs:g} epochs)")
    cpu = table1_hours(CPU_SECONDS_PER_EPISODE, CPU_SECONDS_PER_ROLLOUT_EPISODE)
    text = (f"{head}: ~{cpu['total']:,.0f} CPU-process-hours at the rates measured on 2 CPU "
            f"cores (BC {cpu['teacher_forced']:,.0f}, BC-RL {cpu['rollout']:,.0f}; "
            "igdrivsim/training/cost.py)")
    return text + ("; the GPU rate of this network is not measured yet (scripts/bench_gpu.sh)"
                   if gpu else "")


def warn_if_cpu(config: RunConfig, num_scenarios: int, backend: str, devices: int) -> str | None:
    """Warn once (stderr) when the paper or gpu profile runs without an accelerator; returns
    the message (None when there is nothing to warn about)."""
    warn = {"paper": _paper_on_cpu, "gpu": _gpu_profile_on_cpu}.get(config.profile)
    msg = warn(config, num_scenarios, devices) if backend == "cpu" and warn else None
    if msg:
        print(msg, file=sys.stderr, flush=True)
    return msg


def _paper_on_cpu(config: RunConfig, num_scenarios: int, devices: int) -> str:
    rollout = config.collects_rollout
    per = CPU_SECONDS_PER_ROLLOUT_EPISODE if rollout else CPU_SECONDS_PER_EPISODE
    updates = config.total_updates(num_scenarios)
    episodes = len(config.settings) * config.training.seeds * config.data.batch_size
    hours = updates * episodes * per / devices / 3600
    return (f"igdrivsim train: warning: --profile paper on CPU ({devices} device(s)): "
            f"{updates:,} updates of {config.data.batch_size} "
            f"scenarios x {config.training.seeds} seed(s) x {len(config.settings)} setting(s) "
            f"at ~{per} s per episode (paper network, bench train) is ~{hours:,.0f} hours; "
            "use GPUs (docs/scaling.md) or --profile laptop")


def _gpu_profile_on_cpu(config: RunConfig, num_scenarios: int, devices: int) -> str | None:
    """None when the seeds were overridden down to the laptop's or fewer."""
    seeds, n = config.training.seeds, config.training.num_updates
    if seeds <= LAPTOP_SEEDS:
        return None
    hours = sum(laptop_train_seconds(n, 6, seeds, r) for r in (False, True)) / 2 / 3600
    return (f"igdrivsim train: warning: --profile gpu on CPU: {seeds} seeds, "
            f"{seeds / LAPTOP_SEEDS:.3g}x the laptop profile's {LAPTOP_SEEDS}; its BC and BC-RL "
            f"training alone would take ~{hours:.0f} h on 2 cores; use a GPU or "
            "--profile laptop")
