"""A cost model of a training run: episodes trained per second on one device -> hours.

An *episode* is one (setting, seed, scenario) of an update: 90 steps forward and ``ppo_epochs``
passes backward. ``igdrivsim bench train --profiles paper --method bc`` measures the paper
network's seconds per update on 1 seed x 1 scenario x ``settings``; dividing by ``settings``
gives seconds per episode on one device. A run then costs ``updates x settings x seeds x
batch x seconds per episode / devices`` (data parallel over devices, ignoring communication).

The laptop network (profiles laptop, quick, gpu) is priced per (setting x update) of one
training process from whole measured runs (:func:`laptop_train_seconds`); the pipeline's plan
(:mod:`igdrivsim.pipeline.planning`) spreads those over its worker processes.
"""

from __future__ import annotations

import math
import sys

from igdrivsim.training.config import RunConfig

# Paper network on an idle 2-core CPU: `igdrivsim bench train --profiles paper --method bc
# --obs full --updates 2` = 9.78 s per update of one episode; a method that drives closed-loop
# episodes (BC-RL and the taught methods), the same with `--method bc_rl` = 20.3 s. README
# "Running at paper scale".
CPU_SECONDS_PER_EPISODE = 9.78  # teacher-forced methods (BC)
CPU_SECONDS_PER_ROLLOUT_EPISODE = 20.3  # methods that also drive (BC-RL, DAgger, ADVISOR)
# Paper network on one NVIDIA H200 at the paper's batch: `igdrivsim bench train --profiles
# paper --method bc --obs full --batch-size 256 --seeds 3` = 15.05 s per update of 768 episodes
# (docs/bench/train_paper_bc_h200.json, 2026-11-27); with `--method bc_rl`, 30.3 s (measured
# before bench wrote files; README "Running at paper scale").
GPU_SECONDS_PER_EPISODE = 15.05 / 768
GPU_SECONDS_PER_ROLLOUT_EPISODE = 30.3 / 768
PAPER_SCENARIOS = 152_808  # filtered WOMD training scenarios
# Laptop network, 3 seeds, 16 scenarios per update: seconds per update of ONE setting in one
# one-XLA-thread worker process while another worker keeps the second core busy (the default
# pipeline on 2 cores), everything of a training stage included (loading, teacher records,
# compile, the learning-curve validation every 250 updates). Measured by the default run of
# `bash scripts/reproduce.sh` on the 2-core AMD EPYC (its stage stamps, 2026-11-27): BC, 6
# settings x 1,000 updates in one worker, 5,135 s; BC-RL, 2 settings x 1,000 updates, 4,290 s.
LAPTOP_CPU_S_PER_SETTING_UPDATE = 5135 / (6 * 1000)  # teacher-forced methods (BC)
LAPTOP_CPU_S_PER_SETTING_UPDATE_ROLLOUT = 4290 / (2 * 1000)  # methods that drive (BC-RL, ...)
LAPTOP_SEEDS = 3  # the seeds of those measurements (cost scales with seeds)
# Everything of the default pipeline but training, in CPU-s: the 300-update run at 7f262a6 took
# 5,985 CPU-s end to end (README at 6ae8db5, Table I section, `/usr/bin/time`), of which its
# training at the rates measured then was 300 x 6 x (0.770 + 1.882) = 4,774 CPU-s; the remaining
# 1,211 CPU-s are the data, filter, evaluations, Fig. 1, report and PDF, and the maze study: 524-534
# CPU-s of them (README at 6ae8db5, speed table, maze study row), a stage of its own.
MAZE_CPU_S = 534.0
LAPTOP_OTHER_CPU_S = 1211.0 - MAZE_CPU_S
# One H200, laptop network, 6 settings x 3 seeds per update (`igdrivsim bench train --profiles
# laptop --method M --updates 5`, 2026-11-27): BC 0.0262 s (docs/bench/train_laptop_bc_h200.json),
# BC-RL 0.0907 s, compile 30.6 s (docs/bench/train_laptop_bc_rl_h200.json).
GPU_S_PER_SETTING_UPDATE = 0.0262 / 6
GPU_S_PER_SETTING_UPDATE_ROLLOUT = 0.0907 / 6
GPU_COMPILE_S = 30.6


def laptop_train_seconds(updates: int, settings: int, seeds: int, rollout: bool,
                         gpu: bool = False) -> float:
    """Seconds of one training process of the laptop network: CPU-s on one core (``gpu``
    False), or seconds on one H200 (compile included; seeds scale linearly, an upper bound
    on a GPU)."""
    if gpu:
        per = GPU_S_PER_SETTING_UPDATE_ROLLOUT if rollout else GPU_S_PER_SETTING_UPDATE
        return GPU_COMPILE_S + updates * settings * per * seeds / LAPTOP_SEEDS
    per = LAPTOP_CPU_S_PER_SETTING_UPDATE_ROLLOUT if rollout else LAPTOP_CPU_S_PER_SETTING_UPDATE
    return updates * settings * per * seeds / LAPTOP_SEEDS


def num_updates(config: RunConfig, num_scenarios: int = PAPER_SCENARIOS) -> int:
    t = config.training
    if t.num_updates > 0:
        return t.num_updates
    return max(1, math.ceil(t.epochs * num_scenarios / config.data.batch_size))


def run_hours(config: RunConfig, seconds_per_episode: float, num_scenarios: int,
              devices: int = 1) -> float:
    """Hours of a run of ``config`` on ``devices`` devices at ``seconds_per_episode``."""
    settings = len([s for s in config.observation.setting.split(",") if s.strip()])
    episodes = settings * config.training.seeds * config.data.batch_size
    return num_updates(config, num_scenarios) * episodes * seconds_per_episode / devices / 3600


def warn_if_cpu(config: RunConfig, num_scenarios: int, backend: str, devices: int,
                stream=None) -> str | None:
    """Warn once (stderr) when the paper or gpu profile runs without an accelerator; returns
    the message (None when there is nothing to warn about)."""
    if backend != "cpu":
        return None
    messages = {"paper": _paper_on_cpu, "gpu": _gpu_profile_on_cpu}
    msg = messages[config.profile](config, num_scenarios, devices) if (
        config.profile in messages) else None
    if msg:
        print(msg, file=stream or sys.stderr, flush=True)
    return msg


def _paper_on_cpu(config: RunConfig, num_scenarios: int, devices: int) -> str:
    rollout = config.collects_rollout
    per = CPU_SECONDS_PER_ROLLOUT_EPISODE if rollout else CPU_SECONDS_PER_EPISODE
    hours = run_hours(config, per, num_scenarios, devices)
    gpu = run_hours(config, GPU_SECONDS_PER_ROLLOUT_EPISODE if rollout
                    else GPU_SECONDS_PER_EPISODE, num_scenarios, 1)
    return (f"igdrivsim train: warning: --profile paper on CPU ({devices} device(s)): "
            f"{num_updates(config, num_scenarios):,} updates of {config.data.batch_size} "
            f"scenarios x {config.training.seeds} seed(s) at ~{per} s per episode (paper "
            f"network, bench train) is ~{hours:,.1f} hours ({hours / 8766:,.1f} years); use GPUs "
            f"(~{gpu:,.0f} h on one H200; docs/scaling.md) or --profile laptop")


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
