"""Scenario data: the Scenario pytree, the registry of formats (WOMD tf.Example and Scenario
protobuf, ScenarioNet, GPUDrive JSON), readers, the tf.Example writer and the paper's scenario
filter. Reading any data path goes through :func:`igdrivsim.data.source.open_scenarios`."""

from igdrivsim.data.formats import FORMAT_SCENARIO, FORMAT_TFEXAMPLE, FORMATS
from igdrivsim.data.reader import (
    ReadStats,
    expand_paths,
    iter_file,
    iter_scenarios,
    load_scenario,
    read_scenarios,
    write_tfexample,
)
from igdrivsim.data.scenario import (
    Capacities,
    Scenario,
    decode_scenario_id,
    fit_to_capacities,
    stack_scenarios,
)

__all__ = [
    "FORMAT_SCENARIO", "FORMAT_TFEXAMPLE", "FORMATS", "Capacities", "ReadStats", "Scenario",
    "decode_scenario_id", "expand_paths", "fit_to_capacities", "iter_file", "iter_scenarios",
    "load_scenario", "read_scenarios", "stack_scenarios", "write_tfexample",
]
