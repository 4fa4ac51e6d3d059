"""The offroad metric's road-edge array: every road edge of the map, compacted at reset, with
what the segment rule needs precomputed, so every step measures against the whole map.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from igdrivsim.data.scenario import RG_ROAD_EDGE_TYPES, Roadgraph

_BISECTION_STEPS = 24


@struct.dataclass
class RoadEdges:
    """Road-edge points (types 15, 16), ``[..., E]``: ``xy``/``dir`` (road on the left),
    ``next_xy`` (the polyline's next point, ``xy`` at its end) and the unit vertex bisectors
    ``bis_start``/``bis_end`` of the segment ``xy -> next_xy``."""

    xy: jax.Array
    dir: jax.Array
    next_xy: jax.Array
    bis_start: jax.Array
    bis_end: jax.Array
    valid: jax.Array


def _normalize(v, fallback):
    n = jnp.sqrt(jnp.sum(v * v, axis=-1, keepdims=True))
    return jnp.where(n > 1e-6, v / jnp.maximum(n, 1e-6), fallback)


def select_nearest(d2, eligible, radius: float, capacity: int):
    """``(indices int32[capacity], valid)`` in original order of the eligible points with
    ``d2 <= radius**2``, the nearest kept: the threshold is bisected to fit ``capacity``."""
    d2 = jnp.where(eligible, d2, jnp.inf)
    r2 = jnp.asarray(radius * radius, d2.dtype)
    fits = jnp.sum(d2 <= r2) <= capacity

    def body(_, lohi):
        lo, hi = lohi
        mid = 0.5 * (lo + hi)
        ok = jnp.sum(d2 <= mid) <= capacity
        return jnp.where(ok, mid, lo), jnp.where(ok, hi, mid)

    lo, _ = jax.lax.fori_loop(0, _BISECTION_STEPS, body, (jnp.zeros_like(r2), r2))
    thr = jnp.where(fits, r2, lo)
    keep = d2 <= thr
    (idx,) = jnp.nonzero(keep, size=capacity, fill_value=0)
    valid = jnp.arange(capacity) < jnp.sum(keep)
    return idx.astype(jnp.int32), valid


def _segment_at(rg: Roadgraph, j):
    """For point indices ``j`` (any, possibly out of range): whether the next point continues the
    polyline, that next point (``xy`` itself if not), and the unit segment direction."""
    n = rg.valid.shape[0]
    inside = (j >= 0) & (j < n)
    jc, kc = jnp.clip(j, 0, n - 1), jnp.clip(j + 1, 0, n - 1)
    xy, nxt = rg.xyz[jc, :2], rg.xyz[kc, :2]
    same_next = (inside & (j + 1 < n) & rg.valid[jc] & rg.valid[kc] & (rg.id[kc] == rg.id[jc]))
    next_xy = jnp.where(same_next[..., None], nxt, xy)
    seg_dir = _normalize(next_xy - xy, _normalize(rg.dir[jc, :2], jnp.zeros_like(xy)))
    return same_next, next_xy, seg_dir


def _segment_geometry(rg: Roadgraph, idx):
    """Next polyline point and vertex bisectors of the points ``idx`` (reads only their
    neighbours ``idx - 1 .. idx + 2``)."""
    same_prev, _, prev_dir = _segment_at(rg, idx - 1)
    same_next, next_xy, seg_dir = _segment_at(rg, idx)
    same_next2, _, next_dir = _segment_at(rg, idx + 1)
    bis_start = _normalize(seg_dir + jnp.where(same_prev[..., None], prev_dir, 0.0), seg_dir)
    # At a polyline's last point (degenerate segment) the incoming direction is the only one.
    bis_start = jnp.where((~same_next & same_prev)[..., None], prev_dir, bis_start)
    has_next2 = same_next & same_next2
    bis_end = _normalize(seg_dir + jnp.where(has_next2[..., None], next_dir, 0.0), seg_dir)
    return next_xy, bis_start, bis_end


def select_road_edges(rg: Roadgraph, ref_xy, *, edge_capacity: int) -> RoadEdges:
    """Every road-edge point of one roadgraph in ``min(R, edge_capacity)`` slots, map order (a
    larger map keeps the nearest to ``ref_xy``, the SDC at step 10)."""
    rg = jax.tree.map(jnp.asarray, rg)
    xy = rg.xyz[:, :2]
    is_edge = rg.valid & jnp.isin(rg.type, jnp.asarray(RG_ROAD_EDGE_TYPES))
    d2 = jnp.sum((xy - jnp.asarray(ref_xy, xy.dtype)) ** 2, axis=-1)
    reach = jnp.sqrt(jnp.max(jnp.where(is_edge, d2, 0.0))) + 1.0  # every edge point within
    eidx, evalid = select_nearest(d2, is_edge, reach, min(rg.valid.shape[0], edge_capacity))
    next_xy, bis_start, bis_end = _segment_geometry(rg, eidx)
    return RoadEdges(xy=xy[eidx], dir=rg.dir[eidx, :2], next_xy=next_xy, bis_start=bis_start,
                     bis_end=bis_end, valid=evalid)


def road_edges_from_roadgraph(rg: Roadgraph) -> RoadEdges:
    """All road-edge slots of an (unbatched) roadgraph, uncropped (``[R]``, non-edges invalid)."""
    rg = jax.tree.map(jnp.asarray, rg)
    next_xy, bis_start, bis_end = _segment_geometry(rg, jnp.arange(rg.valid.shape[0]))
    is_edge = rg.valid & jnp.isin(rg.type, jnp.asarray(RG_ROAD_EDGE_TYPES))
    return RoadEdges(xy=rg.xyz[:, :2], dir=rg.dir[:, :2], next_xy=next_xy, bis_start=bis_start,
                     bis_end=bis_end, valid=is_edge)
