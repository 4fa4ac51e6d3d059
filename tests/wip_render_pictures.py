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


@needs_womd
def test_snapshot_shows_what_the_setting_observes(states):
    from igdrivsim.observation.render import snapshot

    full = snapshot(states[0], "full", *jax.random.split(KEY))
    assert full.obj_seen.sum() == 32 and len(full.seen_road_xy) == 1500
    assert full.noise_offset is None
    np.testing.assert_allclose(np.sort(np.hypot(*full.seen_obj_xy.T)),
                               np.sort(np.hypot(*full.obj_xy[full.obj_seen].T)), atol=1e-3)

    fov = snapshot(states[0], "circular_r4", *jax.random.split(KEY))
    assert np.all(np.hypot(*fov.seen_road_xy.T) <= 4.0 + 1e-4)
    assert np.all(np.hypot(*fov.obj_xy[fov.obj_seen].T) <= 4.0 + 1e-4)
    assert 0 < len(fov.seen_road_xy) < 200

    noisy = snapshot(states[0], "gaussian_noise", *jax.random.split(KEY))
    off = noisy.noise_offset
    assert 0.01 < np.hypot(*off) < 20
    # Every observed road point is a true one seen from the believed position: shifted by -off.
    d = np.hypot(*(noisy.seen_road_xy[:, None, :] + off - noisy.road_xy[None]).transpose(2, 0, 1))
    assert d.min(axis=1).max() < 1e-2


@needs_womd
def test_figure_and_animation_are_written(states, tmp_path):
    from PIL import Image

    from igdrivsim.observation.render import write_observation_figure, write_rollout_animation

    paths = write_observation_figure(states[1], tmp_path, ["full", "circular_r4"], KEY)
    assert [os.path.basename(p) for p in paths] == ["fig1_observations.pdf",
                                                    "fig1_observations.png"]
    assert all(os.path.getsize(p) > 10_000 for p in paths)
    assert os.stat(paths[1]).st_mode & 0o044  # readable by others (not mkstemp's 0600)
    gif = write_rollout_animation(states, "circular_r4", tmp_path / "rollout.gif", KEY)
    with Image.open(gif) as im:
        assert im.n_frames == 3
    assert sorted(os.listdir(tmp_path)) == ["fig1_observations.pdf", "fig1_observations.png",
                                            "rollout.gif"]  # no temp files left


def test_render_cli_errors_are_one_line(tmp_path, capsys):
    assert main(["render", "--data", str(tmp_path / "missing.tfrecord")]) == 2
    assert main(["render", "--setting", "no_such_setting", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and all(line.startswith("igdrivsim render: error:") for line in err)
