"""An exact, faster batched observation: nearest points from a cached candidate subset.

Why: the per-step cost of the observation is selecting the 1,500 nearest roadgraph points.
Between two steps the ego moves a few decimetres, so the nearest points barely change. We keep,
per example, a *candidate* subset of ``num_candidates`` roadgraph points (the nearest to the
believed ego position ``c`` at selection time) and the distance ``R`` from ``c`` to the nearest
point left out. At each step the selection runs over the candidates only. The result is
provably the same as over the whole roadgraph while ``R - |b - c| > d_N`` (``b``: current
believed position, ``d_N``: distance of the N-th selected point): any left-out point ``q`` then
has ``|q - b| >= R - |b - c| > d_N``. When that fails for any example of the batch, the
candidates of the whole batch are re-selected (a ``lax.cond`` on the batch, so the cost is paid
only on those steps). With fewer than N valid candidates the check requires that nothing was
left out.

The per-step selection (:func:`_packed_nearest`) avoids XLA:CPU's TopK (a comparator sort): it
packs ``(distance quantised to 2 max_radius / 2**(31 - log2 K), 0.8 mm by default, position)``
into one int32 and sorts that (a single-key integer sort, several times faster), then re-ranks
the 16 entries around the N-th exactly by ``(distance, roadgraph index)``, the full top-k's tie
rule. The observed *set* of points is the top-k's; the slots are nearest-first up to the quantum
(the policy's encoders pool over points, so the order does not matter to them;
:func:`igdrivsim.observation.observe` gives the exact order). If more than 8 entries share the
quantum at the boundary (piles of duplicate points), that step falls back to the re-selection
branch, which uses the exact top-k.

Candidate selection bisects a distance threshold (:func:`igdrivsim.simulator.roadgraph
.select_nearest`), linear in the number of points; the candidates are then ordered by their
distance to the centre with the same int32 packing (the per-step sort is cheaper on nearly
sorted input). Identical points keep their index order. The candidates' coordinates, directions
and types are copied once per selection so that a step reads a small contiguous array instead
of gathering from the roadgraph.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import SimpleNamespace
from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from igdrivsim.errors import ConfigError
from igdrivsim.observation.features import (
    DEFAULT_CONFIG,
    SPEED_SCALE,
    Observation,
    ObservationConfig,
    Selection,
    object_features,
    observe_arrays,
    roadgraph_features,
    rotate_to_frame,
    to_frame,
)
from igdrivsim.observation.models import ObservationSetting, apply_setting, perceive_pose
from igdrivsim.observation.observe import sdc_pose


@dataclass(frozen=True)
class CandidateConfig:
    """``num_candidates``: cached points per example (>= the observation's roadgraph capacity;
    more candidates -> fewer re-selections but a larger per-step top-k).
    ``max_radius``: candidates lie within this many metres of the ego (bisection range).
    ``band``: a step re-ranks only the candidates at positions ``[N - band, N + band)`` of the
    stored order (more -> fewer re-sorts but a larger per-step sort)."""

    num_candidates: int = 3000
    max_radius: float = 200.0
    band: int = 256


@struct.dataclass
class CandidatePoints:
    """The candidates' own copy of what the observation reads (no per-step gather), one array
    per field: on XLA:CPU a loop over ``xy[:, 0]`` and ``xy[:, 1]`` of an ``[K, 2]`` array runs
    ~30x slower than over two ``[K]`` arrays."""

    x: jax.Array  # f32[..., K]
    y: jax.Array  # f32[..., K]
    dir_x: jax.Array  # f32[..., K]
    dir_y: jax.Array  # f32[..., K]
    type: jax.Array  # int32[..., K]
    valid: jax.Array  # bool[..., K] (padding False)


@struct.dataclass
class RoadCandidates:
    """Per example (leading batch dims ``...``): the cached candidate subset."""

    index: jax.Array  # int32[..., K] into the roadgraph axis, nearest first; padding invalid
    points: CandidatePoints
    center: jax.Array  # f32[..., 2] believed ego position at selection
    radius: jax.Array  # f32[...] distance from center to the nearest left-out point (inf: none)
    reselections: jax.Array  # int32[...] how many times the candidates were (re)selected
    resorts: jax.Array  # int32[...] how many times they were re-sorted around the ego


def _packed_order(e: jax.Array, valid: jax.Array, scale: float):
    """Order ``e [K]`` by one int32 sort of ``(e quantised to scale / 2**(31 - log2 K),
    position)``, invalid entries last. Returns ``(order, q, top)``: the permutation, each
    entry's quantised value, and the value reserved for invalid entries."""
    k = e.shape[0]
    bits = max(1, (k - 1).bit_length())
    top = (1 << (31 - bits)) - 1
    q = jnp.clip(jnp.floor(e * (top / scale)), 0, 1 << 30).astype(jnp.int32)  # int: top may
    q = jnp.where(valid, jnp.minimum(q, top - 1), top)  # not be a float32 (small K)
    order = jnp.sort((q << bits) | jnp.arange(k, dtype=jnp.int32)) & ((1 << bits) - 1)
    return order, q, top


