"""Fig. 1 panels and the rollout animation on the real WOMD sample; the render CLI's errors."""

from __future__ import annotations

import os
from pathlib import Path

import jax
import numpy as np
import pytest

from igdrivsim.cli import main

WOMD = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "womd"
EXAMPLE = WOMD / "motion_data_one_example.tfrecord"
needs_womd = pytest.mark.skipif(not EXAMPLE.exists(), reason=f"real WOMD sample absent: {EXAMPLE}")
KEY = jax.random.PRNGKey(0)


@pytest.fixture(scope="module")
def states():
    import igdrivsim.simulator as sim
    from igdrivsim.data import load_scenario
    from igdrivsim.observation.render import expert_states

    return expert_states(jax.jit(sim.reset)(load_scenario(EXAMPLE)), 2)


SETTING = "gaussian_noise+circular_r6"  # one compiled observation for every test here


@needs_womd
def test_snapshot_shows_what_the_setting_observes(states):
    from igdrivsim.observation.render import snapshot

    snap = snapshot(states[0], SETTING, *jax.random.split(KEY))
    off = snap.noise_offset
    assert 0.01 < np.hypot(*off) < 20
    # The field of view is centred on the believed ego: what is seen lies within 6 m of it.
    assert 0 < len(snap.seen_road_xy) < 500
    assert np.all(np.hypot(*snap.seen_road_xy.T) <= 6.0 + 1e-4)
    assert np.all(np.hypot(*snap.seen_obj_xy.T) <= 6.0 + 1e-4)
    assert snap.obj_seen.sum() == len(snap.seen_obj_xy) < len(snap.obj_xy)
    # Every observed road point / object is a true one seen from the believed position, i.e.
    # shifted by -offset in the ego frame.
    for seen, true in ((snap.seen_road_xy, snap.road_xy), (snap.seen_obj_xy, snap.obj_xy)):
        d = np.hypot(*(seen[:, None, :] + off - true[None]).transpose(2, 0, 1))
        assert d.min(axis=1).max(initial=0.0) < 1e-2


@needs_womd
def test_figure_and_animation_are_written(states, tmp_path):
    from PIL import Image

    from igdrivsim.observation.render import write_observation_figure, write_rollout_animation

    paths = write_observation_figure(states[1], tmp_path, [SETTING], KEY)
    assert [os.path.basename(p) for p in paths] == ["fig1_observations.pdf",
                                                    "fig1_observations.png"]
    assert all(os.path.getsize(p) > 10_000 for p in paths)
    assert os.stat(paths[1]).st_mode & 0o044  # readable by others (not mkstemp's 0600)
    gif = write_rollout_animation(states, SETTING, tmp_path / "rollout.gif", KEY)
    with Image.open(gif) as im:
        assert im.n_frames == 3
    assert sorted(os.listdir(tmp_path)) == ["fig1_observations.pdf", "fig1_observations.png",
                                            "rollout.gif"]  # no temp files left


def test_render_cli_errors_are_one_line(tmp_path, capsys):
    assert main(["render", "--data", str(tmp_path / "missing.tfrecord")]) == 2
    assert main(["render", "--obs", "no_such_setting", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and all(line.startswith("igdrivsim render: error:") for line in err)
