"""WOMD readers: real samples, tf.Example round trip, capacities, sharded paths, bad input."""

from __future__ import annotations

import os
from pathlib import Path

import jax
import numpy as np
import pytest

from igdrivsim.data import (
    FORMAT_SCENARIO,
    FORMAT_TFEXAMPLE,
    Capacities,
    ReadStats,
    decode_scenario_id,
    expand_paths,
    iter_file,
    iter_scenarios,
    load_scenario,
    read_scenarios,
    tfrecord,
    write_tfexample,
)
from igdrivsim.data.protos import example_class, scenario_class
from igdrivsim.data.scenario import (
    CURRENT_INDEX,
    NUM_STEPS,
    RG_ROAD_EDGE_TYPES,
    empty_scenario,
    encode_scenario_id,
    fit_to_capacities,
    trim_padding,
)
from igdrivsim.data.tfexample import encode_tfexample
from igdrivsim.errors import DataError

WOMD = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "womd"
EXAMPLE = WOMD / "motion_data_one_example.tfrecord"
SCENARIO = WOMD / "motion_data_one_scenario.tfrecord"
needs_womd = pytest.mark.skipif(not EXAMPLE.exists(),
                                reason=f"real WOMD samples not found in {WOMD}")


def make_scenario(num_objects=4, num_points=12, num_lights=2, seed=0, sid="toy-0"):
    """A random but consistent scenario at native sizes (SDC in slot 1)."""
    rng = np.random.default_rng(seed)
    s = empty_scenario(Capacities(num_objects, num_points, num_lights))
    tr, md, rg, tl = s.trajectory, s.metadata, s.roadgraph, s.traffic_lights
    for name in ("x", "y", "z", "yaw", "vel_x", "vel_y", "length", "width", "height"):
        getattr(tr, name)[:] = rng.normal(size=tr.x.shape).astype(np.float32) * 10
    tr.valid[:] = rng.random(tr.x.shape) < 0.8
    tr.valid[1] = True
    md.id[:] = np.arange(num_objects) + 100
    md.object_type[:] = rng.integers(1, 5, num_objects)
    md.is_sdc[1] = True
    md.tracks_to_predict[:2] = True
    md.objects_of_interest[2:3] = True
    md.valid[:] = tr.valid.any(1)
    rg.xyz[:] = rng.normal(size=rg.xyz.shape) * 50
    rg.dir[:] = rng.normal(size=rg.dir.shape)
    rg.type[:] = rng.integers(1, 20, num_points)
    rg.id[:] = rng.integers(0, 9, num_points)
    rg.valid[:] = rng.random(num_points) < 0.9
    tl.state[:] = rng.integers(0, 9, tl.state.shape)
    tl.valid[:] = rng.random(tl.valid.shape) < 0.5
    tl.lane_id[:] = rng.integers(0, 99, tl.lane_id.shape)
    for name in ("x", "y", "z"):
        getattr(tl, name)[:] = rng.normal(size=tl.x.shape).astype(np.float32)
    return s.replace(scenario_id=encode_scenario_id(sid))


def assert_same(a, b):
    la, lb = jax.tree.leaves(a), jax.tree.leaves(b)
    assert jax.tree.structure(a) == jax.tree.structure(b)
    for x, y in zip(la, lb, strict=True):
        assert x.shape == y.shape and x.dtype == y.dtype
        np.testing.assert_array_equal(x, y)


# --- real samples -------------------------------------------------------------------------------

@needs_womd
def test_real_tfexample_sample():
    (rec,) = list(iter_file(str(EXAMPLE), caps=None))
    s = rec.scenario
    assert rec.format == FORMAT_TFEXAMPLE
    assert decode_scenario_id(s.scenario_id) == "a3bb37c25ce56418"
    assert s.num_objects == 128 and s.num_roadgraph_points == 20_000
    assert int(np.argmax(s.metadata.is_sdc)) == 8 and s.metadata.is_sdc.sum() == 1
    assert s.trajectory.valid[:, CURRENT_INDEX].sum() == 73
    assert s.metadata.objects_of_interest.sum() == 2
    assert np.isin(s.roadgraph.type[s.roadgraph.valid], RG_ROAD_EDGE_TYPES).sum() > 1000
    # Default capacities equal the file's sizes: fitting changes nothing.
    assert_same(fit_to_capacities(s), load_scenario(EXAMPLE))


