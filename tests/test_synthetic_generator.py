"""The synthetic generator: determinism, WOMD-format shards, road-edge orientation, no overlaps,
and enough interactive scenarios (the paper's filter) that a careless policy would get wrong."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import jax
import numpy as np
import pytest

from igdrivsim.cli import main as cli_main
from igdrivsim.data import read_scenarios
from igdrivsim.data.filter import intersecting_objects, sdc_mean_speed
from igdrivsim.data.scenario import (
    CURRENT_INDEX,
    DT,
    RG_ROAD_EDGE_TYPES,
    TYPE_PEDESTRIAN,
    TYPE_VEHICLE,
)
from igdrivsim.data.synthetic.generator import GeneratorConfig, generate_scenario

N_TRAIN, N_VAL = 16, 4


@pytest.fixture(scope="module", params=["default", "calibrated"])
def generated(request, tmp_path_factory):
    """16 + 4 scenarios of seed 7, with each motion model (the default one written as before:
    no ``--motion``)."""
    out = tmp_path_factory.mktemp(f"synthetic_{request.param}")
    argv = ["generate", "--out", str(out), "--train", str(N_TRAIN), "--val", str(N_VAL),
            "--seed", "7", "--shards", "2", "--workers", "1"]
    if request.param != "default":
        argv += ["--motion", request.param]
    assert cli_main(argv) == 0
    return out, list(read_scenarios(out / "training")), argv


def corners(x, y, yaw, length, width):
    """Box corners ``[..., 4, 2]``."""
    c, s = np.cos(yaw)[..., None], np.sin(yaw)[..., None]
    lx = np.array([1, 1, -1, -1]) * np.asarray(length)[..., None] / 2
    ly = np.array([1, -1, -1, 1]) * np.asarray(width)[..., None] / 2
    return np.stack([x[..., None] + lx * c - ly * s, y[..., None] + lx * s + ly * c], -1)


def outside_edges(scenario, pts):
    """Per point ``[K, 2]``: on the right (outer) side of the nearest road-edge point."""
    rg = scenario.roadgraph
    sel = rg.valid & np.isin(rg.type, RG_ROAD_EDGE_TYPES)
    exy, edir = rg.xyz[sel, :2].astype(float), rg.dir[sel, :2].astype(float)
    d2 = ((pts[:, None] - exy[None]) ** 2).sum(-1)
    j = d2.argmin(1)
    rel = pts - exy[j]
    return edir[j, 0] * rel[:, 1] - edir[j, 1] * rel[:, 0] < 0


def sat_overlap(a, b):
    """Separating-axis test for rectangles given as corners ``[..., 4, 2]``."""
    hit = np.ones(np.broadcast_shapes(a.shape[:-2], b.shape[:-2]), bool)
    for poly in (a, b):
        for i in range(2):
            e = poly[..., i + 1, :] - poly[..., i, :]
            ax = np.stack([-e[..., 1], e[..., 0]], -1)[..., None, :]
            pa, pb = (a * ax).sum(-1), (b * ax).sum(-1)
            hit &= (pa.max(-1) > pb.min(-1)) & (pb.max(-1) > pa.min(-1))
    return hit


def sdc_of(s):
    return int(np.argmax(s.metadata.is_sdc))


def test_deterministic_per_seed_and_index():
    a, b = generate_scenario(3, 5), generate_scenario(3, 5)
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        np.testing.assert_array_equal(x, y)
    c = generate_scenario(3, 6)
    assert not np.array_equal(a.trajectory.x, c.trajectory.x)
    v = generate_scenario(3, 5, "validation")
    assert not np.array_equal(a.trajectory.x, v.trajectory.x)


def test_same_scenario_is_the_same_bytes_in_any_process():
    """A generated data set is byte-identical wherever it is written (the stage stamps and the
    filtered manifests of a run resumed on another machine stay valid): protobuf writes a map's
    entries in hash order unless asked for key order, and hash order differs by process."""
    code = ("import hashlib; from igdrivsim.data.synthetic.generator import generate_scenario; "
            "from igdrivsim.data.tfexample import encode_tfexample; "
            "print(hashlib.sha256(encode_tfexample(generate_scenario(0, 1))).hexdigest())")
    digests = {subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                              check=True, env=dict(os.environ, PYTHONHASHSEED=str(h))).stdout
               for h in (1, 2, 3)}
    assert len(digests) == 1


def test_shards_read_back_with_womd_shapes(generated):
    out, scenarios, argv = generated
    names = sorted(os.listdir(out / "training"))
    assert names == [f"training_tfexample.tfrecord-0000{k}-of-00002" for k in range(2)]
    assert sorted(os.listdir(out / "validation"))[0].startswith("validation_tfexample.tfrecord-")
    generator = json.loads((out / "generator_config.json").read_text())["generator"]
    assert generator["seed"] == 7
    config = GeneratorConfig(seed=7, motion=generator.get("motion", "default"))
    assert len(scenarios) == N_TRAIN
    assert len(list(read_scenarios(out / "validation"))) == N_VAL
    ids = set()
    for s in scenarios:
        assert s.trajectory.x.shape == (128, 91)
        assert s.roadgraph.xyz.shape == (20_000, 3)
        assert s.metadata.is_sdc.sum() == 1
        sdc = sdc_of(s)
        assert s.trajectory.valid[sdc].all()
        assert set(np.unique(s.metadata.object_type[s.metadata.valid])) <= {1, 2, 3}
        types = set(np.unique(s.roadgraph.type[s.roadgraph.valid]))
        assert 15 in types and types & {1, 2} and types & set(range(6, 14))
        assert s.metadata.tracks_to_predict[sdc]
        ids.add(bytes(s.scenario_id))
        # Padding is invalid and zero.
        assert not s.trajectory.valid[~s.metadata.valid].any()
    assert len(ids) == N_TRAIN
    # Identical to generating in-process, and a re-run skips the complete shards.
    direct = generate_scenario(7, 3, config=config)
    np.testing.assert_array_equal(direct.trajectory.x, scenarios[3].trajectory.x)
    before = os.path.getmtime(out / "training" / names[0])
    assert cli_main(argv) == 0
    assert os.path.getmtime(out / "training" / names[0]) == before


def test_sdc_log_stays_inside_road_edges(generated):
    _, scenarios, _ = generated
    for s in scenarios:
        i = sdc_of(s)
        tr = s.trajectory
        c = corners(tr.x[i], tr.y[i], tr.yaw[i], tr.length[i], tr.width[i]).reshape(-1, 2)
        assert not outside_edges(s, c.astype(float)).any()
        # Points well to the right of the SDC (outside the road, except where a side street or
        # another arm joins) are detected as outside.
        right = np.stack([tr.x[i] + 30 * np.sin(tr.yaw[i]), tr.y[i] - 30 * np.cos(tr.yaw[i])], 1)
        assert outside_edges(s, right.astype(float)).mean() > 0.5


def test_simulator_offroad_rule_agrees(generated):
    from igdrivsim.simulator import metrics, roadgraph
    s = generated[1][0]
    i = sdc_of(s)
    tr = s.trajectory
    steps = slice(0, None, 6)
    c = corners(tr.x[i, steps], tr.y[i, steps], tr.yaw[i, steps], tr.length[i, steps],
                tr.width[i, steps]).reshape(-1, 2)
    rg = s.roadgraph
    rg = rg.replace(valid=rg.valid & np.isin(rg.type, RG_ROAD_EDGE_TYPES))
    edges = roadgraph.road_edges_from_roadgraph(rg)
    d = metrics.signed_distance_point(c[:, 0], c[:, 1], edges)
    assert float(np.max(d)) < 0  # negative: inside the road


def test_no_overlap_between_logged_objects(generated):
    _, scenarios, _ = generated
    for s in scenarios:
        tr, ok = s.trajectory, np.flatnonzero(s.metadata.valid)
        c = corners(tr.x[ok], tr.y[ok], tr.yaw[ok], tr.length[ok], tr.width[ok])  # [n, T, 4, 2]
        xy, reach = c.mean(-2), np.hypot(tr.length[ok], tr.width[ok]) / 2  # [n, T, 2], [n, T]
        both = tr.valid[ok][:, None] & tr.valid[ok][None]
        near = both & ~np.eye(len(ok), dtype=bool)[..., None] & (  # boxes that may touch
            np.linalg.norm(xy[:, None] - xy[None], axis=-1) < reach[:, None] + reach[None])
        i, j, t = np.nonzero(near)
        assert not sat_overlap(c[i, t], c[j, t]).any(), s.scenario_id


def test_expert_is_smooth_and_consistent(generated):
    _, scenarios, _ = generated
    for s in scenarios:
        i = sdc_of(s)
        tr = s.trajectory
        speed = np.hypot(tr.vel_x[i], tr.vel_y[i])
        acc = np.diff(speed) / DT
        assert np.abs(acc[1:-1]).max() < 8.0
        moving = speed > 1.0
        heading = np.arctan2(tr.vel_y[i], tr.vel_x[i])
        err = np.angle(np.exp(1j * (heading - tr.yaw[i])))
        assert not moving.any() or np.abs(err[moving]).max() < 0.2
        assert 4.0 < tr.length[i, 0] < 5.5 and 1.8 < tr.width[i, 0] < 2.3
        cars = s.metadata.valid & (s.metadata.object_type == TYPE_VEHICLE)
        assert np.median(tr.length[cars].max(1)) == pytest.approx(4.6, abs=0.6)
    assert any((s.metadata.object_type == TYPE_PEDESTRIAN).any() for s in scenarios)


def test_interactive_fraction_and_careless_policy_fails(generated):
    _, scenarios, _ = generated
    kept, careless_fail = 0, 0
    for s in scenarios:
        interactive = intersecting_objects(s).any()
        kept += bool(interactive and sdc_mean_speed(s) >= 0.7)
        if interactive:
            assert s.metadata.objects_of_interest.sum() == 2
        # Careless policy: keep the SDC's velocity and heading from step 10 on.
        i, tr, t = sdc_of(s), s.trajectory, np.arange(91 - CURRENT_INDEX) * DT
        x = tr.x[i, CURRENT_INDEX] + tr.vel_x[i, CURRENT_INDEX] * t
        y = tr.y[i, CURRENT_INDEX] + tr.vel_y[i, CURRENT_INDEX] * t
        yaw = np.full_like(t, tr.yaw[i, CURRENT_INDEX])
        me = corners(x, y, yaw, tr.length[i, 0], tr.width[i, 0])
        off = outside_edges(s, me.reshape(-1, 2).astype(float)).any()
        sl = slice(CURRENT_INDEX, None)
        others = np.flatnonzero(s.metadata.valid & (np.arange(128) != i))
        them = corners(tr.x[others, sl], tr.y[others, sl], tr.yaw[others, sl],
                       tr.length[others, sl], tr.width[others, sl])
        crash = (sat_overlap(me[None], them) & tr.valid[others, sl]).any()
        careless_fail += bool(off or crash)
    assert kept / len(scenarios) >= 0.3
    assert careless_fail / len(scenarios) >= 0.3


def test_cli_rejects_bad_arguments_and_changed_config(generated, tmp_path, capsys):
    assert cli_main(["generate", "--out", str(tmp_path), "--train", "-1"]) == 2
    assert cli_main(["generate", "--out", str(tmp_path), "--train", "2", "--shards", "0"]) == 2
    out, _, argv = generated
    changed = [a if a != "7" else "8" for a in argv]  # another seed into the same folder
    assert cli_main(changed) == 2
    assert "different configuration" in capsys.readouterr().err


@pytest.mark.parametrize("kind", ["road", "intersection"])
def test_every_route_lies_inside_the_road_edges(kind):
    from igdrivsim.data.synthetic.generator import _edges
    from igdrivsim.data.synthetic.maps import intersection_map, road_map

    features = set()
    for seed in range(6):
        m = (road_map if kind == "road" else intersection_map)(np.random.default_rng(seed))
        features |= {"parking"} if m.parking else set()
        features |= {"lane drop"} if m.dropped else set()
        features |= {"stop signs"} if m.stop_arms else set()
        features |= {"signals"} if m.lights else set()
        features |= {"side street"} if m.no_parking else set()
        features |= {"bike lanes"} if m.bike_routes else set()
        tree, table = _edges(m)
        edge_types = {t for _, t in m.features} & set(RG_ROAD_EDGE_TYPES)
        assert edge_types, "a map without road edges"
        for route in m.routes:  # lane centres, lane changes and turns: >= 1 m inside
            p = route.points[::3]
            _, j = tree.query(p)
            rel, d = p - table[j, :2], table[j, 2:]
            inside = d[:, 0] * rel[:, 1] - d[:, 1] * rel[:, 0] >= 0  # 0: at a polyline end
            assert inside.all() and np.linalg.norm(rel, axis=1).min() > 1.0
        for walk in m.walk_paths:  # crossings start and end on the pavement, off the road
            _, j = tree.query(walk)
            rel, d = walk - table[j, :2], table[j, 2:]
            assert (d[:, 0] * rel[:, 1] - d[:, 1] * rel[:, 0] < 0).all()
    assert features == ({"parking", "lane drop", "signals", "side street", "bike lanes"}
                        if kind == "road" else {"parking", "stop signs", "signals"})


def test_compact_shards_read_back_identically(tmp_path):
    argv = ["generate", "--out", str(tmp_path), "--train", "2", "--val", "0", "--seed", "7",
            "--workers", "1", "--compact"]
    assert cli_main(argv) == 0
    back = list(read_scenarios(tmp_path / "training"))
    assert len(back) == 2
    for x, y in zip(jax.tree.leaves(back[1]), jax.tree.leaves(generate_scenario(7, 1)),
                    strict=True):
        np.testing.assert_array_equal(x, y)
