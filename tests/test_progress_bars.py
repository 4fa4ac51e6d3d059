"""Progress bars: a known total (rate and ETA) for the long jobs, and ``--no-progress`` off.

Small hand-made inputs (three toy scenarios); the expensive parts (rendering, rollouts,
training) are replaced by stand-ins: what is checked is the bar, not the work.
"""

from __future__ import annotations

import re
from pathlib import Path
from types import SimpleNamespace
from typing import NamedTuple

import jax
import numpy as np
import pytest

from igdrivsim.cli import main as cli_main
from igdrivsim.data import Capacities
from igdrivsim.data.source import count_scenarios
from igdrivsim.training import inputs

CAPS = Capacities(max_objects=8, max_roadgraph_points=256)


def _bar_counts(err: str, desc: str) -> list[str]:
    """The ``n/total`` fields of the bar ``desc`` in captured stderr (last one last)."""
    return re.findall(rf"{re.escape(desc)}:[^\r\n]*?(\d+/\S+) \[", err)


@pytest.fixture(scope="module")
def shard(tmp_path_factory) -> Path:
    """A folder with one tf.Example file of three toy scenarios ``toy-0..2``."""
    from igdrivsim.data import write_tfexample
    from igdrivsim.simulator import toy

    folder = tmp_path_factory.mktemp("toy")
    write_tfexample(folder / "train.tfrecord",
                    [toy.straight_road(CAPS, speed=3.0 + i, scenario_id=f"toy-{i}")
                     for i in range(3)])
    return folder


@pytest.fixture(scope="module")
def filtered(shard, tmp_path_factory) -> Path:
    """A filter output folder whose manifest keeps two of the three toy scenarios."""
    from igdrivsim.data.manifest import write_manifest

    folder = tmp_path_factory.mktemp("filtered")
    write_manifest(folder / "manifest.jsonl", [
        {"file": str(shard / "train.tfrecord"), "record": i, "scenario_id": f"toy-{i}",
         "sdc_mean_speed": 3.0 + i, "interactive": True, "objects_of_interest": 0,
         "kept": i != 1} for i in range(3)])
    return folder


# --------------------------------------------------------------------------- counting
def test_count_scenarios(shard, filtered, tmp_path):
    count = count_scenarios
    assert count(shard) == 3 and count(shard / "train.tfrecord") == 3
    assert count(shard, 2) == 2 and count(shard, 10) == 3
    assert count([shard, shard / "train.tfrecord"]) == 6
    assert count(filtered) == 2 and count(filtered, 1) == 1  # the manifest's kept rows
    assert count(tmp_path / "missing") is None  # the read reports it, not the count
    (tmp_path / "s.pkl").write_bytes(b"")  # ScenarioNet: counting would decode it all
    assert count(tmp_path / "s.pkl") is None


def test_replay_total(shard, tmp_path):
    from igdrivsim.observation.replay import _replay_total

    assert _replay_total([str(shard)], None) == 3
    assert _replay_total([str(shard)], 2) == 2 and _replay_total([str(shard)], 9) == 3
    (tmp_path / "s.pkl").write_bytes(b"")
    assert _replay_total([str(tmp_path / "s.pkl")], None) is None
    assert _replay_total([str(tmp_path / "s.pkl")], 5) == 5


# --------------------------------------------------------------------------- replay
def test_replay_bar_has_a_total_and_gif_follows_no_progress(shard, tmp_path, capsys,
                                                            monkeypatch):
    from igdrivsim.observation import render

    seen = []
    monkeypatch.setattr(render, "write_rollout_animation",
                        lambda *a, progress=True, **k: seen.append(progress))
    assert cli_main(["replay", str(shard), "--limit", "2", "--gif", str(tmp_path / "g.gif"),
                     "--no-progress"]) == 0
    err = capsys.readouterr().err
    assert seen == [False] and not _bar_counts(err, "replay")
    assert cli_main(["replay", str(shard), "--gif", str(tmp_path / "g.gif")]) == 0
    assert seen == [False, True]
    assert _bar_counts(capsys.readouterr().err, "replay")[-1] == "3/3"


# --------------------------------------------------------------------------- training input
def test_reset_all_bar_total(monkeypatch, capsys):
    monkeypatch.setattr(inputs, "reset_chunk", lambda sc, params, size: {"x": np.zeros(len(sc))})
    out = inputs.reset_all([[1, 2], [3]], None, progress=True, total=3)
    assert out["x"].shape == (3,)
    assert _bar_counts(capsys.readouterr().err, "loading")[-1] == "3/3"
    inputs.reset_all([[1]], None, progress=False, total=1)
    assert not _bar_counts(capsys.readouterr().err, "loading")


@pytest.mark.parametrize("which, limit, total", [("shard", 0, 3), ("shard", 2, 2),
                                                 ("filtered", 0, 2), ("list", 2, 2)])
def test_dataset_passes_the_number_of_scenarios(which, limit, total, shard, filtered,
                                                monkeypatch):
    from igdrivsim.training.config import get_profile

    seen = {}

    def fake_reset_all(chunks, params, chunk=64, progress=False, total=None):
        seen.update(progress=progress, total=total)
        return SimpleNamespace(timestep=np.zeros(total))

    monkeypatch.setattr(inputs, "reset_all", fake_reset_all)
    data = {"shard": shard, "filtered": filtered, "list": [object()] * 3}[which]
    inputs.Dataset.from_config(get_profile("smoke"), data, None, progress=True,
                               max_scenarios=limit, record=False)
    assert seen == {"progress": True, "total": total}


