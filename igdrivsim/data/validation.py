"""Validation scenarios, stacked, from any data path (a filter output folder, files of any
format): what the training curves and the evaluation are judged on."""

from __future__ import annotations

import sys

from tqdm import tqdm

from igdrivsim.data.reader import ScenarioRecord
from igdrivsim.data.scenario import decode_scenario_id, split_ego_id, stack_scenarios
from igdrivsim.data.source import check_data, count_scenarios, open_scenarios
from igdrivsim.errors import DataError


def origin_of(rec: ScenarioRecord) -> dict:
    """Where one read scenario comes from: ``{"scenario_id", "source", "logged_sdc"}``.
    ``source`` is the source log: for a window cut from a long log (ScenarioNet), the reader's
    source id; for an ego of ``egos="all"``, its scenario's id; else the scenario's own id.
    ``logged_sdc``: whether the ego is the log's SDC (always, with ``egos="sdc"``)."""
    sid = decode_scenario_id(rec.scenario.scenario_id)
    if rec.source and rec.source.get("source_id"):
        source = str(rec.source["source_id"])
    else:
        source = split_ego_id(sid)[0] if rec.ego is not None else sid
    return {"scenario_id": sid, "source": source,
            "logged_sdc": True if rec.ego is None else bool(rec.ego["logged_sdc"])}


def load_scenarios(data, caps, max_scenarios: int = 0, progress: bool = False,
                   egos: str = "sdc") -> tuple:
    """``(stacked scenarios [N], origins)`` of ``data``, one :func:`origin_of` dict per
    scenario; ``data``: a location or a list of them (read in turn); see
    :func:`load_validation`."""
    check_data(data, "validation")
    total = count_scenarios(data, max_scenarios, egos) if progress else None
    scenarios, origins = [], []
    with tqdm(total=total, desc="loading", unit="scn", file=sys.stderr,
              disable=not progress, dynamic_ncols=True) as bar:
        for rec in open_scenarios(data, caps, egos=egos, limit=max_scenarios):
            scenarios.append(rec.scenario)
            origins.append(origin_of(rec))
            bar.update()
    if not scenarios:
        raise DataError("no validation scenarios (empty manifest or no records)",
                        file=str(data))
    return stack_scenarios(scenarios), origins


def load_validation(data, caps, max_scenarios: int = 0, progress: bool = False,
                    egos: str = "sdc"):
    """Stacked validation scenarios ``[N]`` of ``data`` (:func:`load_scenarios`); ``progress``: a
    "loading" bar on stderr, with a total where that is cheap to know."""
    return load_scenarios(data, caps, max_scenarios, progress, egos)[0]
