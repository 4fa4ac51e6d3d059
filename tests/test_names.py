"""One source of names: igdrivsim/names.py defines the settings' and methods' labels, colours
and short names; the registries read them, and the names and the report's table modules import
without loading JAX."""

from __future__ import annotations

import subprocess
import sys

from igdrivsim import names

LIGHT_MODULES = ("igdrivsim.names", "igdrivsim.evaluation.schema", "igdrivsim.report.tables",
                 "igdrivsim.report.results_doc", "igdrivsim.report.compare",
                 "igdrivsim.report.sweep", "igdrivsim.report.transfer")


def test_the_registries_read_the_names():
    from igdrivsim.observation import models  # the package registers occlusion
    from igdrivsim.pipeline.profiles import PROFILES
    from igdrivsim.training.config import get_profile
    from igdrivsim.training.methods import METHODS

    assert names.SETTINGS == models.PAPER_SETTINGS
    assert models.PRESET_TITLES == {s: names.SETTING_TITLES[s] for s in models.PRESETS}
    assert names.LEARNED == {m.name: (m.label, m.colour) for m in METHODS.values()}
    assert list(names.LEARNED) == list(METHODS)  # the tables' order is the registry's
    assert set(names.METHODS) <= set(METHODS)
    assert not set(names.REFERENCES) & set(METHODS)
    assert PROFILES["gpu"].seeds == get_profile("gpu").training.seeds == names.GPU_SEEDS


def test_the_names_and_report_tables_import_without_jax():
    code = (f"import {', '.join(LIGHT_MODULES)}; import sys; "
            "loaded = sorted(m for m in ('jax', 'flax', 'optax', 'orbax') if m in sys.modules); "
            "assert not loaded, loaded")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
