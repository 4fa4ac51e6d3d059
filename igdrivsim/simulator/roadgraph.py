"""Roadgraph crop (once per scenario, at reset) and the separate road-edge array.

Why: a WOMD scenario carries 20,000 roadgraph points, most of them far from anything the SDC can
reach in 8 s. Selecting nearest points and testing road edges against all of them at every step
dominates the cost of a naive simulator. Instead :func:`crop_roadgraph` keeps, once per scenario,
the points within ``radius`` of the *logged* SDC path (fixed output capacity; when more points
qualify, the nearest to the path are kept; padding is invalid; the original point order, hence
polyline order, is preserved). Road edges (types 15, 16) get their own small :class:`RoadEdges`
array, with what the segment-based offroad distance needs precomputed.

Selection uses a bisection on the distance threshold plus ``jnp.nonzero(size=...)`` (linear in
the number of points) rather than a top-k/sort over all points.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from igdrivsim.data.scenario import RG_ROAD_EDGE_TYPES, Roadgraph

_BISECTION_STEPS = 24


@struct.dataclass
class RoadEdges:
    """Road-edge points (types 15, 16), ``[..., E]`` (``[..., E, 2]`` for 2-D vectors).

    ``xy``/``dir``: the point and its stored unit direction (road interior on the left; used by
    the point rule). ``next_xy``: the next point of the same polyline (``xy`` itself at a
    polyline end), so ``xy -> next_xy`` is a segment. ``bis_start``/``bis_end``: unit
    directions at the segment's two vertices, the bisector of the incoming and outgoing
    segment directions (used for the sign when the nearest point of a segment is a vertex).
    """

    xy: jax.Array
    dir: jax.Array
    next_xy: jax.Array
    bis_start: jax.Array
    bis_end: jax.Array
    valid: jax.Array


def _normalize(v, fallback):
    n = jnp.sqrt(jnp.sum(v * v, axis=-1, keepdims=True))
    return jnp.where(n > 1e-6, v / jnp.maximum(n, 1e-6), fallback)


def path_distance_sq(points_xy, path_xy, path_valid):
    """Squared distance of each point ``[R, 2]`` to the nearest valid path point ``[T, 2]``."""
    d2 = ((points_xy[:, None, 0] - path_xy[None, :, 0]) ** 2
          + (points_xy[:, None, 1] - path_xy[None, :, 1]) ** 2)
    return jnp.min(jnp.where(path_valid[None, :], d2, jnp.inf), axis=-1)


def select_nearest(d2, eligible, radius: float, capacity: int):
    """Indices ``int32[capacity]`` of eligible points with ``d2 <= radius**2``, nearest first kept.

    Returns ``(indices, valid)``; indices are in increasing (original) order, padding invalid.
    The threshold is bisected so that at most ``capacity`` points pass it.
    """
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


def _segment_geometry(rg: Roadgraph):
    """Per point: next point of its polyline, and vertex bisectors (unbatched ``[R]``)."""
    xy = rg.xyz[:, :2]
    nxt = jnp.roll(xy, -1, axis=0)
    same_next = (jnp.roll(rg.id, -1) == rg.id) & jnp.roll(rg.valid, -1) & rg.valid
    same_next = same_next.at[-1].set(False)
    next_xy = jnp.where(same_next[:, None], nxt, xy)
    seg_dir = _normalize(next_xy - xy, _normalize(rg.dir[:, :2], jnp.zeros_like(xy)))
    prev_dir = jnp.roll(seg_dir, 1, axis=0)
    has_prev = jnp.roll(same_next, 1).at[0].set(False)
    next_dir = jnp.roll(seg_dir, -1, axis=0)
    has_next2 = same_next & jnp.roll(same_next, -1)
    bis_start = _normalize(seg_dir + jnp.where(has_prev[:, None], prev_dir, 0.0), seg_dir)
    # At a polyline's last point (degenerate segment) the incoming direction is the only one.
    bis_start = jnp.where((~same_next & has_prev)[:, None], prev_dir, bis_start)
    bis_end = _normalize(seg_dir + jnp.where(has_next2[:, None], next_dir, 0.0), seg_dir)
    return next_xy, bis_start, bis_end


def crop_roadgraph(rg: Roadgraph, path_xy, path_valid, *, radius: float, capacity: int,
                   edge_radius: float, edge_capacity: int) -> tuple[Roadgraph, RoadEdges]:
    """Crop one (unbatched) roadgraph around a path; see the module docstring.

    ``path_xy [T, 2]``/``path_valid [T]``: the logged SDC positions. Returns the cropped
    :class:`Roadgraph` ``[capacity]`` and the :class:`RoadEdges` ``[edge_capacity]``.
    """
    rg = jax.tree.map(jnp.asarray, rg)
    xy = rg.xyz[:, :2]
    d2 = path_distance_sq(xy, jnp.asarray(path_xy), jnp.asarray(path_valid))
    idx, valid = select_nearest(d2, rg.valid, radius, capacity)
    cropped = jax.tree.map(lambda a: a[idx], rg)
    cropped = cropped.replace(valid=valid & cropped.valid)

    is_edge = rg.valid & jnp.isin(rg.type, jnp.asarray(RG_ROAD_EDGE_TYPES))
    eidx, evalid = select_nearest(d2, is_edge, edge_radius, edge_capacity)
    next_xy, bis_start, bis_end = _segment_geometry(rg)
    edges = RoadEdges(
        xy=xy[eidx], dir=rg.dir[eidx, :2], next_xy=next_xy[eidx], bis_start=bis_start[eidx],
        bis_end=bis_end[eidx], valid=evalid,
    )
    return cropped, edges


def road_edges_from_roadgraph(rg: Roadgraph) -> RoadEdges:
    """All road-edge slots of an (unbatched) roadgraph, uncropped (``[R]``, non-edges invalid)."""
    rg = jax.tree.map(jnp.asarray, rg)
    next_xy, bis_start, bis_end = _segment_geometry(rg)
    is_edge = rg.valid & jnp.isin(rg.type, jnp.asarray(RG_ROAD_EDGE_TYPES))
    return RoadEdges(xy=rg.xyz[:, :2], dir=rg.dir[:, :2], next_xy=next_xy, bis_start=bis_start,
                     bis_end=bis_end, valid=is_edge)
