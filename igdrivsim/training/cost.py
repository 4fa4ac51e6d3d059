"""A cost model of a training run: episodes trained per second on one device -> hours.

An *episode* is one (setting, seed, scenario) of an update: 90 steps forward and ``ppo_epochs``
passes backward. ``igdrivsim bench train --profiles paper --method bc`` measures the paper
network's seconds per update on 1 seed x 1 scenario x ``settings``; dividing by ``settings``
gives seconds per episode on one device. A run then costs ``updates x settings x seeds x
batch x seconds per episode / devices`` (data parallel over devices, ignoring communication).
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
# paper --obs full --batch-size 256 --seeds 3` = 15.0 s per update of 768 episodes (BC),
# 30.3 s with `--method bc_rl`. README "Running at paper scale".
GPU_SECONDS_PER_EPISODE = 15.0 / 768
GPU_SECONDS_PER_ROLLOUT_EPISODE = 30.3 / 768
PAPER_SCENARIOS = 152_808  # filtered WOMD training scenarios
# The laptop profile's default pipeline run takes about 52 minutes on a 2-core CPU (README,
# Table I); the `gpu` profile runs ten times its updates.
LAPTOP_RUN_CPU_HOURS = 52 / 60


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
            f"(~{gpu:,.0f} h on one H200; README: Running at paper scale) or --profile laptop")


def _gpu_profile_on_cpu(config: RunConfig, num_scenarios: int, devices: int) -> str | None:
    """None when the updates were overridden down to the laptop's budget or less."""
    from igdrivsim.training.config import laptop

    n, base = config.training.num_updates, laptop().training.num_updates
    if n <= base:
        return None
    return (f"igdrivsim train: warning: --profile gpu on CPU: {n:,} updates, {n / base:.3g}x "
            f"the laptop profile's {base}, whose whole pipeline takes "
            f"~{LAPTOP_RUN_CPU_HOURS:.1f} h on 2 cores; expect "
            f"~{n / base * LAPTOP_RUN_CPU_HOURS:.0f} h for the pipeline; use a GPU or "
            "--profile laptop")
