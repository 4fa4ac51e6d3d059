"""Shared test data: toy straight-road scenarios written as a tf.Example shard."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest


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


def run_help(main, argv: list[str], monkeypatch, capsys) -> list[argparse.ArgumentParser]:
    """Call ``main(argv + ['--help'])``; return the parsers that parsed (to check their options)."""
    seen: list[argparse.ArgumentParser] = []
    original = argparse.ArgumentParser.parse_args

    def recording(self, *a, **k):
        seen.append(self)
        return original(self, *a, **k)

    monkeypatch.setattr(argparse.ArgumentParser, "parse_args", recording)
    with pytest.raises(SystemExit) as exc:
        main(argv + ["--help"])
    assert exc.value.code == 0, argv
    assert "usage:" in capsys.readouterr().out
    return seen
