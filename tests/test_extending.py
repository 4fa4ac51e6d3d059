"""The extension recipes of docs/EXTENDING.md hold: a method module is picked up by being
added, an observation model trains beside the paper's six, and one that is not a pytree is
never padded as full observability."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pytest

from igdrivsim.observation import features
from igdrivsim.observation.models import (
    ObservationModel,
    ObservationSetting,
    get_setting,
    stack_settings,
)
from igdrivsim.training import methods


@dataclass(frozen=True)
class HideEveryRoadPoint(ObservationModel):
    """Overrides ``apply`` only, as step 1 of the recipe shows."""

    def apply(self, obs, episode_key, step_key):
        return features.hide_roadgraph(obs, obs.roadgraph_valid & False)


def test_a_model_that_is_not_a_pytree_trains_on_its_own():
    plain = ObservationSetting("hide_all", (HideEveryRoadPoint(),))
    assert stack_settings([plain, "full"]) is None
    assert stack_settings([get_setting("full")]) is not None  # full observability is the identity


def test_the_observation_model_recipe_trains_beside_the_paper_six():
    import jax
    import jax.numpy as jnp
    import numpy as np
    from flax import struct

    from igdrivsim.observation import models as obs_models
    from igdrivsim.observation import stack_settings
    from igdrivsim.observation.models import PAPER_SETTINGS, apply_setting
    from igdrivsim.policy.act import example_observation
    from igdrivsim.training.config import get_profile, with_overrides

    namespace = {**vars(obs_models), **vars(features), "struct": struct}
    try:
        exec(_snippet("observation-model"), namespace)  # noqa: S102 - the documented module
        names = [*PAPER_SETTINGS, "rear_blind_5"]
        config = with_overrides(get_profile("smoke"),
                                [f"observation.setting={','.join(names)}"]).validate()
        stacked = stack_settings(config.settings)
        assert jax.tree.leaves(stacked)[0].shape == (len(names),)
        obs = example_observation()
        rng = np.random.default_rng(0)
        obs = obs.replace(objects=jnp.asarray(rng.normal(size=obs.objects.shape), jnp.float32),
                          objects_valid=jnp.ones(obs.objects_valid.shape, bool),
                          roadgraph=jnp.asarray(rng.normal(size=obs.roadgraph.shape),
                                                jnp.float32),
                          roadgraph_valid=jnp.ones(obs.roadgraph_valid.shape, bool))
        keys = (jax.random.key(0), jax.random.key(1))
        together = jax.vmap(lambda s: apply_setting(s, obs, *keys))(stacked)
        for g, name in enumerate(names):
            alone = apply_setting(get_setting(name), obs, *keys)
            for a, b in zip(jax.tree.leaves(alone), jax.tree.leaves(together), strict=True):
                np.testing.assert_array_equal(a, b[g])
        rear = apply_setting(get_setting("rear_blind_5"), obs, *keys)
        assert 0 < int(rear.objects_valid.sum()) < obs.objects_valid.size  # it hides some
    finally:
        for registry in (obs_models.PRESETS, obs_models.PRESET_TITLES):
            registry.pop("rear_blind_5", None)


def test_every_module_of_the_methods_package_is_registered_in_the_tables_order():
    here = Path(methods.__file__).parent
    on_disk = {p.stem for p in here.glob("*.py") if not p.stem.startswith("_")}
    assert set(methods.method_modules()) == on_disk
    assert methods.method_modules()[:4] == ["bc", "bc_rl", "dagger", "advisor"]
    assert methods.DEFAULT_METHOD == "bc"


# --------------------------------------------- the recipes of docs/EXTENDING.md, literally
DOC = Path(__file__).resolve().parents[1] / "docs" / "EXTENDING.md"


def _snippet(name: str) -> str:
    """The code block after ``<!-- recipe: NAME -->`` in docs/EXTENDING.md."""
    text = DOC.read_text(encoding="utf-8")
    after = text.split(f"<!-- recipe: {name} -->", 1)[1]
    return after.split("```python\n", 1)[1].split("```", 1)[0]


def test_the_metric_recipe_reaches_the_rollout_and_every_methods_table(monkeypatch):
    import types

    import numpy as np
    import pandas as pd
    from test_episode_metrics import _poses_from_speed, make_state

    from igdrivsim.evaluation import aggregate, registry
    from igdrivsim.report import tables
    from igdrivsim.simulator import episode_metrics as em

    namespace = dict(vars(em))  # step 1: a function in episode_metrics.py
    exec(_snippet("metric-function"), namespace)  # noqa: S102 - the documented snippet
    em_after = types.SimpleNamespace(**namespace)
    entry = _snippet("metric-entry").strip().rstrip(",")  # step 2: an entry of REGISTRY
    metric = eval(entry, {**vars(registry), "em": em_after})  # noqa: S307
    monkeypatch.setattr(registry, "REGISTRY", [*registry.REGISTRY, metric])
    speed = np.full(91, 10.0)
    value = registry.episode_values(make_state(_poses_from_speed(speed)), None)[metric.key]
    assert float(value) == pytest.approx(10.0)
    rows = [dict(setting="full", method=m, seed=s, scenario_id=f"s{i}", **{metric.key: 1.0 + s})
            for m in ("bc", "bc_rl", "dagger") for s in (0, 1) for i in range(3)]
    summary = aggregate.summarize(pd.DataFrame(rows), metrics=[metric])
    md = tables.supplementary_markdown(summary, [metric])
    dagger = next(line for line in md.splitlines() if "| DAgger |" in line)
    assert "1.50" in dagger  # a method beyond the paper's two gets its values, not "--"


def test_the_method_recipe_adds_a_hyper_parameter_without_touching_the_config():
    import sys
    import types

    from igdrivsim.errors import ConfigError
    from igdrivsim.training.config import get_profile, with_overrides
    from igdrivsim.training.update import update_spec

    name = "igdrivsim.training.methods.bc_rl_scaled"
    module = types.ModuleType(name)
    sys.modules[name] = module
    try:
        exec(_snippet("method-module"), module.__dict__)  # noqa: S102 - the documented module
        base = with_overrides(get_profile("smoke"), ["training.method=bc_rl_scaled"])
        assert update_spec(base.validate()).params.rl_scale == 10.0  # the declared default
        config = with_overrides(base, ["method.rl_scale=20"]).validate()
        assert update_spec(config).params.rl_scale == 20.0
        with pytest.raises(ConfigError, match="expected float"):
            with_overrides(base, ["method.rl_scale=ten"])
        assert config.collects_rollout
        with pytest.raises(ConfigError, match="unknown method parameter"):
            with_overrides(base, ["method.nope=1"])
    finally:
        methods.METHODS.pop("bc_rl_scaled", None)
        sys.modules.pop(name, None)
