"""A recorded episode as an observation source: what the ego saw before any setting, replayed.

The logged (expert-driven) episode of a scenario is deterministic, so what the ego sees along it
*before* the partial-observability model is the same for every setting, seed and method.
:class:`ObservationRecord` holds it (computed once per dataset by
:func:`igdrivsim.training.records.compute_teacher` and cached), in the TRUE ego frame, with more
than the observation's capacities (:func:`superset_config`): every other object slot (``K``)
and the ``M = 4 N`` nearest roadgraph points. :func:`igdrivsim.observation.observe` takes such a
record (one step of it) as its source as it takes a simulator state, and applies the setting:

1. the believed pose (Gaussian position noise) shifts every point by the same offset, and the
   ``N`` nearest points / ``n`` nearest objects are re-selected around the believed position
   from the recorded superset (without noise the recorded order is taken as is);
2. the setting's hiding (fields of view, masking) with the same keys as on a simulator state.

Without noise this equals the observation of the simulator state exactly; with noise it does
while the ``N`` nearest points around the believed position are among the ``4 N`` nearest
around the true one, i.e. while the offset is below the radius of the ``N`` nearest (tens of
metres for the observation sizes in use, against an offset of a few metres).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from igdrivsim.observation.features import (
    POSITION_SCALE,
    Observation,
    ObservationConfig,
    nearest,
    roadgraph_rows,
    rotate_to_frame,
)
from igdrivsim.observation.models import apply_setting, perceive_pose


@struct.dataclass
class ObservationRecord:
    """One scenario's teacher-forced episode (leading axes ``[..., T=90]``), true ego frame.

    Observation fields hold the features of :mod:`igdrivsim.observation.features` (positions
    divided by 100) for the ``K`` object slots and ``M`` roadgraph points nearest the true pose,
    nearest first; ``actions``/``action_valid`` are the discretised expert's labels of the 80
    controlled steps (index ``t - 10``), recorded with it for training (``None`` in a one-step
    slice).
    """

    objects: jax.Array  # f32[..., T, K, 6]
    objects_valid: jax.Array  # bool[..., T, K]
    roadgraph: jax.Array  # f32[..., T, M, 4]: x, y, dir_x, dir_y
    roadgraph_type: jax.Array  # int8[..., T, M]
    roadgraph_valid: jax.Array  # bool[..., T, M]
    sdc_speed: jax.Array  # f32[..., T, 1]
    sdc_yaw_rate: jax.Array  # f32[..., T, 1]
    sdc_yaw: jax.Array  # f32[..., T]
    actions: jax.Array  # int16[..., 80, 3]
    action_valid: jax.Array  # bool[..., 80]


def superset_config(obs: ObservationConfig, max_objects: int) -> ObservationConfig:
    """What is recorded: every other object slot and four times the observed roadgraph points
    (the ``N`` nearest around a believed position ``e`` metres off are among the ``4 N``
    nearest around the true one while ``e`` is below the radius of the ``N`` nearest)."""
    return ObservationConfig(max(obs.num_objects, max_objects - 1), 4 * obs.num_roadgraph_points)


def observe_record(rec: ObservationRecord, setting, episode_key: jax.Array,
                   step_key: jax.Array, config: ObservationConfig) -> Observation:
    """The observation of one recorded step under ``setting`` (one example: ``rec`` fields
    ``[K, ...]`` / ``[M, ...]``); what :func:`igdrivsim.observation.observe` does with a
    record."""
    yaw = rec.sdc_yaw
    zero = jnp.zeros((2,), jnp.float32)
    offset, _ = perceive_pose(setting, zero, yaw, episode_key, step_key)
    dx, dy = rotate_to_frame(offset[0], offset[1], yaw)
    shift = jnp.stack([dx, dy]) / POSITION_SCALE
    moved = jnp.any(shift != 0)

    def pick(xy, valid, n):
        """The ``n`` nearest around the believed pose (the recorded order when not moved)."""
        idx, ok = nearest(jnp.sum((xy - shift) ** 2, -1), valid, n)
        first = jnp.arange(n)
        return jnp.where(moved, idx, first), jnp.where(moved, ok, valid[:n])

    oi, ov = pick(rec.objects[:, :2], rec.objects_valid, config.num_objects)
    objects = rec.objects[oi].at[:, :2].add(-shift)
    objects = jnp.where(ov[:, None], objects, 0.0)
    ri, rv = pick(rec.roadgraph[:, :2], rec.roadgraph_valid, config.num_roadgraph_points)
    rg4 = rec.roadgraph[ri].at[:, :2].add(-shift)
    rg = roadgraph_rows(rg4, rec.roadgraph_type[ri].astype(jnp.int32), rv)
    obs = Observation(objects=objects, objects_valid=ov, roadgraph=rg, roadgraph_valid=rv,
                      sdc_speed=rec.sdc_speed, sdc_yaw_rate=rec.sdc_yaw_rate)
    return apply_setting(setting, obs, episode_key, step_key)


def episode_observations(rec: ObservationRecord, setting, episode_key: jax.Array,
                         config: ObservationConfig) -> Observation:
    """All 90 observations of one recorded episode, ``[T, ...]`` (step key ``fold_in(episode
    key, t)``, as on the simulator state at step ``t``)."""
    steps = jnp.arange(rec.sdc_yaw.shape[0])
    per_step = rec.replace(actions=None, action_valid=None)  # the labels have 80 steps, not 90
    return jax.vmap(lambda r, t: observe_record(
        r, setting, episode_key, jax.random.fold_in(episode_key, t), config))(per_step, steps)
