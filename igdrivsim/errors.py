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


# what a command reports as one line (exit 2): its own errors and file-system refusals (an --out
# that is a file, no space left, ...)
REPORTED = (IGDrivSimError, OSError)


def error_line(err: BaseException) -> str:
    """One of :data:`REPORTED` as one line; a file-system error names its path(s)."""
    if not isinstance(err, OSError):
        return str(err)
    paths = " -> ".join(str(p) for p in (err.filename, err.filename2) if p is not None)
    what = err.strerror or type(err).__name__
    return f"{what}: {paths}" if paths else f"{what}: {err}"


def check_min(option: str, value: float | None, minimum: float) -> None:
    """``ConfigError`` naming the option and its value unless ``value >= minimum`` (``None``:
    not given, accepted)."""
    if value is not None and not value >= minimum:
        raise ConfigError(f"{option} must be >= {minimum}, got {value}")
