"""Backwards-compatible names: the atomic writers now live in :mod:`igdrivsim.io`."""

from igdrivsim.io import atomic_savefig, atomic_write, atomic_write_csv, atomic_write_text

__all__ = ["atomic_savefig", "atomic_write", "atomic_write_csv", "atomic_write_text"]
