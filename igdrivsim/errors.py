"""Errors that the command line reports as one clear line (what went wrong and where)."""

from __future__ import annotations


class IGDrivSimError(Exception):
    """Base class: the CLI prints ``igdrivsim <command>: error: <message>`` and exits 2."""


class ConfigError(IGDrivSimError, ValueError):
    """A bad argument or configuration value."""


class DataError(IGDrivSimError):
    """Bad input data, located by file, record index and key where known."""

    def __init__(self, problem: str, *, file: str | None = None, record: int | None = None,
                 key: str | None = None):
        self.problem, self.file, self.record, self.key = problem, file, record, key
        where = ", ".join(
            part for part in (
                f"file {file}" if file is not None else "",
                f"record {record}" if record is not None else "",
                f"key {key!r}" if key is not None else "",
            ) if part
        )
        super().__init__(f"{where}: {problem}" if where else problem)