def _select(roadgraph: Any, center: jax.Array, config: CandidateConfig):
    """Candidates of ONE example around ``center``: ``(index, valid, radius)``."""
    from igdrivsim.simulator.roadgraph import select_nearest

    xy = jnp.asarray(roadgraph.xyz, jnp.float32)[..., :2]
    d2 = (xy[:, 0] - center[0]) ** 2 + (xy[:, 1] - center[1]) ** 2
    ok = jnp.asarray(roadgraph.valid, bool)
    k = min(config.num_candidates, xy.shape[0])
    idx, valid = select_nearest(d2, ok, config.max_radius, k)  # increasing roadgraph index
    order, _, _ = _packed_order(jnp.sqrt(d2[idx]), valid, config.max_radius)
    idx, valid = idx[order], valid[order]
    kept = jnp.zeros(xy.shape[0], bool).at[idx].max(valid)
    left = jnp.min(jnp.where(ok & ~kept, d2, jnp.inf))
    dirs = jnp.asarray(roadgraph.dir, jnp.float32)
    points = CandidatePoints(x=xy[idx, 0], y=xy[idx, 1], dir_x=dirs[idx, 0], dir_y=dirs[idx, 1],
                             type=jnp.asarray(roadgraph.type, jnp.int32)[idx],
                             valid=valid & ok[idx])
    return idx, points, jnp.sqrt(left)


def _believed(states: Any, setting: ObservationSetting, episode_keys, step_keys):
    from igdrivsim.simulator import current_objects

    objects = current_objects(states)
    xy, yaw, speed = jax.vmap(sdc_pose)(objects, states.sdc_index)
    bxy, byaw = jax.vmap(lambda p, a, e, s: perceive_pose(setting, p, a, e, s))(
        xy, yaw, episode_keys, step_keys)
    return objects, bxy, byaw, speed


def init_candidates(states: Any, setting: ObservationSetting, episode_keys: jax.Array,
                    config: CandidateConfig = CandidateConfig(),
                    step_keys: jax.Array | None = None) -> RoadCandidates:
    """Select the candidates of a batch ``[B]`` of states (e.g. right after reset)."""
    step_keys = episode_keys if step_keys is None else step_keys
    _, bxy, _, _ = _believed(states, setting, episode_keys, step_keys)
    idx, points, radius = jax.vmap(lambda rg, c: _select(rg, c, config))(states.roadgraph, bxy)
    return RoadCandidates(index=idx, points=points, center=bxy, radius=radius,
                          reselections=jnp.ones(bxy.shape[:1], jnp.int32),
                          resorts=jnp.zeros(bxy.shape[:1], jnp.int32))


def _observe_one(bxy, byaw, speed, objects, sdc_index, cand_index, points, center, radius,
                 config: ObservationConfig):
    """Observation (before hiding) of one example from its candidates, and whether it is exact."""
    as_roadgraph = SimpleNamespace(xyz=jnp.stack([points.x, points.y], -1),
                                   dir=jnp.stack([points.dir_x, points.dir_y], -1),
                                   type=points.type, valid=points.valid)
    obs, sel = observe_arrays(bxy, byaw, speed, objects, sdc_index, as_roadgraph, config)
    pos = sel.roadgraph_index
    d = jnp.sqrt((points.x[pos] - bxy[0]) ** 2 + (points.y[pos] - bxy[1]) ** 2)
    full = jnp.all(obs.roadgraph_valid)
    d_last = jnp.max(jnp.where(obs.roadgraph_valid, d, 0.0))
    moved = jnp.sqrt(jnp.sum((bxy - center) ** 2))
    exact = jnp.where(full, radius - moved > d_last + 1e-3, jnp.isinf(radius))  # float margin
    sel = Selection(object_index=sel.object_index,
                    roadgraph_index=jnp.take(cand_index, sel.roadgraph_index))
    return obs, sel, exact


_BOUNDARY = 8  # entries on each side of the N-th nearest whose order is resolved exactly


