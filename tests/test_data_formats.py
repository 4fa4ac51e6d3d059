"""Adding a data format is one module plus one registry entry: a tiny JSON format, written
here and registered with one line, is read and counted by every reader of
:mod:`igdrivsim.data.source` without touching any other module."""

from __future__ import annotations

import json

import numpy as np
import pytest

from igdrivsim.data import formats
from igdrivsim.data.filter import FilterConfig
from igdrivsim.data.formats import FORMATS, Format
from igdrivsim.data.scenario import (
    NUM_STEPS,
    RG_ROAD_EDGE_BOUNDARY,
    TYPE_VEHICLE,
    Capacities,
    decode_scenario_id,
    empty_scenario,
    encode_scenario_id,
)
from igdrivsim.data.source import count_scenarios, load_ref, open_scenarios, scenario_refs
from igdrivsim.errors import DataError

# --- the format's module: ``{"scenarios": [{"id", "speeds": [per vehicle, m/s]}]}`` ----------


def tiny_scenario(desc: dict):
    """Vehicles driving straight along x at constant speeds (the first is the SDC), 3 m
    apart, between two road edges."""
    speeds = np.asarray(desc["speeds"], np.float32)
    n = len(speeds)
    s = empty_scenario(Capacities(max_objects=n, max_roadgraph_points=4, max_traffic_lights=0))
    t = np.arange(NUM_STEPS, dtype=np.float32) * 0.1
    ones = np.ones((n, NUM_STEPS), np.float32)
    traj = s.trajectory.replace(
        x=speeds[:, None] * t, y=np.arange(n, dtype=np.float32)[:, None] * 3 * ones,
        vel_x=speeds[:, None] * ones, length=4.5 * ones, width=2.0 * ones, height=1.5 * ones,
        valid=np.ones((n, NUM_STEPS), bool))
    meta = s.metadata.replace(id=np.arange(n, dtype=np.int32),
                              object_type=np.full(n, TYPE_VEHICLE, np.int32),
                              is_sdc=np.arange(n) == 0, objects_of_interest=np.ones(n, bool),
                              valid=np.ones(n, bool))
    xyz = np.asarray([[0, -2, 0], [200, -2, 0], [200, 3 * n, 0], [0, 3 * n, 0]], np.float32)
    rg = s.roadgraph.replace(xyz=xyz, dir=np.asarray([[1, 0, 0], [0, 0, 0], [-1, 0, 0],
                                                      [0, 0, 0]], np.float32),
                             type=np.full(4, RG_ROAD_EDGE_BOUNDARY, np.int32),
                             id=np.asarray([0, 0, 1, 1], np.int32), valid=np.ones(4, bool))
    return s.replace(trajectory=traj, metadata=meta, roadgraph=rg,
                     scenario_id=encode_scenario_id(desc["id"]))


def _load(path: str) -> list[dict]:
    with open(path) as f:
        return json.load(f)["scenarios"]


def decode_tiny(path: str, start: int, stop: int | None):
    for i, desc in enumerate(_load(path)):
        if i >= start and (stop is None or i < stop):
            try:
                yield i, "tiny", tiny_scenario(desc), None
            except (KeyError, TypeError, ValueError) as err:
                yield i, "tiny", DataError(f"bad tiny scenario: {err!r}"), None


TINY = Format("tiny", lambda path: path.endswith(".tinyjson"), decode_tiny,
              lambda path: len(_load(path)))

# --- the tests ---------------------------------------------------------------------------------


@pytest.fixture
def tiny(monkeypatch, tmp_path):
    monkeypatch.setitem(FORMATS, "tiny", TINY)  # the one registry line
    folder = tmp_path / "tiny"
    folder.mkdir()
    (folder / "a.tinyjson").write_text(json.dumps({"scenarios": [
        {"id": "a0", "speeds": [5.0, 6.0]}, {"id": "a1", "speeds": [8.0]}]}))
    (folder / "b.tinyjson").write_text(json.dumps({"scenarios": [
        {"id": "b0", "speeds": [3.0, 4.0, 9.0]}]}))
    (folder / "notes.txt").write_text("not data")
    return folder


def test_a_registered_format_is_read_counted_and_indexed(tiny):
    assert formats.format_of(str(tiny / "a.tinyjson")) is TINY
    caps = Capacities(max_objects=8, max_roadgraph_points=16, max_traffic_lights=2)
    recs = list(open_scenarios(tiny, caps))
    assert [decode_scenario_id(r.scenario.scenario_id) for r in recs] == ["a0", "a1", "b0"]
    assert [(r.format, r.record) for r in recs] == [("tiny", 0), ("tiny", 1), ("tiny", 0)]
    assert recs[0].scenario.num_objects == 8  # fitted to the capacities
    np.testing.assert_allclose(np.asarray(recs[2].scenario.trajectory.vel_x)[:3, 0], [3, 4, 9])
    assert count_scenarios(tiny) == 3 and count_scenarios(tiny, 2) == 2
    assert count_scenarios([tiny / "b.tinyjson", tiny]) == 4
    assert len(list(open_scenarios(tiny, None, limit=2))) == 2
    files, refs = scenario_refs(tiny)
    assert refs.shape == (3, 3)
    third = load_ref(files[int(refs[2, 0])], int(refs[2, 1]), -1, None)
    assert decode_scenario_id(third.scenario_id) == "b0"


def test_a_registered_format_reads_every_vehicle_as_the_ego(tiny):
    lenient = FilterConfig(criterion="objects_of_interest")
    egos = list(open_scenarios(tiny / "b.tinyjson", None, egos="all", filter_config=lenient))
    assert [r.ego["object_id"] for r in egos] == [0, 1, 2]
    assert [r.ego["logged_sdc"] for r in egos] == [True, False, False]


def test_a_bad_record_of_a_registered_format_names_file_and_record(tiny):
    (tiny / "c.tinyjson").write_text(json.dumps({"scenarios": [{"id": "c0"}]}))
    with pytest.raises(DataError) as err:
        list(open_scenarios(tiny / "c.tinyjson"))
    assert err.value.record == 0 and "c.tinyjson" in str(err.value)
    with pytest.warns(UserWarning, match="skipping bad record"):
        assert len(list(open_scenarios(tiny, skip_bad=True))) == 3
