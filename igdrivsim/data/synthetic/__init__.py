"""Synthetic WOMD-format scenarios: the embedded default data set (see ``generator.py``)."""

from igdrivsim.data.synthetic.generator import (
    GeneratorConfig,
    generate_scenario,
    plan_scenario,
    scenario_rng,
    to_scenario,
)
from igdrivsim.data.synthetic.geometry import paths_intersect

__all__ = ["GeneratorConfig", "generate_scenario", "paths_intersect", "plan_scenario",
           "scenario_rng", "to_scenario"]
