"""Every vehicle as the ego: one scenario per vehicle of a log that is valid over the whole window
and passes the scenario filter as the SDC (docs/data.md, Every vehicle as the ego)."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from igdrivsim.data.filter import FilterConfig, ego_candidates, keep, scenario_stats
from igdrivsim.data.scenario import Scenario, as_ego, decode_scenario_id
from igdrivsim.errors import ConfigError

EGO_MODES = ("sdc", "all")  # the logged SDC only (the paper's protocol), every eligible vehicle
PAPER_FILTER = FilterConfig()  # interactive and mean speed >= 0.7 m/s


def check_egos(egos: str) -> str:
    """``egos`` if it is one of :data:`EGO_MODES`, else a one-line :class:`ConfigError`."""
    if egos not in EGO_MODES:
        raise ConfigError(f"unknown egos {egos!r}; choose one of {', '.join(EGO_MODES)}")
    return egos


def add_egos_argument(parser) -> None:
    parser.add_argument("--egos", choices=EGO_MODES, default="sdc",
                        help="sdc: each scenario from its logged SDC (the paper's); all: one "
                             "scenario per vehicle valid over the window that passes the "
                             "scenario filter as the ego (default: sdc)")


def expand_egos(scenario: Scenario, config: FilterConfig = PAPER_FILTER
                ) -> Iterator[tuple[Scenario, dict]]:
    """:func:`ego_of` per vehicle of one unbatched scenario valid over the whole window that
    passes the filter as the ego (native sizes: fit them to capacities afterwards, so that the
    objects kept are those nearest to the ego)."""
    tr = scenario.trajectory
    speed = np.hypot(np.asarray(tr.vel_x, np.float64), np.asarray(tr.vel_y, np.float64))
    for slot in map(int, ego_candidates(scenario)):
        if (not speed[slot].mean() < config.min_speed  # cheap first: the filter's speed bound
                and keep(scenario_stats(as_ego(scenario, slot)), config)):
            yield ego_of(scenario, slot)


def ego_of(scenario: Scenario, slot: int) -> tuple[Scenario, dict]:
    """``(scenario as seen from slot ``slot``, {"id", "object_id", "logged_sdc"})``."""
    ego = as_ego(scenario, slot)
    return ego, {"id": decode_scenario_id(ego.scenario_id),
                 "object_id": int(np.asarray(scenario.metadata.id)[slot]),
                 "logged_sdc": bool(np.asarray(scenario.metadata.is_sdc)[slot])}


def ego_slot(scenario: Scenario, object_id: int) -> int | None:
    """The slot of object ``object_id`` in one unbatched scenario (None: not there)."""
    hits = np.flatnonzero(np.asarray(scenario.metadata.id) == int(object_id))
    return int(hits[0]) if len(hits) else None
