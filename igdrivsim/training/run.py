"""A training run's folder: what a run writes (:class:`Run`) and reads back
(:meth:`Run.open`, a :class:`SavedRun`); every file name of the folder is spelled here, once.

- ``config.json``: the resolved :class:`RunConfig` under ``"config"``, the run's facts and the
  code that trained (``code``; ``code_resumed``: other code that continued the run);
- ``metrics.jsonl``: one line per logged update, each metric's mean over settings and seeds
  and ``<metric>_seeds`` its per-seed means;
- ``curves.jsonl``: one line per (update, setting, seed): the reported training loss and
  what the validation hook (:attr:`Run.hook`) returns;
- ``checkpoints/<updates done>/`` (:class:`Checkpoints`, Orbax; with ``data.stream`` also
  each process's input iterator state): data order, keys and learning rate are functions of
  the update, so restoring step ``k`` resumes the run exactly;
- ``DONE``: written when the last checkpoint is saved.
"""

from __future__ import annotations

import contextlib
import functools
import json
import os
import sys
from collections.abc import Callable

import jax
import numpy as np
import orbax.checkpoint as ocp
from flax import serialization

from igdrivsim.core.devices import barrier
from igdrivsim.errors import ConfigError, DataError
from igdrivsim.io import atomic_write_json, atomic_write_text, read_json
from igdrivsim.machine import code_state
from igdrivsim.training.config import RunConfig, from_dict, to_dict
from igdrivsim.training.methods import get_method

# The files of a run folder (see the module docstring).
CONFIG, METRICS, CURVES, DONE = "config.json", "metrics.jsonl", "curves.jsonl", "DONE"
CHECKPOINTS = "checkpoints"
DATA_STATES = os.path.join(CHECKPOINTS, "data")

_MESSAGE_CHARS = 300  # tensorstore messages carry a whole JSON spec: keep the start


def _first_line(err: BaseException) -> str:
    """``Type: first line of the message``, cut before tensorstore's spec dump and shortened."""
    lines = str(err).strip().splitlines()
    text = lines[0].strip() if lines else ""
    text = text.split(" [tensorstore_spec", 1)[0]
    if len(text) > _MESSAGE_CHARS:
        text = text[:_MESSAGE_CHARS - 3].rstrip() + "..."
    return f"{type(err).__name__}: {text}" if text else type(err).__name__


def _drop_closed_loop_reports() -> None:
    """After a failed restore, tensorstore reads still in flight call back into orbax's event
    loop, already closed, and each prints a traceback (via ``sys.unraisablehook``): drop those
    reports only, so the error stays one line."""
    previous = sys.unraisablehook
    if getattr(previous, "_drops_closed_loop", False):
        return

    def hook(unraisable) -> None:
        exc = unraisable.exc_value
        if isinstance(exc, RuntimeError) and str(exc) == "Event loop is closed":
            return
        previous(unraisable)

    hook._drops_closed_loop = True  # type: ignore[attr-defined]
    sys.unraisablehook = hook


class Checkpoints:
    """Save / restore ``{"params", "opt_state"}`` (stacked over seeds) in the folder ``path``."""

    def __init__(self, path: str | os.PathLike, max_to_keep: int = 2):
        self.path = os.path.abspath(os.fspath(path))
        options = ocp.CheckpointManagerOptions(max_to_keep=max_to_keep, create=True)
        self.manager = ocp.CheckpointManager(self.path, options=options,
                                             item_handlers=ocp.StandardCheckpointHandler())

    def save(self, step: int, params, opt_state, buffer=None) -> None:
        """Save synchronously (returns when the checkpoint is complete on disk)."""
        if step in self.manager.all_steps():
            return
        items = {"params": params, "opt_state": opt_state}
        if buffer is not None:
            items["buffer"] = serialization.to_state_dict(buffer)
        self.manager.save(step, args=ocp.args.StandardSave(items))
        self.manager.wait_until_finished()

    def restore(self, step: int, params_like, opt_state_like, buffer_like=None):
        """``(params, opt_state, buffer)`` in the templates' structure and shardings."""
        items = {"params": params_like, "opt_state": opt_state_like}
        if buffer_like is not None:
            items["buffer"] = serialization.to_state_dict(buffer_like)
        out = self._restore(step, lambda: items)
        buffer = (None if buffer_like is None
                  else self._checked(step, serialization.from_state_dict, buffer_like,
                                     out["buffer"]))
        return out["params"], out["opt_state"], buffer

    def restore_params(self, step: int):
        """The parameters of checkpoint ``step`` as saved (no template needed)."""
        return self._restore(step, lambda: jax.tree.map(
            lambda m: jax.ShapeDtypeStruct(m.shape, m.dtype),
            dict(self.manager.item_metadata(step))))["params"]

    def _restore(self, step: int, items: Callable[[], dict]) -> dict:
        """The tree ``items()``, each leaf on its template's sharding, else this process's first
        device."""
        default = jax.sharding.SingleDeviceSharding(jax.local_devices()[0])

        def abstract(x):
            sharding = getattr(x, "sharding", None) or default
            return jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=sharding)

        return self._checked(step, lambda: self.manager.restore(
            step, args=ocp.args.StandardRestore(jax.tree.map(abstract, items()))))

    def _checked(self, step: int, fn: Callable, *args):
        """``fn(*args)``; an orbax / tensorstore failure (corrupt, truncated or foreign files)
        becomes a one-line :class:`DataError` naming the checkpoint."""
        try:
            return fn(*args)
        except Exception as err:
            _drop_closed_loop_reports()
            raise DataError(f"cannot restore checkpoint {step} ({_first_line(err)})",
                            file=os.path.join(self.path, str(step))) from err

    def close(self) -> None:
        self.manager.close()


