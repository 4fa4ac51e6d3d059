"""Errors that the command line reports as one clear line (what went wrong and where), and
:func:`run_command`, the one place a command turns them into that line and its exit status."""

from __future__ import annotations

import os
import sys
from collections.abc import Callable


class IGDrivSimError(Exception):
    """Base class: the CLI prints ``igdrivsim <command>: error: <message>`` and exits 2."""


class ConfigError(IGDrivSimError, ValueError):
    """A bad argument or configuration value."""


class DataError(IGDrivSimError):
    """Bad input data, located by file, record index and key where known."""

    def __init__(self, problem: str, *, file: str | None = None, record: int | None = None,
                 key: str | None = None):
        self.problem, self.file, self.record, self.key = problem, file, record, key
        parts = {"file": file, "record": record, "key": None if key is None else repr(key)}
        where = ", ".join(f"{name} {value}" for name, value in parts.items() if value is not None)
        super().__init__(f"{where}: {problem}" if where else problem)


# what a command reports as one line (exit 2): its own errors and file-system refusals (an --out
# that is a file, no space left, ...)
REPORTED = (IGDrivSimError, OSError)


def run_command(prog: str, body: Callable[..., int | None], *args) -> int:
    """``body(*args)`` as every command line runs it: its exit status (``None``: 0); one of
    :data:`REPORTED` printed as one line ``<prog>: error: <what>`` on stderr, status 2; the
    reader of stdout gone (``| head``), a quiet stop, status 141."""
    try:
        return int(body(*args) or 0)
    except BrokenPipeError:  # stdout's reader went away: no error line, no flush error at exit
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except REPORTED as err:
        what = str(err)
        if isinstance(err, OSError):  # a file-system error names its path(s)
            paths = " -> ".join(str(p) for p in (err.filename, err.filename2) if p is not None)
            what = f"{err.strerror or type(err).__name__}: {paths or err}"
        print(f"{prog}: error: {what}", file=sys.stderr)
        return 2


def check_min(option: str, value: float | None, minimum: float) -> None:
    """``ConfigError`` naming the option and its value unless ``value >= minimum`` or None."""
    if value is not None and not value >= minimum:
        raise ConfigError(f"{option} must be >= {minimum}, got {value}")
