"""The report learns every name without JAX: evaluation/schema.py's copy of the registries'
setting and method names, short names, labels and colours equals the registries, and the
report's table modules import without loading JAX."""

from __future__ import annotations

import subprocess
import sys

from igdrivsim.evaluation import schema

LIGHT_MODULES = ("igdrivsim.evaluation.schema", "igdrivsim.report.tables",
                 "igdrivsim.report.results_doc", "igdrivsim.report.compare",
                 "igdrivsim.report.sweep", "igdrivsim.report.transfer")


def test_the_light_names_equal_the_registries():
    from igdrivsim.observation import models  # the package registers occlusion
    from igdrivsim.training.methods import METHODS

    assert schema.SETTINGS == models.PAPER_SETTINGS
    assert schema.SETTING_SHORT == models.PRESET_SHORT
    assert schema.LEARNED == {m.name: (m.label, m.colour) for m in METHODS.values()}
    assert list(schema.LEARNED) == list(METHODS)  # the tables' order is the registry's
    assert set(schema.METHODS) <= set(METHODS)
    assert not set(schema.REFERENCES) & set(METHODS)


def test_the_report_tables_import_without_jax():
    code = (f"import {', '.join(LIGHT_MODULES)}; import sys; "
            "loaded = sorted(m for m in ('jax', 'flax', 'optax', 'orbax') if m in sys.modules); "
            "assert not loaded, loaded")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
