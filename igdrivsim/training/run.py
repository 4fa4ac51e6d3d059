"""A training run's folder and bookkeeping: ``config.json``, ``metrics.jsonl``,
``curves.jsonl``, ``checkpoints/`` and ``DONE``; resume; logs; hooks.

:class:`Run` owns everything a run writes, so the training loop
(:func:`igdrivsim.training.loop.train`) is the pure update of
:func:`~igdrivsim.training.loop.make_train` applied to batches, with ``Run`` called at its
edges. A *hook* (:class:`Hook`) is called with the parameters every ``every`` updates (and at
the start and the end of the run); the values it returns (``{name: [G, S] array}``) go to
``curves.jsonl``. The learning-curve validation is one (:class:`igdrivsim.training.loop.
Validation`); training never imports the evaluation package.
"""

from __future__ import annotations

import contextlib
import json
import os
from collections.abc import Callable
from dataclasses import dataclass

import jax
import numpy as np
from tqdm.auto import tqdm

from igdrivsim.errors import ConfigError
from igdrivsim.io import atomic_write_json, atomic_write_text
from igdrivsim.training.checkpoint import Checkpoints
from igdrivsim.training.config import RunConfig, from_dict, to_dict

CONFIG, METRICS, CURVES, DONE = "config.json", "metrics.jsonl", "curves.jsonl", "DONE"


def is_complete(out_dir: str | os.PathLike) -> bool:
    return os.path.isfile(os.path.join(out_dir, DONE))


def barrier(name: str, timeout_s: int = 3600) -> None:
    """Wait until every process gets here (several processes only). Gloo's CPU collectives give
    up after 30 s, so processes meet here before work whose duration differs between them
    (compiling, loading) is followed by a collective."""
    if jax.process_count() > 1:
        from jax._src import distributed  # private JAX API: only for several processes

        distributed.global_state.client.wait_at_barrier(f"igdrivsim-{name}", timeout_s * 1000)


@dataclass(frozen=True)
class Hook:
    """``fn(params) -> {name: [G, S] values}`` every ``every`` updates, at the start of a fresh
    run and at its last update; the values are written to ``curves.jsonl``."""

    every: int
    fn: Callable[[object], dict]


def truncate_jsonl(path: str, upto: int) -> None:
    """Keep the lines of updates ``<= upto`` (a resumed run re-logs the rest); a line torn by
    a kill mid-write (not JSON, or without an update) is dropped with the rest."""
    if not os.path.isfile(path):
        return

    def update_of(line: str) -> int | None:
        try:
            entry = json.loads(line)
        except ValueError:
            return None
        return entry.get("update") if isinstance(entry, dict) else None

    with open(path) as f:
        kept = [ln if ln.endswith("\n") else ln + "\n" for ln in f
                if isinstance(u := update_of(ln), int) and u <= upto]
    atomic_write_text(path, "".join(kept))


def log_line(update: int, lr: float, metrics: dict, rates: dict) -> dict:
    """One ``metrics.jsonl`` line: each metric's mean over settings and seeds, and its
    per-seed means (over settings) as ``<name>_seeds``."""
    line = {"update": update, "lr": lr, **rates}
    for name, values in metrics.items():
        values = np.asarray(values, np.float64)  # [G, S]
        line[name] = float(values.mean())
        line[f"{name}_seeds"] = [float(v) for v in values.mean(axis=0)]
    return line


def curve_lines(update: int, settings: list[str], method: str, seeds: list[int],
                values: dict) -> list[dict]:
    """One curves.jsonl line per (setting, seed) from ``{name: [G, S] array}``."""
    return [{"update": update, "setting": name, "method": method, "seed": seed,
             **{k: float(np.asarray(v)[g, i]) for k, v in values.items()}}
            for g, name in enumerate(settings) for i, seed in enumerate(seeds)]


# How a run is kept, not what it computes: a run resumes under other values of these.
BOOKKEEPING = (("training", "checkpoint_every"), ("training", "max_checkpoints"),
               ("data", "prefetch"))


def _computed(config) -> object:
    """A config dict (JSON types) without its :data:`BOOKKEEPING` fields."""
    config = json.loads(json.dumps(config))
    if isinstance(config, dict):
        for section, name in BOOKKEEPING:
            if isinstance(config.get(section), dict):
                config[section].pop(name, None)
    return config


