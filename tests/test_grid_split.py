"""The pipeline's grid split does not change the numbers: one small grid (4 settings, smoke BC)
trained as parts {full, circular_r4} + {conic_r4, gaussian_noise} and as {full, conic_r4} +
{circular_r4, gaussian_noise} gives every setting the same parameters (one compiled shape)."""

from __future__ import annotations

import jax
import numpy as np
from conftest import write_toy_shard

from igdrivsim.training.config import get_profile, with_overrides
from igdrivsim.training.loop import train

CONFIG = with_overrides(get_profile("smoke"), ["training.eval_every=0", "training.seeds=2",
                                               "training.num_updates=3"])


def _train(data, out, settings: tuple[str, ...]) -> dict:
    """Each setting's parameters ``[S, ...]`` of one part trained on ``settings``."""
    config = with_overrides(CONFIG, [f"observation.setting={','.join(settings)}"])
    params = train(config, data, out, progress=False, log=lambda *_: None).params
    return {name: jax.tree.map(lambda x, g=g: np.asarray(x[g]), params)
            for g, name in enumerate(settings)}


def test_parameters_do_not_depend_on_the_split(tmp_path):
    data = write_toy_shard(tmp_path / "data", CONFIG)
    one = {**_train(data, tmp_path / "a1", ("full", "circular_r4")),
           **_train(data, tmp_path / "a2", ("conic_r4", "gaussian_noise"))}
    two = {**_train(data, tmp_path / "b1", ("full", "conic_r4")),
           **_train(data, tmp_path / "b2", ("circular_r4", "gaussian_noise"))}
    assert set(one) == set(two) == {"full", "circular_r4", "conic_r4", "gaussian_noise"}
    for name in one:
        diff = jax.tree.map(lambda x, y: float(np.abs(x - y).max()), one[name], two[name])
        assert max(jax.tree.leaves(diff)) < 1e-5, name
    # the settings did train apart: different observations, different parameters
    apart = jax.tree.map(lambda x, y: float(np.abs(x - y).max()), one["full"], one["conic_r4"])
    assert max(jax.tree.leaves(apart)) > 1e-4