# --------------------------------------------------------------------------- validation set
@pytest.mark.parametrize("which, limit, counts", [("shard", 0, "3/3"), ("shard", 2, "2/2"),
                                                  ("filtered", 0, "2/2")])
def test_load_validation_bar(which, limit, counts, shard, filtered, capsys):
    from igdrivsim.data.source import load_validation

    data = str({"shard": shard, "filtered": filtered}[which])
    stacked = load_validation(data, CAPS, limit, progress=True)
    assert np.shape(stacked.scenario_id)[0] == int(counts.split("/")[0])
    assert _bar_counts(capsys.readouterr().err, "loading")[-1] == counts
    load_validation(data, CAPS, limit)  # the default: no bar, as before
    assert not _bar_counts(capsys.readouterr().err, "loading")


# --------------------------------------------------------------------------- GIF, render
def test_gif_frame_bar_total_and_off(monkeypatch, tmp_path, capsys):
    from igdrivsim.observation import render

    monkeypatch.setattr(render, "snapshot", lambda *a, **k: None)
    monkeypatch.setattr(render, "draw_panel", lambda *a, **k: None)
    states, key = [SimpleNamespace(timestep=t) for t in range(10, 14)], jax.random.key(0)
    render.write_rollout_animation(states, "full", tmp_path / "a.gif", key, every=2)
    assert _bar_counts(capsys.readouterr().err, "rollout full")[-1] == "2/2"
    render.write_rollout_animation(states, "full", tmp_path / "b.gif", key, progress=False)
    assert not _bar_counts(capsys.readouterr().err, "rollout full")
    assert (tmp_path / "a.gif").is_file() and (tmp_path / "b.gif").is_file()


@pytest.mark.parametrize("flag, progress", [([], True), (["--no-progress"], False)])
def test_render_passes_no_progress_to_the_gif(flag, progress, shard, tmp_path, monkeypatch):
    from igdrivsim.observation import render

    seen = []
    monkeypatch.setattr(render, "expert_states", lambda state, n: [state] * (n + 1))
    monkeypatch.setattr(render, "write_observation_figure", lambda *a, **k: [])
    monkeypatch.setattr(render, "write_rollout_animation",
                        lambda *a, progress=True, **k: seen.append(progress) or "g.gif")
    assert cli_main(["render", "--data", str(shard / "train.tfrecord"), "--out",
                     str(tmp_path), "--gif", *flag]) == 0
    assert seen == [progress]


# --------------------------------------------------------------------------- speed walk
class _Fake(NamedTuple):
    scenario_id: np.ndarray


def _fake_episode(state, key, actor, *table):
    import jax.numpy as jnp

    b = state.scenario_id.shape[0]
    offsets = (jnp.arange(80 * b).reshape(80, b) % 3) - 1
    zero = jnp.zeros((80, b))
    return zero, zero > 0, zero > 0, zero == 0, offsets


def test_speed_walk_bar_over_batches(monkeypatch, capsys):
    from igdrivsim.evaluation import speed_walk

    monkeypatch.setattr(speed_walk, "episode", _fake_episode)
    monkeypatch.setattr(speed_walk, "reset", lambda s: s)
    scenarios = _Fake(np.zeros((5, 4), np.uint8))
    result = speed_walk.measure(scenarios, batch_size=2, progress=True)
    assert result["scenarios"] == 5
    assert _bar_counts(capsys.readouterr().err, "speed walk")[-1] == "12/12"  # 3 x 4 actors
    speed_walk.measure(scenarios, batch_size=2)
    assert not _bar_counts(capsys.readouterr().err, "speed walk")


@pytest.mark.parametrize("flag, progress", [([], True), (["--no-progress"], False)])
def test_speed_walk_cli_wires_no_progress(flag, progress, monkeypatch, capsys):
    from igdrivsim.evaluation import speed_walk

    seen = []
    monkeypatch.setattr(speed_walk, "load_validation",
                        lambda data, caps, limit, progress=False: seen.append(progress))
    monkeypatch.setattr(speed_walk, "measure",
                        lambda sc, seed, progress=False: seen.append(progress) or {})
    assert cli_main(["speed-walk", "--data", "D", *flag]) == 0
    assert seen == [progress, progress]
    with pytest.raises(SystemExit) as exc:
        cli_main(["speed-walk", "--help"])
    assert exc.value.code == 0 and "--no-progress" in capsys.readouterr().out


# --------------------------------------------------------------------------- maze study
@pytest.mark.parametrize("flag, progress", [([], True), (["--no-progress"], False)])
def test_maze_study_no_progress(flag, progress, tmp_path, monkeypatch):
    from maze import study as S

    class Stop(Exception):
        pass

    seen = []

    def fake_run_study(cfg, out, work, force=False, study=None, progress=True, command=None):
        seen.append(progress)

    monkeypatch.setattr(S, "run_study", fake_run_study)
    assert S.main(["--out", str(tmp_path / "o"), "--work", str(tmp_path / "w"), *flag]) == 0
    assert seen == [progress]
    monkeypatch.undo()

    def fake_tqdm(**kwargs):
        seen.append(kwargs)
        raise Stop

    monkeypatch.setattr(S, "tqdm", fake_tqdm)
    with pytest.raises(Stop):
        S.run_study(S.PROFILES["smoke"], tmp_path / "o", tmp_path / "w", study=object(),
                    progress=progress)
    assert seen[-1]["disable"] is (not progress) and seen[-1]["total"] > 0
