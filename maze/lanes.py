"""Run the study's stages in parallel lanes: one thread per lane, a stage waits for its inputs.

A jitted JAX call releases the GIL and an XLA CPU program of this size runs on one core, so two
lanes keep both cores of a 2-core machine busy. Each stage is deterministic on its own, so the
results do not depend on the number of lanes or on timing.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

Stage = tuple[str, tuple[str, ...], Callable[[dict], Any]]  # (name, inputs, fn(results))


def run_lanes(lanes: list[list[Stage]]) -> dict[str, Any]:
    """Results of every stage by name; the first error of any stage is raised at the end."""
    done = {name: threading.Event() for lane in lanes for name, _, _ in lane}
    results: dict[str, Any] = {}
    errors: dict[str, BaseException] = {}

    def worker(lane: list[Stage]) -> None:
        for name, inputs, fn in lane:
            try:
                for dep in inputs:
                    done[dep].wait()
                    if dep in errors:
                        raise RuntimeError(f"stage {name}: input stage {dep} failed")
                results[name] = fn(results)
            except BaseException as err:  # noqa: BLE001  (re-raised in the caller's thread)
                errors[name] = err
            finally:
                done[name].set()

    threads = [threading.Thread(target=worker, args=(lane,), daemon=True) for lane in lanes]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    if errors:
        raise next(iter(errors.values()))
    return results
