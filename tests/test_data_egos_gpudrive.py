"""Every vehicle as the ego (a hand-made scene with a known set of eligible vehicles, the ego's
own observation, the real samples' expert replay) and the GPUDrive JSON format (real files,
malformed files, the format registry)."""

from __future__ import annotations

import json
from pathlib import Path

import jax
import numpy as np
import pytest

from igdrivsim.data import FORMATS, expand_paths
from igdrivsim.data.egos import expand_egos
from igdrivsim.data.filter import FilterConfig
from igdrivsim.data.formats import format_of
from igdrivsim.data.gpudrive import FORMAT_GPUDRIVE, read_file
from igdrivsim.data.scenario import (
    NUM_STEPS,
    RG_CROSSWALK,
    RG_LANE_SURFACE_STREET,
    RG_ROAD_EDGE_BOUNDARY,
    TYPE_PEDESTRIAN,
    Capacities,
    as_ego,
    decode_scenario_id,
    ego_id,
    empty_scenario,
    encode_scenario_id,
    split_ego_id,
)
from igdrivsim.data.source import count_scenarios, open_scenarios
from igdrivsim.errors import DataError

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
GPUDRIVE, WOMD, SCENARIONET = SHARED / "gpudrive", SHARED / "womd", SHARED / "scenarionet"
needs_gpudrive = pytest.mark.skipif(not GPUDRIVE.is_dir(),
                                    reason=f"GPUDrive JSON samples not at {GPUDRIVE}")
CAPS = Capacities()  # one compiled shape for every real scenario


def _hand_made():
    """Slot 0: the SDC, east along y = 0 at 5 m/s; 1: north across x = 20 at 5 m/s (crosses the
    SDC); 2: parked on the SDC's path (too slow); 3: east along y = 50 (crosses nobody); 4:
    crosses like 1 but valid for half the window; 5: a pedestrian crossing. Eligible: 0 and 1."""
    from igdrivsim.simulator.toy import set_object

    sc = empty_scenario(Capacities(max_objects=6, max_roadgraph_points=8))
    t = np.arange(NUM_STEPS) * 0.1
    set_object(sc, 0, 5.0 * t, 0.0, 0.0, sdc=True)
    set_object(sc, 1, 20.0, -20.0 + 5.0 * t, np.pi / 2)
    set_object(sc, 2, 30.0, 0.0, 0.0)
    set_object(sc, 3, 5.0 * t, 50.0, 0.0)
    set_object(sc, 4, 25.0, -20.0 + 5.0 * t, np.pi / 2, valid=t < 4.5)
    set_object(sc, 5, 10.0, -5.0 + 1.5 * t, np.pi / 2)
    sc.metadata.object_type[5] = TYPE_PEDESTRIAN
    sc.metadata.id[:6] = [100, 101, 102, 103, 104, 105]
    return sc.replace(scenario_id=encode_scenario_id("hand"))


def test_expand_egos_of_a_hand_made_scene(tmp_path):
    sc = _hand_made()
    assert [ego["object_id"] for _, ego in expand_egos(sc)] == [100, 101]  # slots 0 and 1
    assert list(expand_egos(sc, FilterConfig(min_speed=6.0))) == []
    from igdrivsim.data import write_tfexample

    write_tfexample(tmp_path / "hand.tfrecord", [sc])
    recs = list(open_scenarios(tmp_path, Capacities(max_objects=8, max_roadgraph_points=16),
                               egos="all"))
    assert [r.ego for r in recs] == [
        {"id": "hand#100", "object_id": 100, "logged_sdc": True},
        {"id": "hand#101", "object_id": 101, "logged_sdc": False}]
    ego = recs[1].scenario
    assert decode_scenario_id(ego.scenario_id) == "hand#101"
    assert np.flatnonzero(ego.metadata.is_sdc).tolist() == [1]
    assert [r.scenario.num_objects for r in recs] == [8, 8]  # fitted after choosing the ego
    assert len(list(open_scenarios(tmp_path, None))) == 1  # egos="sdc": as logged
    assert split_ego_id("hand#101") == ("hand", 101) and split_ego_id("scene-1_91") == (
        "scene-1_91", None)
    assert len(ego_id("x" * 40, 12345)) == 32


