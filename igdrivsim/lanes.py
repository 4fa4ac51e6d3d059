"""A local pool of lanes: each lane is a thread running one job at a time; a job starts once the
jobs it needs are done, the first ready one in the given order. It runs the pipeline's and the
maze study's stages (jitted JAX calls release the GIL). A job's result must not depend on its
lane or on timing.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field


@dataclass
class Job:
    """``run(echo)`` once every job named in ``after`` has finished."""

    name: str
    run: Callable[[bool], None]
    after: tuple[str, ...] = field(default_factory=tuple)


def run_jobs(jobs: Sequence[Job], lanes: int, stopping: threading.Event | None = None) -> None:
    """Run ``jobs`` on ``lanes`` threads in dependency order. The first failure sets
    ``stopping`` (jobs running beside it may watch it and stop; no new job starts) and is
    raised once every lane is idle. ``lanes`` 1: one job at a time, in this thread, echoing its
    output."""
    stopping = stopping if stopping is not None else threading.Event()
    unknown = {a for j in jobs for a in j.after} - {j.name for j in jobs}
    if unknown:
        raise ValueError(f"jobs wait for unknown jobs: {sorted(unknown)}")
    cond = threading.Condition()
    pending, finished, running = list(jobs), set(), 0
    errors: list[BaseException] = []

    def lane(echo: bool) -> None:
        nonlocal running
        while True:
            with cond:
                while True:
                    if errors or not pending:
                        return
                    job = next((j for j in pending if set(j.after) <= finished), None)
                    if job is not None:
                        pending.remove(job)
                        running += 1
                        break
                    if running == 0:  # nothing runs, nothing is ready: a cycle
                        errors.append(ValueError("jobs wait for each other in a cycle"))
                        cond.notify_all()
                        return
                    cond.wait()
            try:
                job.run(echo)
            except BaseException as err:  # noqa: BLE001 - re-raised in the caller's thread
                with cond:
                    errors.append(err)
                    stopping.set()
                    running -= 1
                    cond.notify_all()
                return
            with cond:
                finished.add(job.name)
                running -= 1
                cond.notify_all()

    if lanes <= 1:
        lane(True)
    else:
        threads = [threading.Thread(target=lane, args=(False,), daemon=True)
                   for _ in range(min(lanes, len(jobs)))]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    if errors:
        raise errors[0]
