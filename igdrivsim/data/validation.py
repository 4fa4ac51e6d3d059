"""Validation scenarios, stacked, from any data path (a filter output folder, files of any
format): what the training curves and the evaluation are judged on."""

from __future__ import annotations

import os
import sys

from tqdm import tqdm

from igdrivsim.data.scenario import stack_scenarios
from igdrivsim.data.source import count_scenarios, open_scenarios
from igdrivsim.errors import DataError


def load_validation(data: str, caps, max_scenarios: int = 0, progress: bool = False,
                    egos: str = "sdc"):
    """Stacked validation scenarios ``[N]`` of ``data`` (:func:`open_scenarios`: a filter output
    folder's kept scenarios, or files, folder, glob, ``name@N``), at most ``max_scenarios``;
    ``egos="all"``: one per eligible vehicle. ``progress``: a "loading" bar on stderr with the
    number of scenarios as its total (when it is cheap to know)."""
    if not os.path.exists(data) and not any(ch in str(data) for ch in "*?@"):
        raise DataError("validation data not found", file=str(data))
    total = count_scenarios(data, max_scenarios, egos) if progress else None
    scenarios = []
    with tqdm(total=total, desc="loading", unit="scn", file=sys.stderr,
              disable=not progress, dynamic_ncols=True) as bar:
        for rec in open_scenarios(data, caps, egos=egos, limit=max_scenarios):
            scenarios.append(rec.scenario)
            bar.update()
    if not scenarios:
        raise DataError("no validation scenarios (empty manifest or no records)", file=data)
    return stack_scenarios(scenarios)