def test_the_ego_is_out_of_its_own_observation_and_the_former_sdc_in_it():
    from igdrivsim.observation import get_setting, observe
    from igdrivsim.observation.features import POSITION_SCALE, rotate_to_frame
    from igdrivsim.simulator import reset

    sc = _hand_made()
    ego = as_ego(sc, 1)
    key = jax.random.key(0)
    obs = observe(reset(ego), get_setting("full"), key, key)
    seen = np.asarray(obs.objects)[np.asarray(obs.objects_valid, bool), :2] * POSITION_SCALE
    tr = sc.trajectory
    valid_now = np.asarray(tr.valid)[:, 10]
    assert len(seen) == valid_now.sum() - 1  # every object valid now, but the ego

    def relative(slot):
        dx, dy = tr.x[slot, 10] - tr.x[1, 10], tr.y[slot, 10] - tr.y[1, 10]
        return np.asarray(rotate_to_frame(dx, dy, tr.yaw[1, 10]))

    distance = lambda slot: np.linalg.norm(seen - relative(slot), axis=1).min()
    assert distance(0) < 1e-3  # the logged SDC is an ordinary object now
    assert np.linalg.norm(seen, axis=1).min() > 1.0  # nothing where the ego is


@pytest.fixture(scope="module")
def replay():
    from igdrivsim.observation.replay import replay_fn

    return replay_fn()


@pytest.mark.parametrize("folder, egos, bound", [(GPUDRIVE, 4, 0.02), (WOMD, 10, 0.02),
                                                 (SCENARIONET, 20, 0.021)])
def test_the_expert_replays_every_real_ego(folder, egos, bound, replay):
    """Mean log divergence per ego (measured: at most 0.0196 m on GPUDrive and WOMD, 0.0206 m
    on one ScenarioNet ego); every step within 0.05 m."""
    if not folder.is_dir():
        pytest.skip(f"real samples not at {folder}")
    from igdrivsim.simulator.metrics import mean_log_divergence

    recs = list(open_scenarios(folder, CAPS, egos="all"))
    assert len({r.ego["id"] for r in recs}) == len(recs) == egos
    assert any(r.ego["logged_sdc"] for r in recs) and not all(r.ego["logged_sdc"] for r in recs)
    for rec in recs:
        _, m, _ = replay(rec.scenario, jax.random.key(0))
        assert int(np.sum(m.valid)) == 80, rec.ego
        assert float(mean_log_divergence(m)) < bound, rec.ego
        assert float(np.max(np.where(m.valid, m.log_divergence, 0.0))) < 0.05, rec.ego


@needs_gpudrive
def test_real_gpudrive_files_read_as_plausible_scenarios(replay):
    files = expand_paths(GPUDRIVE)  # the folder's JSON scenarios, not its README
    assert [Path(f).name for f in files] == sorted(p.name for p in GPUDRIVE.glob("*.json"))
    assert all(format_of(f) is FORMATS["gpudrive"] for f in files)
    recs = list(open_scenarios(GPUDRIVE, None))
    assert [r.format for r in recs] == [FORMAT_GPUDRIVE] * 3
    ids = {decode_scenario_id(r.scenario.scenario_id): r.scenario for r in recs}
    assert sorted(ids) == ["bada21415c031740", "db4edc9bd0c9d18c", "ef3a8f65142f41ac"]
    for sid, n, sdc in (("ef3a8f65142f41ac", 62, 61), ("db4edc9bd0c9d18c", 81, 80),
                        ("bada21415c031740", 15, 14)):
        s = ids[sid]
        assert s.num_objects == n and np.flatnonzero(s.metadata.is_sdc).tolist() == [sdc]
        assert s.trajectory.x.shape == (n, NUM_STEPS) and s.trajectory.valid[sdc].all()
        invalid = ~np.asarray(s.trajectory.valid)
        assert (s.trajectory.x[invalid] == -1).all()  # -10000 is not a position
        assert np.abs(s.trajectory.yaw[~invalid]).max() <= np.pi + 1e-3  # radians
        types = set(np.asarray(s.roadgraph.type).tolist())
        assert {RG_LANE_SURFACE_STREET, RG_ROAD_EDGE_BOUNDARY, RG_CROSSWALK} <= types
        assert types <= set(range(20)) - {4}
    s = ids["db4edc9bd0c9d18c"]
    assert s.metadata.tracks_to_predict.sum() == 7
    assert sorted(s.metadata.id[s.metadata.objects_of_interest].tolist()) == [18, 284]
    assert count_scenarios(GPUDRIVE) == 3
    for s in ids.values():  # the logged SDC replays within 0.02 m
        from igdrivsim.data.scenario import fit_to_capacities
        from igdrivsim.simulator.metrics import mean_log_divergence

        _, m, _ = replay(fit_to_capacities(s, CAPS), jax.random.key(0))
        assert float(mean_log_divergence(m)) < 0.02


