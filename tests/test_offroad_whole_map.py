"""Offroad is judged on the whole map: off the log it matches a brute-force NumPy check over
every road-edge point / segment of each real sample (WOMD tf.Example, Scenario proto,
ScenarioNet)."""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from igdrivsim.data import read_scenarios
from igdrivsim.data.scenario import RG_ROAD_EDGE_TYPES
from igdrivsim.simulator import SimParams, reset
from igdrivsim.simulator.metrics import offroad

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
SAMPLES = sorted([*DATA.glob("womd/*.tfrecord"), *DATA.glob("scenarionet/*.pkl")])
PARAMS = SimParams()
TIMES = (30, 60, 90)
DISTANCES = (20.0, 35.0, 50.0, 65.0, 80.0)
ANGLES = np.arange(8) * np.pi / 4 + 0.3


def _unit(v):
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.where(n > 1e-6, v / np.maximum(n, 1e-6), 0.0)


def _edges(rg):
    """Every road-edge slot of a map: point, stored direction, segment end (the point itself at
    a polyline's end), and the vertex bisectors at both ends of its segment (float64)."""
    xy, d = np.asarray(rg.xyz)[:, :2].astype(np.float64), np.asarray(rg.dir)[:, :2]
    valid, ids = np.asarray(rg.valid), np.asarray(rg.id)
    n = len(xy)
    nxt_same = np.zeros(n, bool)
    nxt_same[:-1] = valid[:-1] & valid[1:] & (ids[:-1] == ids[1:])
    nxt = np.where(nxt_same[:, None], np.roll(xy, -1, axis=0), xy)
    v = nxt - xy
    seg = np.where((np.linalg.norm(v, axis=-1) > 1e-6)[:, None], _unit(v), _unit(d))
    prev_ok = np.roll(nxt_same, 1) & (np.arange(n) > 0)
    next_ok = nxt_same & np.roll(nxt_same, -1) & (np.arange(n) < n - 1)
    prev_dir = np.where(prev_ok[:, None], np.roll(seg, 1, axis=0), 0.0)
    next_dir = np.where(next_ok[:, None], np.roll(seg, -1, axis=0), 0.0)

    def bisector(w):
        return np.where((np.linalg.norm(w, axis=-1) > 1e-6)[:, None], _unit(w), seg)

    bis_start, bis_end = bisector(seg + prev_dir), bisector(seg + next_dir)
    last = ~nxt_same & prev_ok
    bis_start[last] = prev_dir[last]
    k = valid & np.isin(np.asarray(rg.type), RG_ROAD_EDGE_TYPES)
    return xy[k], d[k].astype(np.float64), nxt[k], bis_start[k], bis_end[k]


def _corners(x, y, yaw, length, width):
    c, s = np.cos(yaw), np.sin(yaw)
    lx, ly = 0.5 * length * np.array([1, -1, -1, 1.0]), 0.5 * width * np.array([1, 1, -1, -1.0])
    return np.stack([x + c * lx - s * ly, y + s * lx + c * ly], -1)


def _outside(q, direction, d2) -> bool:
    """The sign at the nearest candidate (ties: outside wins), as the metric's rule."""
    j = d2 <= d2.min()
    return bool(np.max(q[j, 0] * direction[j, 1] - q[j, 1] * direction[j, 0]) > 0)


def brute_offroad(corners, edges, method: str) -> bool:
    """Some corner is outside the road, over ALL road edges of the map (NumPy, float64)."""
    a, d, b, bs, be = edges
    if not len(a):
        return False
    s = b - a
    len2 = np.sum(s * s, -1)
    for c in corners:
        r = c - a
        if method == "point":
            if _outside(r, d, np.sum(r * r, -1)):
                return True
            continue
        u = np.clip(np.sum(r * s, -1) / np.maximum(len2, 1e-12), 0.0, 1.0)
        q = r - u[:, None] * s
        at_end = ((u >= 1.0) & (len2 > 0))[:, None]
        direction = np.where((u <= 0.0)[:, None], bs, np.where(at_end, be, s))
        if _outside(q, direction, np.sum(q * q, -1)):
            return True
    return False


def _verdict(state, t, x, y, yaw, method):
    s = state.sdc
    moved = s.replace(x=s.x.at[t].set(x), y=s.y.at[t].set(y), yaw=s.yaw.at[t].set(yaw),
                      valid=s.valid.at[t].set(True))
    return offroad(state.replace(sdc=moved, timestep=t), method)


_reset = jax.jit(lambda sc: reset(sc, PARAMS))
_verdicts = {m: jax.jit(jax.vmap(lambda st, t, x, y, yaw, m=m: _verdict(st, t, x, y, yaw, m),
                                 in_axes=(None, 0, 0, 0, 0))) for m in ("point", "segment")}


def _off_log_poses(sc):
    """Poses 20-80 m from the logged SDC at steps 30, 60, 90, in 8 directions (f32 values)."""
    i = int(np.argmax(sc.metadata.is_sdc))
    tr = sc.trajectory
    lx, ly, lyaw, lv = (np.asarray(a)[i] for a in (tr.x, tr.y, tr.yaw, tr.valid))
    rows = []
    for t in TIMES:
        at = t if lv[t] else int(np.flatnonzero(lv)[-1])
        for dist in DISTANCES:
            for a in ANGLES:
                rows.append((t, lx[at] + dist * np.cos(lyaw[at] + a),
                             ly[at] + dist * np.sin(lyaw[at] + a), lyaw[at] + a))
    t, x, y, yaw = (np.asarray(c) for c in zip(*rows, strict=True))
    return t.astype(np.int32), x.astype(np.float32), y.astype(np.float32), yaw.astype(np.float32)


@pytest.mark.skipif(not SAMPLES, reason=f"real samples not found under {DATA}")
def test_offroad_off_the_log_matches_brute_force_over_the_whole_map():
    checked, offroad_seen, road_seen = 0, 0, 0
    for path in SAMPLES:
        for sc in read_scenarios(str(path)):
            state = _reset(jax.tree.map(jnp.asarray, sc))
            edges = _edges(sc.roadgraph)
            assert int(np.sum(np.asarray(state.road_edges.valid))) == len(edges[0])  # all kept
            i = int(state.sdc_index)
            length, width = (float(np.asarray(a)[i, 10]) for a in (sc.trajectory.length,
                                                                     sc.trajectory.width))
            t, x, y, yaw = _off_log_poses(sc)
            for method, verdicts in _verdicts.items():
                got = np.asarray(verdicts(state, *map(jnp.asarray, (t, x, y, yaw))))
                want = np.array([brute_offroad(_corners(*pose, length, width), edges, method)
                                 for pose in zip(x, y, yaw, strict=True)])
                bad = np.flatnonzero(got != want)
                assert not len(bad), (f"{path.name} ({method}): {len(bad)} of {len(got)} poses "
                                      f"disagree, first at step {t[bad[0]]}")
                checked += len(got)
                offroad_seen += int(want.sum())
                road_seen += int((~want).sum())
    assert checked >= 2 * 120 * 10 and offroad_seen > 0 and road_seen > 0
