"""Streaming training input for paper scale (``data.stream``), built on Grain: bounded host
memory, per-host shards, resumable order.

The scenarios (:class:`ScenarioIndex`) are split into ``n = data.shards`` (default: the number
of processes) disjoint shards ``j::n``, each process owning a contiguous block. Per seed and
shard, Grain's ``MapDataset.range(len).shuffle(seed).repeat()`` permutes each epoch; batch ``u``
of a process takes, per seed, positions ``u b .. (u+1) b - 1`` of each owned shard (``b = B /
n``), decoded and reset ``data.buffer`` batches ahead in ``data.workers`` threads. The
iterator's state is saved beside each checkpoint and restored on ``--resume``.
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Sequence

import grain
import jax
import numpy as np
from jax.sharding import NamedSharding

from igdrivsim.data.scenario import Capacities, Scenario
from igdrivsim.data.source import check_data, load_ref, scenario_refs
from igdrivsim.errors import ConfigError, DataError
from igdrivsim.io import atomic_write_json, read_json
from igdrivsim.simulator import SimParams, SimState
from igdrivsim.training import inputs
from igdrivsim.training.config import RunConfig


class ScenarioIndex:
    """Random access to the scenarios :func:`~igdrivsim.data.source.open_scenarios` reads from
    ``data`` (a Grain data source): ``(file id, record[, ego object id])`` per scenario
    (:func:`~igdrivsim.data.source.scenario_refs`), decoded on demand."""

    def __init__(self, data: str | os.PathLike, caps: Capacities, limit: int = 0,
                 egos: str = "sdc"):
        files, refs = scenario_refs(data, limit, egos)
        refs = np.asarray(refs, np.int32)
        if refs.shape[1] == 3 and (refs[:, 2] < 0).all():
            refs = refs[:, :2]  # the logged SDCs: no ego column
        self.files, self.refs, self.caps = files, refs, caps

    def __len__(self) -> int:
        return len(self.refs)

    def __getitem__(self, i: int) -> Scenario:
        row = self.refs[int(i)]
        ego = int(row[2]) if len(row) > 2 else -1
        return load_ref(self.files[int(row[0])], int(row[1]), ego, self.caps)


def shard_order(shard_len: int, seed: int, shard: int) -> grain.MapDataset:
    """Scenario positions within a shard in training order: an infinite stream of epochs, each
    a permutation seeded by ``(seed, shard, epoch)``."""
    mixed = int(np.random.SeedSequence([int(seed), int(shard)]).generate_state(1)[0])
    return grain.MapDataset.range(shard_len).shuffle(seed=mixed).repeat()


class StreamDataset:
    """Per-process batches ``(None, states [S, b_local])`` read, decoded and reset on demand;
    the same interface as :class:`~igdrivsim.training.inputs.Dataset` for the loop."""

    teacher = None

    def __init__(self, source, batch_size: int, seeds: Sequence[int], params: SimParams,
                 num_shards: int = 0, process: int | None = None,
                 processes: int | None = None, workers: int = 2, buffer: int = 2):
        process = jax.process_index() if process is None else process
        processes = jax.process_count() if processes is None else processes
        self.num_shards = num_shards or processes
        if batch_size % self.num_shards:
            raise ConfigError(f"data.batch_size ({batch_size}) must be a multiple of "
                              f"data.shards ({self.num_shards})")
        self.source, self.params = source, params
        self.num = len(source)  # global number of scenarios
        if self.num < self.num_shards:
            raise DataError(f"{self.num} scenarios cannot fill {self.num_shards} shards")
        self.batch_size = batch_size
        self.per_shard = batch_size // self.num_shards
        self.seeds = [int(s) for s in seeds]
        if self.num_shards % processes:
            raise ConfigError(f"data.shards ({self.num_shards}) must be a multiple of the "
                              f"number of processes ({processes})")
        per = self.num_shards // processes  # this process reads a contiguous block of shards
        self.shards = range(process * per, (process + 1) * per)
        # positions (global indices) of each owned shard, and its order per seed
        self.members = {j: np.arange(j, self.num, self.num_shards) for j in self.shards}
        self.orders = {(s, j): shard_order(len(self.members[j]), s, j)
                       for s in self.seeds for j in self.shards}
        self.workers, self.buffer = workers, buffer

    @classmethod
    def from_config(cls, config: RunConfig, data, params: SimParams) -> StreamDataset:
        d = config.data
        if isinstance(data, (str, os.PathLike)):
            check_data(data, "training")
            source = ScenarioIndex(data, config.capacities, d.max_scenarios, d.egos)
        else:
            source = list(data)[: d.max_scenarios or None]
        return cls(source, d.batch_size, config.seeds, params, d.shards, workers=d.workers,
                   buffer=d.buffer)

    def indices(self, update: int) -> np.ndarray:
        """Global scenario indices ``[S, b_local]`` this process reads for ``update``."""
        pos = range(update * self.per_shard, (update + 1) * self.per_shard)
        return np.asarray([[self.members[j][self.orders[(s, j)][p]] for j in self.shards
                            for p in pos] for s in self.seeds], np.int64)

    def host_batch(self, update: int) -> tuple[None, SimState]:
        """Decode and reset the scenarios of ``update`` on the host: ``(None, states [S, b])``."""
        idx = self.indices(update)
        flat = [self.source[int(i)] for i in idx.reshape(-1)]
        states = inputs.reset_chunk(flat, self.params, len(flat))  # late-bound: tests patch it
        return None, jax.tree.map(lambda x: x.reshape(idx.shape + x.shape[1:]), states)

    def host_batches(self, updates: range, state: dict | None = None) -> Iterator:
        """``(host batch, iterator state after it)`` for each of ``updates``, from a Grain
        iterator (threaded, ``buffer`` ahead; nothing read past the last update); ``state``
        (saved with the checkpoint of the first update) resumes it exactly."""
        start = updates.start
        ds = grain.MapDataset.range(updates.stop).map(self.host_batch)
        it = iter(ds.to_iter_dataset(grain.ReadOptions(num_threads=self.workers,
                                                       prefetch_buffer_size=self.buffer)))
        state = {"next_index": start} if state is None else state
        if state.get("next_index") != start:
            raise ConfigError(f"saved input iterator state {state} does not match update {start}")
        it.set_state(state)
        for _ in updates:
            batch = next(it)
            yield batch, it.get_state()
        if hasattr(it, "close"):  # stop Grain's reader threads now, not at exit
            it.close()

    def place(self, batch, sharding: NamedSharding):
        """This process's part ``[S, b_local]`` -> global arrays ``[S, B]``."""

        def one(x):
            x = np.asarray(x)
            shape = (x.shape[0], self.batch_size, *x.shape[2:])
            return jax.make_array_from_process_local_data(sharding, x, shape)

        return jax.tree.map(one, batch)


def state_path(folder: str, step: int, process: int) -> str:
    """Where ``process`` keeps its iterator state of checkpoint ``step`` in ``folder``."""
    return os.path.join(folder, f"{step}.p{process}.json")


def save_state(folder: str, step: int, state: dict, keep: Sequence[int]) -> None:
    """Save this process's iterator state of checkpoint ``step``; prune those of checkpoints
    no longer kept."""
    process = jax.process_index()
    os.makedirs(folder, exist_ok=True)
    atomic_write_json(state_path(folder, step, process), {"step": step, "iterator": state})
    for name in os.listdir(folder):
        head, _, tail = name.partition(".p")
        if tail == f"{process}.json" and head.isdigit() and int(head) not in set(keep) | {step}:
            os.remove(os.path.join(folder, name))


def load_state(folder: str, step: int) -> dict:
    """The iterator state saved with checkpoint ``step`` by this process in ``folder``."""
    path = state_path(folder, step, jax.process_index())
    if not os.path.isfile(path):
        raise ConfigError(f"{path}: no input iterator state for checkpoint {step}; "
                          "cannot resume the streamed run exactly")
    return read_json(path)["iterator"]