@needs_womd
def test_real_scenario_proto_sample():
    (rec,) = list(iter_file(str(SCENARIO), caps=None))
    s, rg = rec.scenario, rec.scenario.roadgraph
    assert rec.format == FORMAT_SCENARIO
    assert decode_scenario_id(s.scenario_id) == "637f20cafde22ff8"
    assert s.num_objects == 83 and int(np.argmax(s.metadata.is_sdc)) == 82
    assert {1, 2, 3} & set(np.unique(s.metadata.object_type)) == {1, 2, 3}
    msg = scenario_class().FromString(tfrecord.read_record(SCENARIO, 0))
    track = msg.tracks[5]
    np.testing.assert_allclose(s.trajectory.x[5], [st.center_x for st in track.states], rtol=1e-6)
    # Map polylines are resampled: <= 0.5 m spacing inside a polyline, unit directions pointing
    # to the next point, zero at the polyline's end; road edges of both types are present.
    types = set(np.unique(rg.type))
    assert {15, 16, 18} <= types and types <= set(range(1, 20))
    same = rg.id[1:] == rg.id[:-1]
    step = np.linalg.norm(np.diff(rg.xyz[:, :2], axis=0), axis=1)
    assert step[same].max() <= 0.5 + 1e-3
    norm = np.linalg.norm(rg.dir, axis=1)
    assert np.allclose(norm[:-1][same], 1.0, atol=1e-4)
    assert np.allclose(rg.dir[:-1][~same], 0.0)
    seg = np.diff(rg.xyz.astype(np.float64), axis=0)[same]
    heading = seg / np.linalg.norm(seg, axis=1, keepdims=True)
    np.testing.assert_allclose(rg.dir[:-1][same], heading, atol=2e-3)
    # The first road edge polyline keeps WOMD's vertex order (orientation preserved).
    edge = next(f for f in msg.map_features if f.WhichOneof("feature_data") == "road_edge")
    pts = rg.xyz[rg.id == edge.id]
    np.testing.assert_allclose(pts[0, :2], [edge.road_edge.polyline[0].x,
                                            edge.road_edge.polyline[0].y], atol=1e-3)
    np.testing.assert_allclose(pts[-1, :2], [edge.road_edge.polyline[-1].x,
                                             edge.road_edge.polyline[-1].y], atol=1e-3)


# --- writer round trip, roadgraph sizes, capacities ---------------------------------------------

@pytest.mark.parametrize("num_points", [20_000, 30_000])
def test_tfexample_round_trip_and_roadgraph_size(tmp_path, num_points):
    scenarios = [make_scenario(num_points=num_points, seed=i, sid=f"s{i}") for i in range(2)]
    path = tmp_path / "x.tfrecord"
    assert write_tfexample(path, scenarios) == 2
    back = [r.scenario for r in iter_file(str(path), caps=None)]
    assert [b.num_roadgraph_points for b in back] == [num_points] * 2
    for a, b in zip(scenarios, back, strict=True):
        assert_same(a, b)
    caps = Capacities(max_objects=8, max_roadgraph_points=num_points, max_traffic_lights=4)
    (fitted,) = list(read_scenarios(path, caps=caps, workers=0))[:1]
    assert fitted.num_roadgraph_points == num_points and fitted.num_objects == 8


@needs_womd
def test_real_tfexample_round_trip(tmp_path):
    s = load_scenario(EXAMPLE, caps=None)
    write_tfexample(tmp_path / "r.tfrecord", s)
    assert_same(s, load_scenario(tmp_path / "r.tfrecord", caps=None))


def test_capacities_pad_invalid_and_keep_sdc_and_nearest():
    s = make_scenario(num_objects=6, num_points=5, num_lights=1)
    tr = s.trajectory
    tr.valid[:] = True
    s.metadata.valid[:] = True
    tr.x[:] = np.array([40.0, 0.0, 30.0, 3.0, 100.0, 5.0])[:, None]  # SDC (slot 1) at x=0
    tr.y[:] = 0.0
    padded = fit_to_capacities(s, Capacities(10, 8, 3))
    assert padded.num_objects == 10 and not padded.metadata.valid[6:].any()
    assert not padded.trajectory.valid[6:].any() and (padded.metadata.id[6:] == -1).all()
    assert not padded.roadgraph.valid[5:].any() and not padded.traffic_lights.valid[1:].any()
    assert_same(jax.tree.map(lambda x: x[:6], padded.trajectory), s.trajectory)
    cut = fit_to_capacities(s, Capacities(3, 5, 1))
    # SDC plus the two nearest (x=3, x=5), in their original order.
    np.testing.assert_array_equal(cut.metadata.id, [101, 103, 105])
    assert cut.metadata.is_sdc.tolist() == [True, False, False]


