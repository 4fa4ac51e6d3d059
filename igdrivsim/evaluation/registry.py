"""The registry of per-scenario metrics beyond Table I: the one place a metric is added.

A :class:`ScenarioMetric` is computed by ``episode`` (``(final_state, params) -> f32[]`` inside
the jitted rollout) or ``derive`` (from the other columns of a row). The rollout, the CSV
columns, the supplementary table and figure iterate over :data:`REGISTRY`; :func:`register`
adds one at run time. Definitions: docs/metrics.md; adding one: docs/EXTENDING.md.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass

from igdrivsim.evaluation.schema import PER_SCENARIO_COLUMNS
from igdrivsim.simulator import episode_metrics as em

EpisodeFn = Callable[..., object]  # (final SimState, SimParams) -> f32[]
DeriveFn = Callable[[Mapping[str, float]], float]


@dataclass(frozen=True)
class ScenarioMetric:
    """One per-scenario metric (see the module docstring)."""

    key: str  # per_scenario.csv column and name in the supplementary outputs
    label: str  # table row / figure panel name
    unit: str
    scale: float  # 100 for rates shown as percentages
    higher_is_better: bool
    source: str  # where the definition comes from (details in docs/metrics.md)
    episode: EpisodeFn | None = None
    derive: DeriveFn | None = None
    figure: bool = True  # a panel of the supplementary figure

    @property
    def column(self) -> str:
        return self.key

    def __post_init__(self):
        if (self.episode is None) == (self.derive is None):
            raise ValueError(f"metric {self.key!r}: give exactly one of episode / derive")


def pdm_score(row: Mapping[str, float]) -> float:
    """NAVSIM-style ``NC x DAC x (5 EP + 5 TTC + 2 C) / 12`` from a per-scenario row (NC: no
    overlap, DAC: never offroad, EP: progress, TTC: ttc_compliant, C: comfortable)."""
    nc, dac = 1.0 - row["overlap"], 1.0 - row["offroad"]
    return nc * dac * (5 * row["progress"] + 5 * row["ttc_compliant"]
                       + 2 * row["comfortable"]) / 12


REGISTRY: list[ScenarioMetric] = [
    ScenarioMetric("progress", "progress vs log", "ratio", 1.0, True,
                   "nuPlan ego progress along the expert route", episode=em.progress),
    ScenarioMetric("making_progress", "making progress", "%", 100.0, True,
                   "nuPlan making-progress check (progress >= 0.2)",
                   derive=lambda r: float(r["progress"] >= em.PROGRESS_THRESHOLD), figure=False),
    ScenarioMetric("comfortable", "comfortable", "%", 100.0, True,
                   "nuPlan ego-is-comfortable (six bounds)", episode=em.comfortable),
    ScenarioMetric("max_abs_lon_accel", "max |lon. accel.|", "m/s²", 1.0, False,
                   "nuPlan comfort quantity", episode=em.max_abs("lon_accel"), figure=False),
    ScenarioMetric("max_abs_lat_accel", "max |lat. accel.|", "m/s²", 1.0, False,
                   "nuPlan comfort quantity", episode=em.max_abs("lat_accel")),
    ScenarioMetric("max_abs_lon_jerk", "max |lon. jerk|", "m/s³", 1.0, False,
                   "nuPlan comfort quantity", episode=em.max_abs("lon_jerk")),
    ScenarioMetric("max_abs_yaw_rate", "max |yaw rate|", "rad/s", 1.0, False,
                   "nuPlan comfort quantity", episode=em.max_abs("yaw_rate"), figure=False),
    ScenarioMetric("kinematic_infeasible", "kinematically infeasible", "%", 100.0, False,
                   "Waymax kinematic infeasibility (our limits)",
                   episode=em.kinematic_infeasible),
    ScenarioMetric("min_ttc", "min time to collision", "s", 1.0, True,
                   "nuPlan time to collision (3 s horizon)", episode=em.min_time_to_collision,
                   figure=False),
    ScenarioMetric("ttc_compliant", "TTC within bound", "%", 100.0, True,
                   "nuPlan time-to-collision-within-bound (>= 0.95 s)",
                   episode=em.ttc_compliant),
    ScenarioMetric("at_fault_overlap", "at-fault overlap", "%", 100.0, False,
                   "nuPlan / V-Max at-fault collision (no rear or side hits)",
                   episode=em.at_fault_overlap),
    ScenarioMetric("pdm_score", "PDM-style score", "score", 1.0, True,
                   "NAVSIM PDM score (our NC, DAC, EP, TTC, C)", derive=pdm_score),
]


def register(metric: ScenarioMetric) -> ScenarioMetric:
    """Add a metric (its column goes after the existing ones); a repeated key is an error."""
    if any(m.key == metric.key for m in REGISTRY):
        raise ValueError(f"metric {metric.key!r} is already registered")
    REGISTRY.append(metric)
    return metric


def metrics() -> tuple[ScenarioMetric, ...]:
    return tuple(REGISTRY)


def columns() -> tuple[str, ...]:
    return tuple(m.key for m in REGISTRY)


def scenario_columns() -> tuple[str, ...]:
    """The columns per_scenario.csv is written with: Table I's, then this registry's."""
    return PER_SCENARIO_COLUMNS + columns()


SCENARIO_COLUMNS = scenario_columns()  # at import, before any later register() call


def episode_keys() -> tuple[str, ...]:
    return tuple(m.key for m in REGISTRY if m.episode is not None)


def episode_values(state, params) -> dict:
    """Every ``episode`` metric of one final state: ``{key: f32[]}`` (traced in the rollout)."""
    return {m.key: m.episode(state, params) for m in REGISTRY if m.episode is not None}


def derive_row(row: dict[str, float]) -> dict[str, float]:
    """Add the ``derive`` metrics to a per-scenario row, in registry order (NaN if an input is
    NaN, e.g. a rollout run without episode metrics)."""
    for m in REGISTRY:
        if m.derive is not None:
            value = m.derive(row)
            inputs_nan = any(isinstance(v, float) and math.isnan(v) for v in row.values())
            row[m.key] = float("nan") if inputs_nan else float(value)
    return row
