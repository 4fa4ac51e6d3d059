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


def test_an_old_config_json_reads_through_upgrade_config():
    """A run written before the loss section and the methods' own params reads as today's."""
    import dataclasses

    from igdrivsim.training.config import from_dict, get_profile, to_dict

    laptop = get_profile("laptop")
    old = to_dict(laptop)
    old["training"] |= old.pop("loss") | {"advisor_alpha": 0.5, "aggregate_batches": 4}
    del old["training"]["method_params"]
    expected = dataclasses.replace(laptop, training=dataclasses.replace(
        laptop.training, method_params=(("alpha", 0.5),)))
    assert from_dict(old) == expected
    assert from_dict(to_dict(expected)) == expected


def test_train_interface_is_stable():
    args = _parse(["train", "--profile", "laptop", "--obs", "circular_r4", "--method", "bc_rl",
                   "--seeds", "3", "--data", "D", "--out", "O"])
    assert (args.obs, args.method, args.seeds, args.data) == ("circular_r4", "bc_rl", 3, "D")
    args = _parse(["evaluate", "RUN", "--data", "D", "--out", "O", "--references"])
    assert args.runs == ["RUN"] and args.references


def test_only_the_clis_have_a_main_block():
    """Every command is an ``igdrivsim`` subcommand (or the pipeline): no other module of the
    package runs as ``python -m`` with its own ``if __name__ == "__main__"``."""
    from pathlib import Path

    root = Path(cli.__file__).parent
    entries = {"cli.py", "pipeline/__main__.py"}
    mains = sorted(p.relative_to(root).as_posix() for p in root.rglob("*.py")
                   if 'if __name__ == "__main__"' in p.read_text())
    assert [m for m in mains if m not in entries] == []