@needs_womd
def test_capacities_on_real_sample_keep_sdc():
    s = load_scenario(EXAMPLE, caps=Capacities(max_objects=16, max_roadgraph_points=1000))
    assert s.num_objects == 16 and s.metadata.is_sdc.sum() == 1
    full = load_scenario(EXAMPLE, caps=None)
    sdc = int(np.argmax(full.metadata.is_sdc))
    k = int(np.argmax(s.metadata.is_sdc))
    np.testing.assert_array_equal(s.trajectory.x[k], full.trajectory.x[sdc])
    assert s.roadgraph.valid.all()


# --- paths --------------------------------------------------------------------------------------

def test_expand_paths_sharded_dir_glob(tmp_path):
    shards = [tmp_path / f"train.tfrecord-{i:05d}-of-00003" for i in range(3)]
    for i, p in enumerate(shards):
        write_tfexample(p, make_scenario(sid=f"s{i}", seed=i))
    (tmp_path / "notes.txt").write_text("not data")
    names = [str(p) for p in shards]
    assert expand_paths(str(tmp_path / "train.tfrecord@3")) == names
    assert expand_paths(tmp_path) == names  # files named *tfrecord* win over other files
    assert expand_paths(str(tmp_path / "train.*-0000[02]-*")) == [names[0], names[2]]
    assert expand_paths([names[1], str(tmp_path / "train.tfrecord@3")]) == [names[1]] + names
    ids = [decode_scenario_id(s.scenario_id)
           for s in read_scenarios(tmp_path / "train.tfrecord@3")]
    assert ids == ["s0", "s1", "s2"]
    shards[1].unlink()
    with pytest.raises(DataError, match="1 of 3 shards missing, e.g. .*-00001-of-00003"):
        expand_paths(str(tmp_path / "train.tfrecord@3"))
    with pytest.raises(DataError, match="no such file"):
        expand_paths(str(tmp_path / "absent.tfrecord"))
    with pytest.raises(DataError, match="matches no files"):
        expand_paths(str(tmp_path / "nothing*"))


# --- bad input ----------------------------------------------------------------------------------

def _example_with(edit) -> bytes:
    example = example_class().FromString(encode_tfexample(make_scenario()))
    edit(example.features.feature)
    return example.SerializeToString()


def _bad_files(tmp_path) -> dict[str, tuple[str, str]]:
    """name -> (path, expected message fragment); in each file record 1 of 3 is the bad one."""
    good = encode_tfexample(make_scenario())
    s_nan = make_scenario()
    s_nan.trajectory.x[1, 3] = np.nan
    s_nosdc = make_scenario()
    s_nosdc.metadata.is_sdc[:] = False
    bad_records = {
        "missing_key": (_example_with(lambda fm: fm.pop("state/current/y")),
                        "key 'state/current/y': missing feature"),
        "misshaped_key": (_example_with(lambda fm: fm["state/future/x"].float_list.value.append(1)),
                          "key 'state/future/x': expected 320 values, found 321"),
        "unknown_format": (b"\x1a\x05hello-this-is-no-womd", "unknown record format"),
        "nan": (encode_tfexample(s_nan), "key 'state/past/x': non-finite"),
        "no_sdc": (encode_tfexample(s_nosdc), "key 'state/is_sdc': expected exactly one SDC"),
    }
    files = {}
    for name, (data, message) in bad_records.items():
        path = tmp_path / f"{name}.tfrecord"
        tfrecord.write_records(path, [good, data, good])
        files[name] = (str(path), message)
    # Corrupt data CRC: flip one byte inside record 1's data.
    path = tmp_path / "crc.tfrecord"
    tfrecord.write_records(path, [good, good, good])
    raw = bytearray(path.read_bytes())
    raw[len(good) + 16 + 12 + 100] ^= 0xFF
    path.write_bytes(bytes(raw))
    files["crc"] = (str(path), "corrupt record: data CRC mismatch")
    return files


