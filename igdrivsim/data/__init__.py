"""Scenario data: the Scenario pytree, the registry of formats (WOMD tf.Example and Scenario
protobuf, ScenarioNet, GPUDrive JSON), the tf.Example writer, sharded sources and the paper's
scenario filter."""

from igdrivsim.data.filter import FilterConfig, keep, merge, run_filter, scenario_stats
from igdrivsim.data.formats import FORMAT_SCENARIO, FORMAT_TFEXAMPLE, FORMATS, decode_record
from igdrivsim.data.manifest import (
    iter_manifest_scenarios,
    load_manifest_scenarios,
    read_manifest,
)
from igdrivsim.data.reader import (
    ReadStats,
    ScenarioRecord,
    expand_paths,
    iter_file,
    iter_scenarios,
    load_scenario,
    process_pool,
    read_scenarios,
    write_tfexample,
)
from igdrivsim.data.scenario import (
    Capacities,
    Scenario,
    decode_scenario_id,
    empty_scenario,
    fit_to_capacities,
    sdc_index,
    stack_scenarios,
)

__all__ = [
    "FORMAT_SCENARIO", "FORMAT_TFEXAMPLE", "FORMATS", "Capacities", "FilterConfig", "ReadStats",
    "Scenario",
    "ScenarioRecord", "decode_record", "decode_scenario_id", "empty_scenario", "expand_paths",
    "fit_to_capacities", "iter_file", "iter_scenarios", "load_scenario",
    "read_scenarios", "sdc_index", "stack_scenarios", "write_tfexample",
    "iter_manifest_scenarios", "keep", "load_manifest_scenarios", "merge", "process_pool",
    "read_manifest", "run_filter", "scenario_stats",
]
