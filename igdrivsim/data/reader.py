"""Reading scenario files: path expansion, streaming and parallel reads.

Each file is decoded by its format (:mod:`igdrivsim.data.formats`) at native sizes, then fitted
to the requested :class:`Capacities`. A bad record is a :class:`DataError` naming file, record and
problem; with ``skip_bad=True`` it is skipped with a warning, counted in a :class:`ReadStats`, and
the rest of the file is still read.
"""

from __future__ import annotations

import glob
import itertools
import multiprocessing
import os
import re
import warnings
from collections.abc import Iterable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from typing import NamedTuple

from igdrivsim.data import samples, tfrecord
from igdrivsim.data.formats import folder_files, format_of
from igdrivsim.data.scenario import (
    DEFAULT_CAPS,
    Capacities,
    Scenario,
    fit_to_capacities,
    index_scenario,
)
from igdrivsim.data.tfexample import encode_tfexample
from igdrivsim.errors import DataError

_SHARDED = re.compile(r"^(?P<name>.+)@(?P<count>\d+)$")
PathSpec = str | os.PathLike | Sequence[str | os.PathLike]


class ScenarioRecord(NamedTuple):
    """A decoded scenario and where it came from."""

    file: str
    record: int
    format: str
    scenario: Scenario
    source: dict | None = None  # windowed logs (ScenarioNet): {"source_id", "first_step"}
    ego: dict | None = None  # every vehicle as the ego: {"id", "object_id", "logged_sdc"}


@dataclass
class ReadStats:
    """Counts of what a read saw; ``skipped`` lists ``(file, record, message)`` of bad records."""

    read: int = 0
    skipped: list[tuple[str, int | None, str]] = field(default_factory=list)

    def skip(self, err: DataError) -> None:
        self.skipped.append((err.file, err.record, str(err)))
        warnings.warn(f"skipping bad record: {err}", stacklevel=3)


def available_cpus() -> int:
    """CPUs this process may run on (a cluster job's allocation, not the whole node)."""
    try:
        return len(os.sched_getaffinity(0)) or 1
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def expand_paths(spec: PathSpec) -> list[str]:
    """Files named by a path, a directory (its files; an ``igdrivsim samples`` folder: its
    scenario files), a glob, ``name@N`` (``name-00000-of-0000N`` ...), or a list of those;
    :class:`DataError` if something names no file."""
    if not isinstance(spec, str | os.PathLike):
        return [p for s in spec for p in expand_paths(s)]
    spec = os.fspath(spec)
    if os.path.isdir(spec):
        if os.path.isfile(os.path.join(spec, samples.RECORD)):  # igdrivsim samples' folder
            return expand_paths(samples.scenario_dir(spec))
        files = folder_files(spec)
    elif os.path.isfile(spec):
        return [spec]
    elif (m := _SHARDED.match(spec)) is not None:
        count = int(m["count"])
        files = [f"{m['name']}-{i:05d}-of-{count:05d}" for i in range(count)]
        if missing := [f for f in files if not os.path.isfile(f)]:
            raise DataError(f"{len(missing)} of {count} shards missing, e.g. {missing[0]}",
                            file=spec)
    elif glob.has_magic(spec):
        files = sorted(f for f in glob.glob(spec) if os.path.isfile(f))
    else:
        raise DataError("no such file or directory", file=spec)
    if not files:
        raise DataError("matches no files", file=spec)
    return files


def as_paths(spec: PathSpec) -> list[str]:
    return [os.fspath(s) for s in ([spec] if isinstance(spec, str | os.PathLike) else spec)]


def iter_file(path: str, caps: Capacities | None = DEFAULT_CAPS, skip_bad: bool = False,
              stats: ReadStats | None = None, start: int = 0,
              stop: int | None = None) -> Iterator[ScenarioRecord]:
    """Decode scenarios ``start <= i < stop`` of one file of any registered format
    (:mod:`igdrivsim.data.formats`), fitted to ``caps`` (None: native sizes)."""
    stats = stats if stats is not None else ReadStats()

    def bad(err: DataError, record: int | None) -> None:  # raise or skip it, located
        err = DataError(err.problem, file=path, key=err.key,
                        record=record if err.record is None else err.record)
        if not skip_bad:
            raise err from None
        stats.skip(err)

    try:
        for index, fmt, scenario, source in format_of(path).decode(path, start, stop):
            if isinstance(scenario, DataError):
                bad(scenario, index)
                continue
            if caps is not None:
                scenario = fit_to_capacities(scenario, caps)
            stats.read += 1
            yield ScenarioRecord(path, index, fmt, scenario, source)
    except DataError as err:  # the file as a whole does not read: one bad record
        bad(err, None)