def test_bad_input_errors_name_file_record_key(tmp_path):
    for name, (path, message) in _bad_files(tmp_path).items():
        with pytest.raises(DataError) as info:
            list(read_scenarios(path))
        text = str(info.value)
        assert "\n" not in text, name
        assert text.startswith(f"file {path}, record 1"), (name, text)
        assert message in text, (name, text)
        assert info.value.record == 1 and info.value.file == path


def test_skip_bad_counts_and_keeps_the_rest(tmp_path):
    files = _bad_files(tmp_path)
    for name, (path, _message) in files.items():
        stats = ReadStats()
        with pytest.warns(UserWarning, match="skipping bad record"):
            recs = list(iter_scenarios(path, skip_bad=True, stats=stats))
        assert [r.record for r in recs] == [0, 2], name
        assert stats.read == 2 and [(f, r) for f, r, _ in stats.skipped] == [(path, 1)]


def test_truncated_and_missing_files(tmp_path):
    good = encode_tfexample(make_scenario())
    path = tmp_path / "cut.tfrecord"
    tfrecord.write_records(path, [good, good])
    raw = path.read_bytes()
    path.write_bytes(raw[: len(raw) - 50])
    with pytest.raises(DataError, match=r"record 1: truncated record"):
        list(read_scenarios(path))
    stats = ReadStats()
    with pytest.warns(UserWarning):
        assert len(list(read_scenarios(path, skip_bad=True, stats=stats))) == 1
    assert len(stats.skipped) == 1
    with pytest.raises(DataError, match="no such file"):
        list(read_scenarios(tmp_path / "missing.tfrecord"))
    (tmp_path / "text.tfrecord").write_text("this is not a TFRecord file at all\n")
    with pytest.raises(DataError, match=r"record 0: corrupt record: length CRC mismatch"):
        list(read_scenarios(tmp_path / "text.tfrecord"))
    with pytest.raises(DataError, match="no record 5"):
        load_scenario(path, index=5)


@needs_womd
def test_scenario_proto_without_sdc(tmp_path):
    msg = scenario_class().FromString(tfrecord.read_record(SCENARIO, 0))
    msg.sdc_track_index = 500
    path = tmp_path / "nosdc.tfrecord"
    tfrecord.write_records(path, [msg.SerializeToString()])
    with pytest.raises(DataError, match=r"record 0, key 'sdc_track_index': no SDC"):
        load_scenario(path)


def test_parallel_reading_matches_serial(tmp_path):
    path = tmp_path / "many.tfrecord"
    tfrecord.write_records(path, [encode_tfexample(make_scenario(sid=f"p{i}", seed=i))
                                  for i in range(5)] + [b"\x1a\x03bad"])
    stats = ReadStats()
    with pytest.warns(UserWarning):
        par = list(iter_scenarios([path, path], skip_bad=True, stats=stats, workers=2, chunk=2,
                                  caps=None))
    with pytest.warns(UserWarning):
        ser = list(iter_scenarios([path, path], skip_bad=True, caps=None))
    assert [(r.file, r.record) for r in par] == [(r.file, r.record) for r in ser]
    assert len(par) == 10 and stats.read == 10 and len(stats.skipped) == 2
    for a, b in zip(par, ser, strict=True):
        assert_same(a.scenario, b.scenario)
    assert os.path.basename(par[0].file) == "many.tfrecord"