def is_run(out_dir: str | os.PathLike) -> bool:
    """A run folder: training has written its ``config.json``."""
    return os.path.isfile(os.path.join(out_dir, CONFIG))


def is_complete(out_dir: str | os.PathLike) -> bool:
    return os.path.isfile(os.path.join(out_dir, DONE))


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


def read_jsonl(path: str | os.PathLike) -> list[dict]:
    """The records of a ``.jsonl`` file of a run (``[]`` when it does not exist); a line that
    is not a JSON object is a one-line :class:`DataError` naming the file and the line."""
    path = os.fspath(path)
    if not os.path.isfile(path):
        return []
    records = []
    with open(path) as f:
        for number, line in enumerate(f, start=1):
            if not line.strip():
                continue
            try:
                record = json.loads(line)
            except ValueError as err:
                raise DataError(f"bad record on line {number} ({err})", file=path) from err
            if not isinstance(record, dict):
                raise DataError(f"bad record on line {number} (not a JSON object)", file=path)
            records.append(record)
    return records


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

    def __init__(self, out_dir: str | os.PathLike, config: RunConfig, resume: bool = False,
                 log: Callable[[str], None] = print):
        self.dir = os.fspath(out_dir)
        self.config, self.resume, self.log = config, resume, log
        # the driver's learning-curve validation: params -> {name: [G, S] values}
        self.hook: Callable[[object], dict] | None = None
        self.main = jax.process_index() == 0
        # a resumed run keeps the code it started with and lists other code that continued it
        self.record = {"config": to_dict(config), "code": code_state()}
        self.data_states = os.path.join(self.dir, DATA_STATES)  # a streamed input's states
        self.ckpt: Checkpoints | None = None
        self._files = contextlib.ExitStack()
        self.bar = None  # the driver's progress bar (process 0)

    @staticmethod
    def open(out_dir: str | os.PathLike) -> SavedRun:
        """The read side: the run in ``out_dir`` as training left it (:class:`SavedRun`)."""
        return SavedRun(out_dir)

    # ------------------------------------------------------------------------- the folder
    def complete_already(self) -> bool:
        """True when the run is complete (nothing to do); refuses another configuration, and an
        unfinished run without ``resume``."""
        os.makedirs(self.dir, exist_ok=True)
        if is_run(self.dir):
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
        old = read_json(path)
        try:
            old_config = to_dict(from_dict(old.get("config", {})))
        except (ConfigError, TypeError):
            old_config = old.get("config")
        if _computed(old_config) != _computed(self.record["config"]):
            raise ConfigError(f"{path}: the run was started with a different configuration; "
                              "use another --out or the same options")
        if isinstance(old.get("code"), dict):
            now, resumed = self.record["code"], list(old.get("code_resumed", []))
            self.record["code"] = old["code"]
            if now != old["code"] and now not in resumed:
                resumed.append(now)
            if resumed:
                self.record["code_resumed"] = resumed

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
        self.ckpt = Checkpoints(os.path.join(self.dir, CHECKPOINTS), t.max_checkpoints)
        start = 0
        if self.resume and self.ckpt.manager.latest_step() is not None:
            start = self.ckpt.manager.latest_step()
            state = self.ckpt.restore(start, *state)
            self.log(f"resuming from update {start}")
        if self.main:
            for name in (METRICS, CURVES):
                truncate_jsonl(os.path.join(self.dir, name), start if self.resume else -1)
        return start, state

    def checkpoint(self, done: int, state: tuple, data_state=None) -> None:
        if data_state is not None:  # the input iterator's state, saved first
            from igdrivsim.training.stream import save_state  # lazy: grain, data.stream only

            save_state(self.data_states, done, data_state, self.ckpt.manager.all_steps())
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

    def curves(self, done: int, values: dict) -> None:
        """One ``curves.jsonl`` line per (setting, seed) from ``{name: [G, S] array}``."""
        for g, name in enumerate(self.config.settings):
            for i, seed in enumerate(self.config.seeds):
                line = {"update": done, "setting": name, "method": self.config.training.method,
                        "seed": seed, **{k: float(np.asarray(v)[g, i]) for k, v in values.items()}}
                self.curves_file.write(json.dumps(line) + "\n")
        self.curves_file.flush()

    def metrics(self, done: int, lr: float, metrics: dict, rates: dict) -> None:
        """A ``metrics.jsonl`` line (each metric's mean over settings and seeds, and its
        per-seed means as ``<name>_seeds``) and the reported loss's curve points."""
        line = {"update": done, "lr": lr, **rates}
        for name, values in metrics.items():
            values = np.asarray(values, np.float64)  # [G, S]
            line[name] = float(values.mean())
            line[f"{name}_seeds"] = [float(v) for v in values.mean(axis=0)]
        self.metrics_file.write(json.dumps(line) + "\n")
        self.metrics_file.flush()
        key = get_method(self.config.training.method).reports
        self.curves(done, {key: metrics[key]})
        if self.bar is not None:
            self.bar.set_postfix({key: f"{line[key]:.3f}"}, refresh=False)

    def run_hook(self, done: int, params, last: bool = False) -> bool:
        """Write the hook's values when due at ``done``: every ``eval_every`` updates, at the
        start of a fresh run (0) and at its last update; True when it ran."""
        due = self.hook is not None and (done % self.config.training.eval_every == 0 or last)
        if due:
            self.curves(done, self.hook(params))
        return due