class Run:
    """The folder of one run of ``config`` (every setting x seed), on every process; only
    process 0 writes. Use as a context manager around the update loop."""

    def __init__(self, out_dir: str | os.PathLike, config: RunConfig, settings: list[str],
                 resume: bool = False, log: Callable[[str], None] = print,
                 hooks: tuple[Hook, ...] = ()):
        self.dir = os.fspath(out_dir)
        self.config, self.settings, self.resume, self.log = config, settings, resume, log
        self.hooks = hooks
        self.main = jax.process_index() == 0
        t = config.training
        self.seeds = list(range(t.seed_offset, t.seed_offset + t.seeds))
        self.record = {"config": to_dict(config)}
        self.ckpt: Checkpoints | None = None
        self._files = contextlib.ExitStack()
        self.bar = None

    # ------------------------------------------------------------------------- the folder
    def complete_already(self) -> bool:
        """Look at the folder before anything is written: True when the run is complete (then
        nothing is to be done); refuses another configuration, and an unfinished run without
        ``resume``."""
        os.makedirs(self.dir, exist_ok=True)
        if os.path.isfile(os.path.join(self.dir, CONFIG)):
            self._check_config()
            if is_complete(self.dir):
                self.log(f"run {self.dir} is already complete; nothing to do")
                return True
            if not self.resume:
                raise ConfigError(f"{self.dir} holds an unfinished run; pass --resume to "
                                  "continue it")
        # every process has looked at the folder before process 0 writes config.json (a
        # slower process would otherwise find it and refuse to start a "resumed" run)
        barrier("checked")
        return False

    def _check_config(self) -> None:
        """Refuse to resume a run started with another configuration (fields added to the
        config classes since then count at their defaults; :data:`BOOKKEEPING` fields may
        differ)."""
        path = os.path.join(self.dir, CONFIG)
        with open(path) as f:
            old = json.load(f)
        try:
            old_config = to_dict(from_dict(old.get("config", {})))
        except (ConfigError, TypeError):
            old_config = old.get("config")
        if _computed(old_config) != _computed(self.record["config"]):
            raise ConfigError(f"{path}: the run was started with a different configuration; "
                              "use another --out or the same options")

    def write_config(self, **facts) -> None:
        """``config.json``: the resolved config and ``facts`` (updates, scenarios, devices)."""
        self.record |= facts
        if self.main:
            atomic_write_json(os.path.join(self.dir, CONFIG), self.record, indent=2)

    # ------------------------------------------------------------------ resume and saving
    def restore(self, state: tuple) -> tuple[int, tuple]:
        """``(updates done, state)``: the latest checkpoint's when resuming, else ``(0,
        state)``; the logs are cut back to that update."""
        t = self.config.training
        self.ckpt = Checkpoints(self.dir, t.max_checkpoints)
        start = 0
        if self.resume and self.ckpt.latest_step() is not None:
            start = self.ckpt.latest_step()
            state = self.ckpt.restore(start, *state)
            self.log(f"resuming from update {start}")
        if self.main:
            for name in (METRICS, CURVES):
                truncate_jsonl(os.path.join(self.dir, name), start if self.resume else -1)
        return start, state

    def checkpoint(self, done: int, state: tuple, data_state=None) -> None:
        if data_state is not None:  # the input iterator's state, saved first
            from igdrivsim.training.stream import save_state  # lazy: grain, data.stream only

            save_state(self.dir, done, data_state, self.ckpt.manager.all_steps())
        barrier(f"save-{done}")
        self.ckpt.save(done, *state)

    def finish(self, end: int, num_updates: int) -> bool:
        """Close the checkpoints; ``DONE`` when the last update is done. Returns complete."""
        self.ckpt.close()
        complete = end == num_updates
        if complete and self.main:
            atomic_write_text(os.path.join(self.dir, DONE), f"{num_updates}\n")
        return complete

    # ----------------------------------------------------------------------------- logs
    def __enter__(self) -> Run:
        opener = (lambda p: open(p, "a")) if self.main else (lambda p: open(os.devnull, "w"))
        self.metrics_file = self._files.enter_context(opener(os.path.join(self.dir, METRICS)))
        self.curves_file = self._files.enter_context(opener(os.path.join(self.dir, CURVES)))
        return self

    def __exit__(self, *exc) -> None:
        if self.bar is not None:
            self.bar.close()
        self._files.close()

    def progress(self, start: int, num_updates: int) -> None:
        """A progress bar (rate and ETA) on process 0."""
        if self.main:
            self.bar = tqdm(total=num_updates, initial=start, unit="upd", desc="train",
                            dynamic_ncols=True)

    def curves(self, done: int, values: dict) -> None:
        for line in curve_lines(done, self.settings, self.config.training.method, self.seeds,
                                values):
            self.curves_file.write(json.dumps(line) + "\n")
        self.curves_file.flush()

    def metrics(self, done: int, lr: float, metrics: dict, rates: dict) -> None:
        """A ``metrics.jsonl`` line and the training loss's curve points."""
        line = log_line(done, lr, metrics, rates)
        self.metrics_file.write(json.dumps(line) + "\n")
        self.metrics_file.flush()
        loss_key = "bc_loss" if "bc_loss" in metrics else "teacher_ce"
        self.curves(done, {loss_key: metrics[loss_key]})
        if self.bar is not None:
            self.bar.set_postfix({loss_key: f"{line[loss_key]:.3f}"}, refresh=False)

    def run_hooks(self, done: int, params, last: bool = False) -> bool:
        """Call the hooks due at ``done`` (0: a fresh run's start); True when one ran."""
        ran = False
        for hook in self.hooks:
            if hook.every > 0 and (done % hook.every == 0 or last):
                self.curves(done, hook.fn(params))
                ran = True
        return ran
