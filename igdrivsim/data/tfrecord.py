"""TFRecord framing: ``uint64 length | uint32 masked_crc(length) | data | uint32 masked_crc(data)``,
little-endian, CRC32C masked (:func:`masked_crc`). Every record is checked; a bad CRC or a
truncated record is a :class:`DataError` naming the file and record index.
"""

from __future__ import annotations

import os
import struct
from collections.abc import Iterable, Iterator

import google_crc32c

from igdrivsim.errors import DataError
from igdrivsim.io import atomic_path

_MASK_DELTA = 0xA282EAD8
_HEADER = struct.Struct("<QI")
_FOOTER = struct.Struct("<I")


def masked_crc(data: bytes) -> int:
    """The masked CRC32C that TFRecord stores after the length and after the data."""
    crc = google_crc32c.value(data)
    return (((crc >> 15) | (crc << 17)) + _MASK_DELTA) & 0xFFFFFFFF


def _open(path: str):
    try:
        return open(path, "rb")
    except OSError as err:
        raise DataError(f"cannot open: {err.strerror}", file=path) from None


def _lengths(f, path: str) -> Iterator[int]:
    """The data length of each record header of ``f``, its length CRC checked; a truncated header
    or a bad length CRC is a :class:`DataError` (nothing after it can be located)."""
    index = 0
    while header := f.read(_HEADER.size):
        if len(header) < _HEADER.size:
            raise DataError(f"truncated record header ({len(header)} of 12 bytes)", file=path,
                            record=index)
        length, length_crc = _HEADER.unpack(header)
        if masked_crc(header[:8]) != length_crc:
            raise DataError("corrupt record: length CRC mismatch (not a TFRecord file?)",
                            file=path, record=index)
        yield length
        index += 1


def iter_frames(path: str | os.PathLike, start: int = 0
                ) -> Iterator[tuple[int, bytes | None, DataError | None]]:
    """``(record_index, data, error)`` per record from ``start`` (earlier ones skipped by seeking).
    A bad data CRC comes as ``data=None`` and its error, and reading goes on; a broken framing
    (bad length CRC, truncation) yields its error last: nothing after it can be located."""
    path = os.fspath(path)
    try:
        with _open(path) as f:
            for index, length in enumerate(_lengths(f, path)):
                if index < start:
                    f.seek(length + 4, os.SEEK_CUR)
                    continue
                body = f.read(length + 4)
                if len(body) < length + 4:
                    raise DataError(f"truncated record: expected {length + 4} bytes after the "
                                    f"header, found {len(body)}", file=path, record=index)
                data = body[:length]
                if masked_crc(data) != _FOOTER.unpack(body[length:])[0]:
                    yield index, None, DataError("corrupt record: data CRC mismatch", file=path,
                                                 record=index)
                else:
                    yield index, data, None
    except DataError as err:
        yield err.record or 0, None, err


def read_record(path: str | os.PathLike, index: int) -> bytes:
    """The data of record ``index`` (raises :class:`DataError` if it is bad or missing)."""
    for _, data, error in iter_frames(path, start=index):
        if error is not None:
            raise error
        return data
    raise DataError(f"no record {index} (file has fewer records)", file=os.fspath(path),
                    record=index)


def count_records(path: str | os.PathLike) -> int:
    """Number of records, checking only the framing (length CRCs), not the data CRCs."""
    path = os.fspath(path)
    records = 0
    with _open(path) as f:
        for length in _lengths(f, path):
            f.seek(length + 4, os.SEEK_CUR)
            records += 1
    return records


def write_records(path: str | os.PathLike, records: Iterable[bytes]) -> int:
    """Write framed records atomically; returns how many were written."""
    n = 0
    with atomic_path(path) as f:
        for data in records:
            length = struct.pack("<Q", len(data))
            f.write(length + _FOOTER.pack(masked_crc(length)) + data
                    + _FOOTER.pack(masked_crc(data)))
            n += 1
    return n
