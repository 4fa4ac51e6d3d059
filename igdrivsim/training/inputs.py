"""The training input pipeline: load once, reset once, record once, shuffle, prefetch.

Scenarios (:func:`~igdrivsim.data.source.open_scenarios`, fitted to the profile's capacities)
are ``reset`` once; the teacher-forced records (:mod:`igdrivsim.training.records`) and, for the
methods that drive, the states stay in host memory, so a batch is a gather. Seed ``s`` walks
the data in epochs, each a permutation drawn from ``numpy.random.default_rng([seed, epoch])``:
a batch is a pure function of ``(seed, update)``, so a resumed run sees the batches an
uninterrupted one would. A background thread places the next ``prefetch`` batches on the
devices (streamed batches too).
"""

from __future__ import annotations

import contextlib
import functools
import os
import queue
import threading
from collections.abc import Iterator, Sequence
from itertools import islice

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding
from tqdm.auto import tqdm

from igdrivsim.core.devices import place
from igdrivsim.data.scenario import Scenario, stack_scenarios
from igdrivsim.data.source import check_data, count_scenarios, data_identity, open_scenarios
from igdrivsim.errors import ConfigError, DataError
from igdrivsim.observation import ObservationRecord
from igdrivsim.simulator import SimParams, SimState, reset
from igdrivsim.training.config import RunConfig
from igdrivsim.training.records import cache_key, compute_records, load_or_compute


@functools.lru_cache(maxsize=8)
def _jit_reset(params: SimParams):
    return jax.jit(lambda s: reset(s, params))


def reset_chunk(scenarios: Sequence[Scenario], params: SimParams, size: int) -> SimState:
    """``reset`` (jitted; padded to ``size`` for one compiled shape) -> host ``SimState [n]``."""
    n = len(scenarios)
    part = list(scenarios) + [scenarios[0]] * (size - n)
    state = jax.device_get(_jit_reset(params)(stack_scenarios(part)))
    return jax.tree.map(lambda x: np.asarray(x)[:n], state)


def reset_all(chunks, params: SimParams, chunk: int = 64, progress: bool = False,
              total: int | None = None) -> SimState:
    """Every scenario of ``chunks`` (lists of scenarios) reset, stacked on the host ``[N]``;
    ``total``: the bar's (None: unknown)."""
    parts = []
    with tqdm(total=total, desc="loading", unit="scn", dynamic_ncols=True,
              disable=not progress) as bar:
        for scenarios in chunks:
            parts.append(reset_chunk(scenarios, params, chunk))
            bar.update(len(scenarios))
    if not parts:
        raise DataError("no training scenarios found")
    return jax.tree.map(lambda *xs: np.concatenate(xs), *parts)


def batch_indices(num_scenarios: int, batch_size: int, seed: int, update: int) -> np.ndarray:
    """Scenario indices of update ``update`` for seed ``seed`` (epoch-wise permutations)."""
    pos = np.arange(update * batch_size, (update + 1) * batch_size, dtype=np.int64)
    epochs, offsets = pos // num_scenarios, pos % num_scenarios
    out = np.empty(batch_size, np.int64)
    for e in np.unique(epochs):
        perm = np.random.default_rng([int(seed), int(e)]).permutation(num_scenarios)
        out[epochs == e] = perm[offsets[epochs == e]]
    return out


