"""Prose the report writes into markdown (the README, docs/results.md): wrapped at
:data:`WIDTH`, never splitting a code span, a link or a duration."""

from __future__ import annotations

import re

# the width of the prose lines the report writes into the README
WIDTH = 96
# a word of markdown: code spans, links and durations whole (they hold spaces), else non-space
# runs
_WORD = re.compile(r"(?:\d+ h \d+ min|`[^`\n]*`|\[[^\]\n]*\]\([^)\s]*\)|\S)+")


def wrap(text: str, width: int = WIDTH, indent: str = "") -> list[str]:
    """``text`` as lines of at most ``width`` characters, continuation lines prefixed by
    ``indent``; a code span or a link is never split (a longer one stands on its own line)."""
    lines, line = [], ""
    for word in _WORD.findall(text):
        if line.strip() and len(line) + 1 + len(word) > width:
            lines.append(line)
            line = indent + word
        else:
            line = f"{line} {word}" if line.strip() else line + word
    return lines + [line] if line else lines
