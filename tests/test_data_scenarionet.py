"""ScenarioNet reader: safe loading, windows, resampling, derived road edges, and the shared
samples (offroad of the logged SDC, discretised-expert replay)."""

from __future__ import annotations

import json
import os
import pickle
from pathlib import Path

import jax
import numpy as np
import pytest

from igdrivsim.data import decode_scenario_id, expand_paths, iter_scenarios
from igdrivsim.data import scenarionet as sn
from igdrivsim.data.scenario import CURRENT_INDEX, NUM_STEPS, RG_ROAD_EDGE_TYPES
from igdrivsim.errors import DataError

SAMPLES = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "scenarionet"
needs_samples = pytest.mark.skipif(
    not SAMPLES.is_dir(), reason=f"ScenarioNet samples not found at {SAMPLES}")


class _Evil:
    def __init__(self, marker: str):
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


def test_malicious_pickle_is_refused_and_nothing_runs(tmp_path):
    marker = tmp_path / "pwned"
    path = tmp_path / "evil.pkl"
    path.write_bytes(pickle.dumps({"tracks": _Evil(str(marker))}))
    with pytest.raises(DataError) as err:
        sn.safe_load(path)
    msg = str(err.value)
    assert str(path) in msg and "system" in msg and "\n" not in msg
    with pytest.raises(DataError, match="refused"):
        list(iter_scenarios(str(path)))
    assert not marker.exists()


def _description(steps=30, dt=0.1, clockwise=True, with_edges=False) -> dict:
    """A small synthetic scenario: the SDC drives along x inside a 40 x 8 m lane polygon."""
    t = np.arange(steps) * dt
    x = -10 + 5.0 * t
    state = lambda px, py: {
        "position": np.c_[px, py, np.zeros(steps)], "heading": np.zeros(steps),
        "velocity": np.c_[np.full(steps, 5.0), np.zeros(steps)],
        "length": np.full((steps, 1), 1.8), "width": np.full((steps, 1), 4.5),  # swapped
        "height": np.ones((steps, 1)), "valid": np.ones(steps)}
    square = np.array([[-20, -4], [20, -4], [20, 4], [-20, 4]], float)
    features = {"lane1": {"type": "LANE_SURFACE_STREET", "polyline": np.c_[x, 0 * x],
                          "polygon": square[::-1] if clockwise else square},
                "cw": {"type": "CROSSWALK", "polygon": square[:4] / 4}}
    if with_edges:
        features["e"] = {"type": "ROAD_EDGE_BOUNDARY", "polyline": square[[0, 1]]}
    return {"id": "toy", "version": "v", "length": steps,
            "metadata": {"sdc_id": "ego", "scenario_id": "toy", "ts": t, "dataset": "x"},
            "tracks": {"ego": {"type": "VEHICLE", "state": state(x, 0 * x), "metadata": {}},
                       "p": {"type": "PEDESTRIAN", "state": state(x, 2 + 0 * x),
                             "metadata": {}},
                       "c": {"type": "TRAFFIC_CONE", "state": state(x, -2 + 0 * x),
                             "metadata": {}}},
            "dynamic_map_states": {}, "map_features": features}


@pytest.mark.parametrize("clockwise", [True, False])
def test_lane_polygons_become_road_edges_with_road_on_the_left(clockwise):
    ((s, source),) = sn.decode_description(_description(clockwise=clockwise))
    assert (source, decode_scenario_id(s.scenario_id)) == (
        {"source_id": "toy", "first_step": 0}, "toy")
    assert s.trajectory.x.shape == (3, NUM_STEPS)
    assert s.trajectory.valid[:, :30].all() and not s.trajectory.valid[:, 30:].any()
    assert list(s.metadata.object_type) == [1, 2, 4] and list(s.metadata.is_sdc) == [1, 0, 0]
    assert s.trajectory.length[0, 0] == pytest.approx(4.5)  # vehicle box un-swapped
    rg = s.roadgraph
    edge = np.isin(rg.type, RG_ROAD_EDGE_TYPES)
    assert edge.sum() > 100 and (rg.type == 18).any() and (rg.type == 2).any()
    pts, d = rg.xyz[edge, :2], rg.dir[edge, :2]
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1, atol=1e-5)
    inward = -pts  # the polygon's centre is on the road: it must be left of dir
    assert (d[:, 0] * inward[:, 1] - d[:, 1] * inward[:, 0] > 0).all()
    # dataset road edges present: nothing is derived
    ((s, _),) = sn.decode_description(_description(with_edges=True))
    assert np.isin(s.roadgraph.type, RG_ROAD_EDGE_TYPES).sum() < 100


