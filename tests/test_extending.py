"""The extension recipes of docs/EXTENDING.md hold: a method module is picked up by being
added, and an observation model without a data form is never folded as full observability."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from igdrivsim.observation import features
from igdrivsim.observation.models import (
    ObservationModel,
    ObservationSetting,
    get_setting,
    setting_params,
)
from igdrivsim.training import methods


@dataclass(frozen=True)
class HideEveryRoadPoint(ObservationModel):
    """Overrides ``apply`` only, as step 1 of the recipe shows."""

    def apply(self, obs, episode_key, step_key):
        return features.hide_roadgraph(obs, obs.roadgraph_valid & False)


def test_a_model_without_a_data_form_has_none():
    assert setting_params(ObservationSetting("hide_all", (HideEveryRoadPoint(),))) is None
    assert setting_params(get_setting("full")) is not None  # full observability is the identity


def test_every_module_of_the_methods_package_is_registered_in_the_tables_order():
    here = Path(methods.__file__).parent
    on_disk = {p.stem for p in here.glob("*.py") if not p.stem.startswith("_")}
    assert set(methods.method_modules()) == on_disk
    assert methods.method_modules()[:4] == ["bc", "bc_rl", "dagger", "advisor"]
    assert methods.DEFAULT_METHOD == "bc"
