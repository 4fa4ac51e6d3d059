"""Shared test data: toy straight-road scenarios written as a tf.Example shard."""

from __future__ import annotations

from pathlib import Path


def write_toy_shard(folder: Path, config, count: int = 8) -> str:
    """``count`` toy straight-road scenarios (speeds 3.0, 4.5, ...) with the capacities of
    ``config``, as ``folder/train.tfrecord``; returns the folder."""
    from igdrivsim.data import write_tfexample
    from igdrivsim.simulator import toy

    caps = config.capacities
    scenarios = [toy.straight_road(caps, speed=3.0 + 1.5 * i, scenario_id=f"toy-{i}")
                 for i in range(count)]
    write_tfexample(Path(folder) / "train.tfrecord", scenarios)
    return str(folder)
