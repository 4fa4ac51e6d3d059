"""Every sub-command's ``--help`` exits 0 and every option has a help text (in-process, fast)."""

from __future__ import annotations

import argparse
import importlib

import pytest
from conftest import run_help

from igdrivsim import cli

COMMANDS = [[name] for name in cli.COMMANDS] + [["bench"]] + [["bench", n] for n in cli.BENCHES]
MAZE = ["maze.__main__", "maze.bench", "maze.render", "maze.study",
        "igdrivsim.pipeline.cli"]  # the last: scripts/reproduce.sh


def _options(parser: argparse.ArgumentParser):
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for choice in action.choices.values():
                yield from _options(choice)
        elif action.help != argparse.SUPPRESS:
            yield action


def _check_help_texts(parser: argparse.ArgumentParser, where: str) -> None:
    missing = [a.option_strings or a.dest for a in _options(parser) if not a.help]
    assert not missing, f"{where}: options without help: {missing}"


@pytest.mark.parametrize("argv", COMMANDS, ids=" ".join)
def test_igdrivsim_help(argv, monkeypatch, capsys):
    run_help(cli.main, argv, monkeypatch, capsys)
    # The same parser with the command's options configured, as main() builds it.
    parser = cli.build_parser()
    if argv != ["bench"]:
        parser.parse_known_args(argv)[0]._configure()
    _check_help_texts(parser, "igdrivsim " + " ".join(argv))


@pytest.mark.parametrize("module", MAZE)
def test_maze_help(module, monkeypatch, capsys):
    seen = run_help(importlib.import_module(module).main, [], monkeypatch, capsys)
    assert seen
    _check_help_texts(seen[0], module)


def _parse(argv: list[str]) -> argparse.Namespace:
    parser = cli.build_parser()
    parser.parse_known_args(argv)[0]._configure()
    return parser.parse_args(argv)


@pytest.mark.parametrize("new, old, dest, value", [
    (["evaluate", "R", "--data", "D", "--out", "O", "--limit", "5"], "--max-scenarios",
     "max_scenarios", 5),
    (["render", "--obs", "full"], "--setting", "setting", "full"),
    (["bench", "sim", "--obs", "full"], "--setting", "setting", "full"),
    (["bench", "sim", "--batch-sizes", "1,2"], "--batches", "batches", "1,2"),
    (["bench", "train", "--batch-size", "4"], "--batch", "batch", 4),
    (["bench", "data", "--limit", "7"], "--records", "records", 7),
])
def test_renamed_options_keep_old_spelling(new, old, dest, value):
    assert getattr(_parse(new), dest) == value
    old_argv = [old if a == new[-2] else a for a in new]
    assert getattr(_parse(old_argv), dest) == value


def test_train_interface_is_stable():
    args = _parse(["train", "--profile", "laptop", "--obs", "circular_r4", "--method", "bc_rl",
                   "--seeds", "3", "--data", "D", "--out", "O"])
    assert (args.obs, args.method, args.seeds, args.data) == ("circular_r4", "bc_rl", 3, "D")
    args = _parse(["evaluate", "RUN", "--data", "D", "--out", "O", "--references"])
    assert args.runs == ["RUN"] and args.references
