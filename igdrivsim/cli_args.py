"""The help formatter shared by every command module (and ``maze``): a low layer, so that
command modules need not import :mod:`igdrivsim.cli` (the top layer)."""

from __future__ import annotations

import argparse


class DefaultsFormatter(argparse.HelpFormatter):
    """Append "(default: X)" to an option's help unless it already names its default."""

    def _get_help_string(self, action: argparse.Action) -> str:
        help_ = action.help or ""
        if ("default" in help_ or action.default is argparse.SUPPRESS or not action.option_strings
                or action.nargs == 0):
            return help_
        if action.default is None:
            return f"{help_} (default: none)".strip()
        if action.default == []:
            return help_  # a repeatable option, empty unless given
        return f"{help_} (default: %(default)s)".strip()