def _edit(path: Path, edit) -> Path:
    desc = json.loads(path.read_text())
    edit(desc)
    return desc


@needs_gpudrive
@pytest.mark.parametrize("edit, key", [
    (lambda d: d["metadata"].pop("sdc_track_index"), "metadata.sdc_track_index"),
    (lambda d: d["metadata"].update(sdc_track_index=999), "metadata.sdc_track_index"),
    (lambda d: d["objects"][2]["heading"].pop(), "objects[2].heading"),
    (lambda d: d["objects"][0].update(type="spaceship"), "objects[0].type"),
    (lambda d: d["roads"][1].pop("geometry"), "roads[1].geometry"),
    (lambda d: d.pop("objects"), "objects"),
])
def test_a_malformed_gpudrive_file_is_one_line_naming_file_and_key(tmp_path, edit, key):
    src = GPUDRIVE / "tfrecord-00002-of-01000_407.json"
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(_edit(src, edit)))
    with pytest.raises(DataError) as err:
        read_file(bad)
    text = str(err.value)
    assert str(bad) in text and repr(key) in text and "\n" not in text


def test_broken_json_and_the_cli_line(tmp_path, capsys):
    from igdrivsim.cli import main

    (tmp_path / "x.json").write_text('{"objects": [')
    with pytest.raises(DataError, match="not valid JSON"):
        read_file(tmp_path / "x.json")
    assert main(["stats", str(tmp_path), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "x.json" in err[0] and "not valid JSON" in err[0]


@needs_gpudrive
def test_stats_and_env_take_every_ego(capsys):
    from igdrivsim.cli import main
    from igdrivsim.envs.driving import DrivingEnv

    assert main(["stats", str(GPUDRIVE), "--egos", "all", "--no-progress"]) == 0
    assert "gpudrive (4)" in capsys.readouterr().out
    env = DrivingEnv(str(GPUDRIVE), egos="all", caps=CAPS)
    assert sorted(decode_scenario_id(s.scenario_id) for s in env.scenarios) == [
        "bada21415c031740#1729", "bada21415c031740#1749", "db4edc9bd0c9d18c#285",
        "db4edc9bd0c9d18c#3"]


@needs_gpudrive
def test_training_input_stream_and_config_take_every_ego():
    import argparse

    from igdrivsim.errors import ConfigError
    from igdrivsim.training.commands import resolve_config, train_arguments
    from igdrivsim.training.config import get_profile, with_overrides
    from igdrivsim.training.stream import ScenarioIndex

    caps = Capacities(max_objects=16, max_roadgraph_points=256)
    want = [r.ego["id"] for r in open_scenarios(GPUDRIVE, caps, egos="all")]
    index = ScenarioIndex(GPUDRIVE, caps, egos="all")
    assert index.refs.shape == (4, 3)
    assert [decode_scenario_id(index[i].scenario_id) for i in range(len(index))] == want
    assert ScenarioIndex(GPUDRIVE, caps).refs.shape == (3, 2)  # 8 bytes each
    parser = argparse.ArgumentParser()
    train_arguments(parser)
    args = parser.parse_args(["--data", str(GPUDRIVE), "--out", "x", "--egos", "all"])
    assert resolve_config(args).data.egos == "all"
    with pytest.raises(ConfigError, match="data.egos"):
        with_overrides(get_profile("laptop"), ["data.egos=every"]).validate()


def test_a_new_format_is_one_registry_entry(tmp_path, monkeypatch):
    """A format registered at the end of ``FORMATS`` is detected, listed, counted and read by
    every reader, with every vehicle as the ego too."""
    from igdrivsim.data.formats import Format

    def decode(path, start, stop):
        if start <= 0 and (stop is None or stop > 0):
            yield 0, "toy", _hand_made(), None

    toy = Format("toy", lambda p: p.endswith(".toy"), decode, lambda p: 1, True, lambda p: True)
    monkeypatch.setitem(FORMATS, "toy", toy)
    (tmp_path / "a.toy").write_text("")
    (tmp_path / "notes.txt").write_text("")
    assert expand_paths(tmp_path) == [str(tmp_path / "a.toy")]
    assert count_scenarios(tmp_path) == 1
    recs = list(open_scenarios(tmp_path, Capacities(max_objects=8, max_roadgraph_points=16),
                               egos="all"))
    assert [r.format for r in recs] == ["toy", "toy"]
    assert [r.ego["object_id"] for r in recs] == [100, 101]