def iter_scenarios(paths: PathSpec, caps: Capacities | None = DEFAULT_CAPS,
                   skip_bad: bool = False, stats: ReadStats | None = None, workers: int = 0,
                   chunk: int = 16) -> Iterator[ScenarioRecord]:
    """Stream :class:`ScenarioRecord` over all files of ``paths`` in order; ``workers > 1``
    decodes chunks of ``chunk`` records in that many processes (:func:`pool_map`)."""
    files = expand_paths(paths)
    stats = stats if stats is not None else ReadStats()
    if workers <= 1:
        for path in files:
            yield from iter_file(path, caps, skip_bad, stats)
    else:
        yield from _iter_parallel(files, caps, skip_bad, stats, workers, chunk)


def _decode_chunk(path: str, caps, skip_bad: bool, start: int, stop: int):
    stats = ReadStats()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        recs = list(iter_file(path, caps, skip_bad, stats, start, stop))
    return recs, stats.skipped


def pool_map(fn, tasks, workers: int) -> Iterator:
    """``fn(*task)`` for each task, in order: in this process (``workers <= 1``) or in
    ``workers`` spawned processes, at most ``2 * workers`` tasks in flight."""
    if workers <= 1:
        yield from (fn(*task) for task in tasks)
        return
    # spawned, not forked: forking a process that runs JAX threads can deadlock
    with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn")) as pool:
        todo = iter(tasks)
        pending = [pool.submit(fn, *task) for task in itertools.islice(todo, 2 * workers)]
        try:
            while pending:  # one more in flight as each result is taken
                pending += [pool.submit(fn, *task) for task in itertools.islice(todo, 1)]
                yield pending.pop(0).result()
        finally:
            for fut in pending:
                fut.cancel()


def _iter_parallel(files, caps, skip_bad, stats, workers, chunk):
    tasks = []
    for path in files:
        try:
            n = format_of(path).count(path)
        except DataError as err:
            if not skip_bad:
                raise
            n = err.record or 0  # read what precedes the broken framing; report the break
            stats.skip(err)
        tasks += [(path, caps, skip_bad, s, min(s + chunk, n)) for s in range(0, n, chunk)]
    for recs, skipped in pool_map(_decode_chunk, tasks, workers):
        for f, r, msg in skipped:
            stats.skipped.append((f, r, msg))
            warnings.warn(f"skipping bad record: {msg}", stacklevel=2)
        for rec in recs:
            stats.read += 1
            yield rec


def read_scenarios(paths: PathSpec, caps: Capacities = DEFAULT_CAPS, skip_bad: bool = False,
                   stats: ReadStats | None = None, workers: int = 0) -> Iterator[Scenario]:
    return (rec.scenario for rec in iter_scenarios(paths, caps, skip_bad, stats, workers))


def load_scenario(path: str | os.PathLike, index: int = 0,
                  caps: Capacities | None = DEFAULT_CAPS) -> Scenario:
    """Record ``index`` of one file as a :class:`Scenario` fitted to ``caps`` (None: native)."""
    path = os.fspath(path)
    for rec in iter_file(path, caps, start=index, stop=index + 1):
        return rec.scenario
    raise DataError(f"no record {index} (file has fewer records)", file=path, record=index)


def unbatch(scenarios: Iterable[Scenario]) -> Iterator[Scenario]:
    for s in scenarios:
        if s.batch_shape:
            yield from unbatch(index_scenario(s, i) for i in range(s.batch_shape[0]))
        else:
            yield s


def write_tfexample(path: str | os.PathLike, scenarios: Iterable[Scenario] | Scenario) -> int:
    """Write scenarios (batched or not) as WOMD tf.Example records, atomically; returns the count.
    For compact files, pass them through :func:`~igdrivsim.data.scenario.trim_padding` first."""
    if isinstance(scenarios, Scenario):
        scenarios = [scenarios]
    return tfrecord.write_records(path, map(encode_tfexample, unbatch(scenarios)))