def _packed_nearest(d2: jax.Array, valid: jax.Array, tie: jax.Array, n: int, scale: float):
    """The ``n`` nearest valid entries of ``d2 [K]`` as a set, approximately nearest first.

    One int32 sort of ``(distance quantised to scale / 2**(31 - log2 K), position)`` orders
    them; the ``2 * _BOUNDARY`` entries around the ``n``-th are then re-ranked exactly by
    ``(d2, tie)`` (``tie``: roadgraph index, as the full top-k breaks ties). Returns
    ``(positions int32[n], ok)``; ``ok`` is False when the quantisation could hide the true
    boundary (more than ``_BOUNDARY`` entries within one quantum of it): use the top-k then.
    """
    k = d2.shape[0]
    order, q, top = _packed_order(jnp.sqrt(d2), valid, scale)
    h = min(_BOUNDARY, n, k - n)
    if h == 0:
        return order[:n], jnp.bool_(True)
    win = order[n - h:n + h]
    wd, wt = jnp.where(valid[win], d2[win], jnp.inf), tie[win]
    a, b = (slice(None), None), (None, slice(None))  # first[i, j]: entry i precedes entry j
    first = (wd[a] < wd[b]) | ((wd[a] == wd[b]) & (
        (wt[a] < wt[b]) | ((wt[a] == wt[b]) & (win[a] < win[b]))))
    ranked = jnp.zeros_like(win).at[jnp.sum(first, axis=0)].set(win)
    qw = q[ranked]
    ok = jnp.bool_(True)
    if n - h > 0:  # everything left of the window precedes every unselected window entry
        ok &= (q[order[n - h - 1]] < qw[h]) | (jnp.sum(valid) <= n)
    if n + h < k:  # everything right of it follows every selected one
        ok &= (q[order[n + h]] > qw[h - 1]) | (q[order[n + h]] == top)
    return jnp.concatenate([order[:n - h], ranked[:h]]), ok


def _covers(bxy, center, radius, d_last, full):
    """The candidates hold the true nearest N: any left-out point is farther than the N-th."""
    moved = jnp.sqrt(jnp.sum((bxy - center) ** 2))
    return jnp.where(full, radius - moved > d_last + 1e-3, jnp.isinf(radius))  # float margin


def _band_select(d2: jax.Array, valid: jax.Array, tie: jax.Array, n: int, band: int,
                 scale: float):
    """The ``n`` nearest valid entries of ``d2 [K]`` when the stored order is nearly sorted.

    The first ``n - band`` entries are taken as they are and the ``band`` nearest of the next
    ``2 band`` are picked by :func:`_packed_nearest`. That is the exact top-``n`` set when every
    taken entry is nearer than every entry left (checked on the exact distances; ties fail),
    or when at most ``n`` entries are valid and they come first. Returns ``(positions
    int32[n], exact, squared distance of the farthest taken entry)``; positions ``< n - band``
    are the identity (callers slice them instead of gathering).
    """
    k = d2.shape[0]
    w = min(band, n, k - n)
    lo, hi = n - w, n + w
    d2 = jnp.where(valid, d2, jnp.inf)
    few = jnp.sum(valid) <= n
    if w == 0:
        return jnp.arange(n), jnp.bool_(True), jnp.max(jnp.where(valid[:n], d2[:n], 0.0))
    band_pos, ok = _packed_nearest(d2[lo:hi], valid[lo:hi], tie[lo:hi], w, scale)
    taken = jnp.zeros(2 * w, bool).at[band_pos].set(True)
    inf = jnp.float32(jnp.inf)
    head_max = jnp.max(d2[:lo]) if lo > 0 else -inf
    tail_min = jnp.min(d2[hi:]) if hi < k else inf
    taken_max = jnp.max(jnp.where(taken, d2[lo:hi], -inf))
    left_min = jnp.minimum(jnp.min(jnp.where(taken, inf, d2[lo:hi])), tail_min)
    split = (head_max < left_min) & (taken_max < tail_min)
    first = jnp.all(valid[:n] == (jnp.arange(n) < jnp.sum(valid)))
    exact = ok & jnp.where(few, first, split)
    last2 = jnp.max(jnp.where(valid[:lo], d2[:lo], 0.0), initial=0.0)
    last2 = jnp.maximum(last2, jnp.max(jnp.where(taken & valid[lo:hi], d2[lo:hi], 0.0)))
    return jnp.concatenate([jnp.arange(lo), lo + band_pos]), exact, last2