def test_long_logs_become_windows_and_other_rates_are_resampled():
    ws = sn.decode_description(_description(steps=200))
    assert [source["first_step"] for _, source in ws] == [0, 91]
    assert [decode_scenario_id(s.scenario_id) for s, _ in ws] == ["toy_0", "toy_91"]
    np.testing.assert_allclose(ws[1][0].trajectory.x[0, 0], -10 + 5 * 9.1, atol=1e-4)
    ws = sn.decode_description(_description(steps=41, dt=0.5))  # 2 Hz, 20 s
    assert len(ws) == 2
    x = ws[0][0].trajectory.x[0]
    np.testing.assert_allclose(np.diff(x), 0.5, atol=1e-4)  # 5 m/s at 10 Hz
    with pytest.raises(DataError, match="steps"):
        sn.decode_description(_description(steps=2, dt=0.5))


def test_bad_description_errors_name_the_key(tmp_path):
    desc = _description()
    del desc["tracks"]["ego"]["state"]["heading"]
    path = tmp_path / "bad.pkl"
    path.write_bytes(pickle.dumps(desc))
    with pytest.raises(DataError) as err:
        list(iter_scenarios(str(path)))
    assert str(path) in str(err.value) and "tracks/ego/state" in str(err.value)
    desc = _description()
    desc["metadata"]["sdc_id"] = "nobody"
    path.write_bytes(pickle.dumps(desc))
    with pytest.raises(DataError, match="sdc_id"):
        list(iter_scenarios(str(path)))


@needs_samples
def test_dataset_folder_with_summary_and_mapping(tmp_path):
    (tmp_path / "part").mkdir()
    names = sorted(p.name for p in SAMPLES.glob("*.pkl"))[:2]
    for n in names:
        (tmp_path / "part" / n).symlink_to(SAMPLES / n)
    (tmp_path / sn.SUMMARY_FILE).write_bytes(pickle.dumps({n: {} for n in names}))
    (tmp_path / sn.MAPPING_FILE).write_bytes(pickle.dumps({n: "part" for n in names}))
    assert expand_paths(str(tmp_path)) == [str(tmp_path / "part" / n) for n in names]
    assert expand_paths(str(SAMPLES)) == sorted(str(p) for p in SAMPLES.glob("*.pkl"))


@pytest.fixture(scope="module")
def sample_records():
    if not SAMPLES.is_dir():
        pytest.skip(f"ScenarioNet samples not found at {SAMPLES}")
    return list(iter_scenarios(str(SAMPLES)))


def test_samples_read_as_windows(sample_records):
    assert len(sample_records) == 8  # 4 logs of ~20 s, 2 windows each
    for rec in sample_records:
        s, md = rec.scenario, rec.scenario.metadata
        assert rec.format == "scenarionet" and rec.source["first_step"] == 91 * rec.record
        assert decode_scenario_id(s.scenario_id).startswith(rec.source["source_id"])
        sdc = int(np.argmax(md.is_sdc))
        assert md.is_sdc.sum() == 1 and s.trajectory.valid[sdc, CURRENT_INDEX]
        assert md.object_type[sdc] == 1
        assert s.trajectory.length[sdc, CURRENT_INDEX] > s.trajectory.width[sdc, CURRENT_INDEX]
        rg = s.roadgraph
        assert (np.isin(rg.type, RG_ROAD_EDGE_TYPES) & rg.valid).sum() > 100
    waymo = [r for r in sample_records if "waymo" in r.file]
    assert np.asarray(waymo[0].scenario.traffic_lights.valid).any()


def test_samples_logged_sdc_on_road_and_expert_replays_the_log(sample_records):
    from igdrivsim.observation.replay import replay_fn

    run = replay_fn("expert")
    offroad_steps = 0
    for rec in sample_records:
        _, replay, log = jax.device_get(run(rec.scenario, jax.random.key(0)))
        offroad_steps += int(np.sum(log.offroad))
        div = np.where(replay.valid, replay.log_divergence, 0)
        assert div.max() < 0.1, rec.source
    assert offroad_steps <= 0.01 * 80 * len(sample_records)


@needs_samples
def test_inspect_json_carries_source_id_and_first_step(capsys):
    from igdrivsim.cli import main

    path = str(SAMPLES / "sd_waymo_v1.2_eb4b91b10ca94ff2.pkl")
    assert main(["inspect", path]) == 0
    lines = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert [(d["source_id"], d["first_step"], d["scenario_id"]) for d in lines] == [
        ("eb4b91b10ca94ff2", 0, "eb4b91b10ca94ff2_0"),
        ("eb4b91b10ca94ff2", 91, "eb4b91b10ca94ff2_91")]


@needs_samples
def test_replay_json_carries_source_id_and_first_step(capsys):
    from igdrivsim.cli import main

    path = str(SAMPLES / "sd_nuscenes_v1.0-mini_scene-0757.pkl")
    assert main(["replay", path, "--json"]) == 0
    lines = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert [(d["source_id"], d["first_step"], d["record"]) for d in lines] == [
        ("scene-0757", 0, 0), ("scene-0757", 91, 1)]
    assert all(d["replay_max_log_divergence"] < 0.1 for d in lines)
