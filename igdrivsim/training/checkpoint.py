"""Orbax checkpoints of a run: ``<updates done>/`` folders under the run's checkpoint folder
(:data:`igdrivsim.training.run.CHECKPOINTS`) holding params + optimiser (+ DAgger's buffer of
labelled episodes, for the methods that keep one).

Orbax writes each step into a temporary folder and renames it when complete, so a run killed
mid-save leaves the previous checkpoint intact. The step number is the number of updates done;
everything else (data order, keys, learning rate) is a function of it, so restoring
``(params, opt_state, buffer)`` at step ``k`` resumes the run exactly.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable

import jax
import orbax.checkpoint as ocp
from flax import serialization

from igdrivsim.errors import DataError

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

    def latest_step(self) -> int | None:
        return self.manager.latest_step()

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
        """``(params, opt_state, buffer)`` restored into the structure (and shardings) of the
        given templates (``buffer`` is ``None`` without a template)."""
        items = {"params": params_like, "opt_state": opt_state_like}
        if buffer_like is not None:
            items["buffer"] = serialization.to_state_dict(buffer_like)
        out = self._restore(step, lambda: items)
        buffer = (None if buffer_like is None
                  else self._checked(step, serialization.from_state_dict, buffer_like,
                                     out["buffer"]))
        return out["params"], out["opt_state"], buffer

    def restore_params(self, step: int):
        """The parameters of checkpoint ``step`` in the structure they were saved with (read
        from the checkpoint itself: no template; the rest of the checkpoint is dropped)."""

        def saved():
            return jax.tree.map(lambda m: jax.ShapeDtypeStruct(m.shape, m.dtype),
                                dict(self.manager.item_metadata(step)))

        return self._restore(step, saved)["params"]

    def _restore(self, step: int, items: Callable[[], dict]) -> dict:
        """Restore the tree ``items()`` (arrays or shapes and dtypes), each on its template's
        sharding, else on this process's first device."""
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