def _observe_band(bxy, byaw, speed, objects, sdc_index, c: RoadCandidates,
                  config: ObservationConfig, cand_config: CandidateConfig):
    """Observation (before hiding) of one example from its stored candidate order
    (:func:`_band_select`). Returns ``(observation, selection, exact, covers)``; ``covers`` is
    :func:`_covers` for this selection."""
    pts, n = c.points, config.num_roadgraph_points
    obj, obj_valid, obj_idx = object_features(bxy, byaw, objects, sdc_index, config.num_objects)
    d2 = (pts.x - bxy[0]) ** 2 + (pts.y - bxy[1]) ** 2
    pos, exact, last2 = _band_select(d2, pts.valid, c.index, n, cand_config.band,
                                     2.0 * cand_config.max_radius)
    lo = n - min(cand_config.band, n, pts.x.shape[0] - n)

    def pick(a):  # a[pos], the head sliced rather than gathered
        return jnp.concatenate([a[:lo], a[pos[lo:]]])

    valid = pick(pts.valid)
    rx, ry = to_frame(pick(pts.x), pick(pts.y), bxy, byaw)
    dx, dy = rotate_to_frame(pick(pts.dir_x), pick(pts.dir_y), byaw)
    obs = Observation(
        objects=obj, objects_valid=obj_valid,
        roadgraph=roadgraph_features(rx, ry, dx, dy, pick(pts.type), valid),
        roadgraph_valid=valid, sdc_speed=jnp.reshape(speed / SPEED_SCALE, (1,)))
    covers = _covers(bxy, c.center, c.radius, jnp.sqrt(last2), jnp.all(valid))
    return obs, Selection(object_index=obj_idx, roadgraph_index=pick(c.index)), exact, covers


def _resort(c: RoadCandidates, bxy: jax.Array, scale: float) -> RoadCandidates:
    """The same candidates of one example stored nearest-first around ``bxy`` (invalid last)."""
    p = c.points
    d = jnp.sqrt((p.x - bxy[0]) ** 2 + (p.y - bxy[1]) ** 2)
    order, _, _ = _packed_order(d, p.valid, scale)
    return c.replace(index=c.index[order], points=jax.tree.map(lambda a: a[order], p),
                     resorts=c.resorts + 1)


def observe_batch_with_candidates(
    states: Any,
    setting: ObservationSetting,
    episode_keys: jax.Array,
    step_keys: jax.Array,
    candidates: RoadCandidates,
    config: ObservationConfig = DEFAULT_CONFIG,
    cand_config: CandidateConfig = CandidateConfig(),
    return_selection: bool = False,
):
    """:func:`igdrivsim.observation.observe` for a batch ``[B]`` of states, from candidates.

    Returns ``(observation [B], updated candidates)`` (plus the :class:`Selection` with
    ``return_selection``): the same observed points as ``vmap(observe)``, with the roadgraph
    slots in the stored candidate order (nearest first as of the last re-sort) instead of
    exactly nearest first. Each step tries, in turn, until one is exact for the whole batch:
    the stored order (:func:`_observe_band`); the candidates re-sorted around the ego; new
    candidates with the exact top-k. Call it under ``jit`` WITHOUT an outer ``vmap`` so these
    stay real branches (``lax.cond`` on the batch).
    """
    if cand_config.num_candidates < config.num_roadgraph_points:
        raise ConfigError(f"CandidateConfig.num_candidates ({cand_config.num_candidates}) must be "
                          f">= num_roadgraph_points ({config.num_roadgraph_points})")
    objects, bxy, byaw, speed = _believed(states, setting, episode_keys, step_keys)
    scale = 2.0 * cand_config.max_radius
    band = jax.vmap(lambda c, *a: _observe_band(*a, c, config, cand_config))

    def run(c: RoadCandidates):
        return band(c, bxy, byaw, speed, objects, states.sdc_index)

    def reselect(_):  # new candidates around the ego: the stored order is exact unless ties
        idx, points, radius = jax.vmap(lambda rg, c: _select(rg, c, cand_config))(
            states.roadgraph, bxy)
        c = candidates.replace(index=idx, points=points, center=bxy, radius=radius,
                               reselections=candidates.reselections + 1)
        o, s, exact, _ = run(c)

        def top_k(_):
            o, s, _ = jax.vmap(lambda *a: _observe_one(*a, config))(
                bxy, byaw, speed, objects, states.sdc_index, c.index, c.points, c.center,
                c.radius)
            return o, s

        o, s = jax.lax.cond(jnp.all(exact), lambda _: (o, s), top_k, None)
        return o, s, c

    def resort(_):
        c = jax.vmap(lambda c, b: _resort(c, b, scale))(candidates, bxy)
        o, s, exact, covers = run(c)
        return jax.lax.cond(jnp.all(exact & covers), lambda _: (o, s, c), reselect, None)

    obs, sel, exact, covers = run(candidates)
    obs, sel, candidates = jax.lax.cond(
        jnp.all(exact & covers), lambda _: (obs, sel, candidates),
        lambda _: jax.lax.cond(jnp.all(covers), resort, reselect, None), None)
    obs = jax.vmap(lambda o, e, s: apply_setting(setting, o, e, s))(obs, episode_keys, step_keys)
    if return_selection:
        return obs, candidates, sel
    return obs, candidates


__all__ = ["CandidateConfig", "CandidatePoints", "RoadCandidates", "init_candidates",
           "observe_batch_with_candidates", "Observation"]
