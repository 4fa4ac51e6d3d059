"""Atomic file writers (a temp file in the target's folder, then ``os.replace``) and the one
reader of the JSON records they write (:func:`read_json`).

Every output of the package goes through them, so a reader or a resumed pipeline never sees a
half-written file: an error leaves the old file (or none) and removes the temp file (a killed
process may leave a hidden ``.<name>.*``). Files get ``0o666`` minus the umask. No fsync: this
guards against process crashes, not power loss.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any

from igdrivsim.errors import ConfigError, DataError

_REQUIRED = object()


def read_json(path: str | os.PathLike[str], default: Any = _REQUIRED) -> dict:
    """The JSON object in ``path``; when it is missing, unreadable or not an object, ``default``
    if given, else a :class:`~igdrivsim.errors.DataError` naming the file."""
    try:
        record = json.loads(Path(path).read_text(encoding="utf-8"))
        if not isinstance(record, dict):
            raise ValueError(f"a JSON {type(record).__name__}, not an object")
    except (OSError, ValueError) as err:  # ValueError: JSON and UTF-8 decoding too
        if default is not _REQUIRED:
            return default
        raise DataError(f"not readable JSON ({err})", file=str(path)) from err
    return record


def require_folder(path: str | os.PathLike[str], option: str = "--out") -> Path:
    """``path`` as a folder to write into, refused up front when a file is there."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise ConfigError(f"{option} {path}: a file is there, not a folder")
    return path


def require_file_target(path: str | os.PathLike[str], option: str = "--out") -> Path:
    """``path`` as a file to write, refused up front when a folder is there."""
    path = Path(path)
    if path.is_dir():
        raise ConfigError(f"{option} {path}: a folder is there, not a file")
    return path


def _umask() -> int:
    """The process umask, read without changing it where Linux allows (thread-safe)."""
    try:
        with open("/proc/self/status", encoding="ascii") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


@contextmanager
def _replacing(path: Path, suffix: str) -> Iterator[Path]:
    """A temp path next to ``path`` that replaces it on a clean exit (removed otherwise)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix, dir=path.parent)
    os.close(fd)
    tmp = Path(name)
    try:
        yield tmp
        os.chmod(tmp, 0o666 & ~_umask())  # what a plain open() would give
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


@contextmanager
def atomic_path(path: str | os.PathLike[str], mode: str = "wb",
                **open_kwargs: Any) -> Iterator[IO[Any]]:
    """Yield a temp file open in ``mode`` (as :func:`open`) that replaces ``path`` on a clean
    exit."""
    with _replacing(Path(path), ".tmp") as tmp, open(tmp, mode, **open_kwargs) as f:
        yield f


def atomic_write(path: str | os.PathLike[str], write: Callable[[Path], object],
                 suffix: str | None = None) -> Path:
    """Call ``write(tmp)`` with a temp path next to ``path`` ending with ``suffix`` (default:
    ``path``'s, for libraries that infer the format from it), then move it into place."""
    path = Path(path)
    with _replacing(path, path.suffix if suffix is None else suffix) as tmp:
        write(tmp)
    return path


def atomic_copy(src: str | os.PathLike[str], dst: str | os.PathLike[str]) -> Path:
    """Copy the file ``src`` to ``dst`` through a temp file (never half a copy at ``dst``)."""
    return atomic_write(dst, lambda tmp: shutil.copyfile(src, tmp))


def atomic_write_text(path: str | os.PathLike[str], text: str) -> Path:
    return atomic_write(path, lambda tmp: tmp.write_text(text, encoding="utf-8"))


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes) -> Path:
    return atomic_write(path, lambda tmp: tmp.write_bytes(data))


def atomic_write_json(path: str | os.PathLike[str], obj: Any, **json_kwargs: Any) -> Path:
    """Write ``json.dumps(obj, **json_kwargs)`` plus a final newline atomically."""
    return atomic_write_text(path, json.dumps(obj, **json_kwargs) + "\n")


def atomic_write_csv(path: str | os.PathLike[str], frame: Any) -> Path:
    """Write a pandas DataFrame as CSV (no index) atomically; compression follows the suffix."""
    return atomic_write(path, lambda tmp: frame.to_csv(tmp, index=False))


def atomic_savefig(fig: Any, path: str | os.PathLike[str], **kwargs: Any) -> Path:
    """Save a matplotlib figure atomically in the format of ``path``'s suffix (without one,
    matplotlib's ``savefig.format``)."""
    fmt = kwargs.pop("format", None) or Path(path).suffix.lstrip(".")
    if not fmt:
        import matplotlib  # heavy, and only for a figure saved without a suffix

        fmt = matplotlib.rcParams["savefig.format"]
    return atomic_write(path, lambda tmp: fig.savefig(tmp, format=fmt, **kwargs))