class Dataset:
    """Teacher-forced records (and, for BC-RL, reset states) of all training scenarios in host
    memory, and the batch sampler."""

    def __init__(self, teacher: ObservationRecord | None, states: SimState | None, batch_size: int,
                 seeds: Sequence[int]):
        self.teacher, self.states, self.batch_size = teacher, states, batch_size
        self.num = int(np.shape(teacher.sdc_yaw if teacher is not None else states.timestep)[0])
        self.seeds = [int(s) for s in seeds]

    @classmethod
    def from_config(cls, config: RunConfig, data, params: SimParams, progress: bool = False,
                    chunk: int = 64, cache_dir: str | None = None, need_states: bool = False,
                    max_scenarios: int | None = None, record: bool | None = None) -> Dataset:
        """Load ``data`` (folder / files, or a list of :class:`Scenario`), the records from
        ``cache_dir`` when computed before; ``record`` False (default:
        ``config.data.record_teacher``) keeps states only: the update records each batch."""
        d, rec = config.data, config.record_config
        limit = d.max_scenarios if max_scenarios is None else max_scenarios
        on_disk = isinstance(data, (str, os.PathLike))

        def load() -> SimState:  # the bar's total: the manifest's kept rows, the records, the list
            if on_disk:
                total = count_scenarios(data, limit, d.egos) if progress else None
                check_data(data, "training")
                records = open_scenarios(data, config.capacities, egos=d.egos, limit=limit)
                chunks = iter(lambda: [r.scenario for r in islice(records, chunk)], [])
            else:
                scenarios = list(data)[: limit or None]
                total = len(scenarios)
                chunks = (scenarios[i:i + chunk] for i in range(0, len(scenarios), chunk))
            return reset_all(chunks, params, chunk, progress, total)

        if not (d.record_teacher if record is None else record):
            return cls(None, load(), d.batch_size, config.seeds)
        states = None

        def compute():
            nonlocal states
            states = load()
            return compute_records(states, params, rec, progress=progress)

        key = None
        if cache_dir and on_disk:
            egos = {} if d.egos == "sdc" else {"egos": d.egos}  # the keys of before, for sdc
            key = cache_key(data_identity(data), caps=config.capacities, rec=rec, sim=params,
                            limit=limit, **egos)
        teacher = load_or_compute(cache_dir if key else None, key or "", compute)
        if need_states and states is None:
            states = load()
        return cls(teacher, states if need_states else None, d.batch_size, config.seeds)

    def indices(self, update: int) -> np.ndarray:
        """Scenario indices ``[S, B]`` of update ``update``."""
        return np.stack([batch_indices(self.num, self.batch_size, s, update) for s in self.seeds])

    def host_batch(self, update: int):
        """``(teacher [S, B] or None, states [S, B] or None)`` on the host for ``update``."""
        idx = self.indices(update)
        take = lambda tree: None if tree is None else jax.tree.map(lambda x: x[idx], tree)
        return take(self.teacher), take(self.states)

    def host_batches(self, updates: range, state=None) -> Iterator[tuple]:
        """``(host batch, None)`` for each of ``updates`` (the order needs no saved state)."""
        for u in updates:
            yield self.host_batch(u), None

    place = staticmethod(place)  # the devices' copy of a host batch


def prefetch(dataset, updates: range, sharding: NamedSharding, depth: int = 2,
             state: dict | None = None) -> Iterator[tuple]:
    """Yield ``(placed batch, input state after it)`` for ``updates`` in order; a daemon thread
    works ``depth`` ahead. ``dataset``: a :class:`Dataset` or a streaming
    :class:`~igdrivsim.training.stream.StreamDataset` (``state`` resumes its iterator)."""
    if depth <= 0:
        for batch, st in dataset.host_batches(updates, state):
            yield dataset.place(batch, sharding), st
        return
    q: queue.Queue = queue.Queue(maxsize=depth)
    stop = threading.Event()

    def work():
        try:
            for batch, st in dataset.host_batches(updates, state):
                item = (dataset.place(batch, sharding), st)
                while not stop.is_set():
                    with contextlib.suppress(queue.Full):
                        q.put(item, timeout=0.1)
                        break
                if stop.is_set():
                    return
        except BaseException as err:  # surface loader errors in the training thread
            q.put(err)

    thread = threading.Thread(target=work, name="igdrivsim-prefetch", daemon=True)
    thread.start()
    try:
        for _ in updates:
            item = q.get()
            if isinstance(item, BaseException):
                raise item
            yield item
    finally:
        stop.set()
        thread.join(timeout=5)


def check_batch(batch_size: int, mesh: Mesh) -> None:
    if batch_size % mesh.size:
        raise ConfigError(f"data.batch_size ({batch_size}) must be a multiple of the number of "
                          f"devices ({mesh.size})")
