"""The generator's batched geometry gives what a test of every pair gives, and the shards do not
depend on how the work is spread over processes and shards."""

from __future__ import annotations

import numpy as np
import pytest

from igdrivsim.cli import main as cli_main
from igdrivsim.data import tfrecord
from igdrivsim.data.synthetic.agents import (
    ON_ROAD,
    PARALLEL,
    T,
    _occupancy,
    box_corners,
    boxes_overlap,
    collides_any,
)
from igdrivsim.data.synthetic.commands import shard_paths
from igdrivsim.data.synthetic.generator import plan_scenario, scenario_rng


def _collides(a, b) -> bool:
    """Reference: whether two planned agents' boxes overlap at some step where both are valid."""
    if (a.route.kind in PARALLEL and b.route.kind in PARALLEL
            and a.route.group != b.route.group):
        return False  # two lanes of a road: a lane's width apart
    both = a.valid & b.valid
    if not both.any():
        return False
    reach = a.reach + b.reach
    if (a.bbox[0] - reach > b.bbox[2] or a.bbox[2] + reach < b.bbox[0]
            or a.bbox[1] - reach > b.bbox[3] or a.bbox[3] + reach < b.bbox[1]):
        return False
    d = a.xy - b.xy
    near = both & (np.einsum("ij,ij->i", d, d) < reach * reach)
    if not near.any():
        return False
    ca = box_corners(a.xy[near], a.yaw[near], a.length, a.width)
    cb = box_corners(b.xy[near], b.yaw[near], b.length, b.width)
    return bool(boxes_overlap(ca, cb).any())


def _pairwise(agent, other):
    """Reference: one other at a time, every step, every route point in its grown box."""
    pts, yaw_route = agent.route.points, agent.route.yaw
    reach = other.reach + agent.width / 2 + 1.0
    lo, hi = np.array(other.bbox[:2]), np.array(other.bbox[2:])
    rows = np.flatnonzero(np.all((pts >= lo - reach) & (pts <= hi + reach), axis=1))
    d = pts[rows, None, :] - other.xy[None]
    c, s = np.cos(other.yaw), np.sin(other.yaw)
    dx = np.abs(d[..., 0] * c + d[..., 1] * s) - other.length / 2
    dy = np.abs(-d[..., 0] * s + d[..., 1] * c) - other.width / 2
    occ = (np.maximum(dx, dy) < agent.width / 2 + 0.4) & other.valid[None]
    keep = occ.any(1)
    rows, occ = rows[keep], occ[keep]
    cosang = np.cos(other.yaw[None] - yaw_route[rows, None])
    return rows, occ, np.where(cosang > 0.75, other.speed[None] * cosang, np.nan)


@pytest.mark.parametrize("index", [0, 1, 2])
def test_occupancy_matches_a_test_of_every_pair(index):
    _, planned = plan_scenario(scenario_rng(0, index))
    checked = 0
    for i, agent in enumerate(planned):
        if agent.static or agent.walker:
            continue
        parallel = agent.route.kind in PARALLEL
        others = [o for o in planned[:i] if not o.static
                  and not (parallel and o.route.kind in PARALLEL
                           and o.route.group != agent.route.group)
                  and not (agent.route.kind in ON_ROAD and o.role == "stroller")]
        rows, occ, along = _occupancy(agent, agent.route.yaw, others)
        ref = [_pairwise(agent, o) for o in others]
        assert np.array_equal(rows, np.concatenate([r for r, _, _ in ref] or [[]]).astype(int))
        assert np.array_equal(occ, np.concatenate([o for _, o, _ in ref] or [np.zeros((0, T))]))
        assert np.array_equal(along, np.concatenate([a for _, _, a in ref] or [np.zeros((0, T))]),
                              equal_nan=True)
        checked += len(rows)
    assert checked > 0  # some agent's route is covered by another agent


def _overlap_reference(a, b):
    hit = np.ones(a.shape[:-2], bool)
    for poly in (a, b):
        edges = np.roll(poly, -1, axis=-2) - poly
        axes = np.stack([-edges[..., 1], edges[..., 0]], -1)[..., :2, :]
        for i in range(2):
            ax = axes[..., i, None, :]
            pa, pb = (a * ax).sum(-1), (b * ax).sum(-1)
            hit &= (pa.max(-1) > pb.min(-1)) & (pb.max(-1) > pa.min(-1))
    return hit


def test_boxes_overlap_matches_the_separating_axis_reference():
    rng = np.random.default_rng(0)
    n = 20_000
    xy, yaw = rng.normal(0, 3, (n, 2, 2)), rng.uniform(-4, 4, (n, 2))
    length, width = rng.uniform(0.5, 9, (n, 2)), rng.uniform(0.5, 3, (n, 2))
    a = box_corners(xy[:, 0], yaw[:, 0], length[:, 0], width[:, 0])
    b = box_corners(xy[:, 1], yaw[:, 1], length[:, 1], width[:, 1])
    expected = _overlap_reference(a, b)
    assert 0.1 < expected.mean() < 0.9
    assert np.array_equal(boxes_overlap(a, b), expected)
    assert np.array_equal(boxes_overlap(a[:1], b[:1]), expected[:1])
    far = box_corners(np.full((3, 2), 50.0), np.zeros(3), 4.0, 2.0)
    assert not boxes_overlap(a[:3], far).any()


def test_shards_do_not_depend_on_workers_or_shard_count(tmp_path):
    records = {}
    for workers, shards in ((1, 1), (2, 3)):
        out = tmp_path / f"w{workers}s{shards}"
        assert cli_main(["generate", "--out", str(out), "--train", "10", "--val", "0",
                         "--shards", str(shards), "--workers", str(workers),
                         "--no-progress"]) == 0
        records[workers] = [r for path in shard_paths(str(out), "training", shards)
                            for _, r, _ in tfrecord.iter_frames(path)]
    assert len(records[1]) == 10
    assert records[1] == records[2]


def test_collides_any_is_any_pairwise_collision():
    _, planned = plan_scenario(scenario_rng(0, 3))
    hits = 0
    for i, agent in enumerate(planned):
        for others in (planned[:i], planned[i + 1:], planned[:i] + planned[i + 1:]):
            expected = any(_collides(agent, b) for b in others)
            assert collides_any(agent, others) == expected
        # a copy of itself collides: every valid step overlaps
        hits += collides_any(agent, [agent])
    assert hits == len(planned)