class SavedRun:
    """A run folder read back (:meth:`Run.open`)."""

    def __init__(self, out_dir: str | os.PathLike):
        """Read ``config.json``; a one-line error when the folder holds no run or it cannot
        be read."""
        self.dir = os.fspath(out_dir)
        path = os.path.join(self.dir, CONFIG)
        if not os.path.isfile(path):
            raise ConfigError(f"{path}: not a training run (no {CONFIG})")
        self.record = read_json(path)
        if not isinstance(self.record.get("config"), dict):
            raise DataError("not a run config (no \"config\" object)", file=path)

    @functools.cached_property
    def config(self) -> RunConfig:
        try:
            return from_dict(self.record["config"])
        except (TypeError, KeyError) as err:  # a field of the wrong kind
            raise DataError(f"not a run's config ({err})",
                            file=os.path.join(self.dir, CONFIG)) from err

    @property
    def complete(self) -> bool:
        """The run did its last update (``DONE``)."""
        return is_complete(self.dir)

    def latest_step(self) -> int | None:
        """The updates done at the latest checkpoint (``None`` without one)."""
        with contextlib.closing(Checkpoints(os.path.join(self.dir, CHECKPOINTS))) as ckpt:
            return ckpt.manager.latest_step()

    def params(self, step: int | None = None):
        """The parameters stacked over settings and seeds ``[G, S]`` at checkpoint ``step``
        (default: the latest), on this process's first device."""
        with contextlib.closing(Checkpoints(os.path.join(self.dir, CHECKPOINTS))) as ckpt:
            step = ckpt.manager.latest_step() if step is None else step
            if step is None:
                raise ConfigError(f"{self.dir}: no checkpoint yet")
            return ckpt.restore_params(step)

    def curves(self) -> list[dict]:
        """The ``curves.jsonl`` records (one per update, setting and seed; ``[]`` without)."""
        return read_jsonl(os.path.join(self.dir, CURVES))

    def metrics(self) -> list[dict]:
        """The ``metrics.jsonl`` records (one per logged update; ``[]`` without)."""
        return read_jsonl(os.path.join(self.dir, METRICS))
