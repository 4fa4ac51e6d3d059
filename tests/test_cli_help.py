"""Every sub-command's ``--help`` exits 0 and every option has a help text (in-process, fast)."""

from __future__ import annotations

import argparse
import importlib

import pytest

from igdrivsim import cli

COMMANDS = [[name] for name in cli.COMMANDS] + [["bench"]] + [["bench", n] for n in cli.BENCHES]
MAZE = ["maze.__main__", "maze.bench", "maze.render", "maze.study"]


def _run_help(main, argv: list[str], monkeypatch, capsys) -> list[argparse.ArgumentParser]:
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
    _run_help(cli.main, argv, monkeypatch, capsys)
    # The same parser with the command's options configured, as main() builds it.
    parser = cli.build_parser()
    if argv != ["bench"]:
        parser.parse_known_args(argv)[0]._configure()
    _check_help_texts(parser, "igdrivsim " + " ".join(argv))


@pytest.mark.parametrize("module", MAZE)
def test_maze_help(module, monkeypatch, capsys):
    seen = _run_help(importlib.import_module(module).main, [], monkeypatch, capsys)
    assert seen
    _check_help_texts(seen[0], module)