def test_constructed_scenario_proto(tmp_path):
    msg = scenario_class()()
    msg.scenario_id, msg.sdc_track_index, msg.current_time_index = "proto-1", 1, 10
    for tid, n in ((7, 91), (9, 91), (11, 5)):  # the last track is short (test-split style)
        track = msg.tracks.add(id=tid, object_type=1)
        for t in range(n):
            track.states.add(center_x=t * 1.0, center_y=float(tid), heading=0.1, velocity_x=10.0,
                             length=4.0, width=2.0, height=1.5, valid=t != 3)
    msg.objects_of_interest.extend([11])
    msg.tracks_to_predict.add(track_index=2)
    lane = msg.map_features.add(id=100)
    lane.lane.type = 2
    for x in (0.0, 2.0):
        lane.lane.polyline.add(x=x, y=0.0, z=0.0)
    edge = msg.map_features.add(id=101)
    edge.road_edge.type = 1
    for x, y in ((0.0, -3.0), (0.0, 3.0)):  # vertex order kept: dir = +y
        edge.road_edge.polyline.add(x=x, y=y, z=0.0)
    cw = msg.map_features.add(id=102)
    for x, y in ((5.0, 0.0), (6.0, 0.0), (6.0, 1.0)):
        cw.crosswalk.polygon.add(x=x, y=y, z=0.0)
    msg.map_features.add(id=103).stop_sign.position.x = 9.0
    msg.map_features.add(id=104).driveway.polygon.add(x=1.0)  # no tf.Example type: skipped
    for t in range(NUM_STEPS):
        dms = msg.dynamic_map_states.add()
        dms.lane_states.add(lane=100, state=4, stop_point={"x": 1.0, "y": 2.0})
        if t >= 50:
            dms.lane_states.add(lane=200, state=6)
    path = tmp_path / "p.tfrecord"
    tfrecord.write_records(path, [msg.SerializeToString()])
    (rec,) = list(iter_file(str(path), caps=None))
    s = rec.scenario
    assert rec.format == FORMAT_SCENARIO and decode_scenario_id(s.scenario_id) == "proto-1"
    tr, md, rg, tl = s.trajectory, s.metadata, s.roadgraph, s.traffic_lights
    assert md.is_sdc.tolist() == [False, True, False] and md.id.tolist() == [7, 9, 11]
    assert md.objects_of_interest.tolist() == [False, False, True]
    assert md.tracks_to_predict.tolist() == [False, False, True]
    assert tr.valid[0].sum() == 90 and not tr.valid[0, 3]
    assert tr.valid[2].tolist() == [True, True, True, False, True] + [False] * 86
    np.testing.assert_array_equal(tr.x[1, :5], [0, 1, 2, 3, 4])
    assert np.allclose(tr.vel_x[tr.valid], 10.0) and np.allclose(tr.yaw[tr.valid], 0.1)
    # Lane 0..2 m at 0.5 m: 5 points; edge 6 m: 13 points; crosswalk closed: 1+1+1.414 m.
    counts = {int(i): int((rg.id == i).sum()) for i in np.unique(rg.id)}
    assert counts == {100: 5, 101: 13, 102: 2 + 2 + 3 + 1, 103: 1}
    assert rg.type[rg.id == 100].tolist() == [2] * 5 and set(rg.type[rg.id == 101]) == {15}
    assert set(rg.type[rg.id == 102]) == {18} and rg.type[rg.id == 103].tolist() == [17]
    np.testing.assert_allclose(rg.xyz[rg.id == 100, 0], [0, 0.5, 1, 1.5, 2])
    np.testing.assert_allclose(rg.dir[rg.id == 101], [[0, 1, 0]] * 12 + [[0, 0, 0]])
    assert tl.state.shape == (2, NUM_STEPS) and tl.valid[0].all() and tl.valid[1].sum() == 41
    assert tl.lane_id[0, 0] == 100 and tl.lane_id[1, 60] == 200 and tl.lane_id[1, 10] == -1
    assert tl.state[0, 0] == 4 and tl.x[0, 5] == 1.0 and tl.y[0, 5] == 2.0


def test_trimmed_writing_round_trips_after_fitting(tmp_path):
    caps = Capacities(max_objects=8, max_roadgraph_points=40, max_traffic_lights=4)
    s = fit_to_capacities(make_scenario(num_objects=3, num_points=12, num_lights=2), caps)
    write_tfexample(tmp_path / "full.tfrecord", s)
    write_tfexample(tmp_path / "trim.tfrecord", trim_padding(s))
    trimmed = load_scenario(tmp_path / "trim.tfrecord", caps=None)
    assert trimmed.num_objects == 3 and trimmed.num_roadgraph_points <= 12
    assert_same(load_scenario(tmp_path / "trim.tfrecord", caps=caps), s)
    full, small = (os.path.getsize(tmp_path / n) for n in ("full.tfrecord", "trim.tfrecord"))
    assert small < full
    umask = os.umask(0)
    os.umask(umask)
    assert os.stat(tmp_path / "trim.tfrecord").st_mode & 0o777 == 0o666 & ~umask
