"""The observation pipeline: believed pose -> SDC-frame features -> hiding, for one example.

``observe(source, setting, episode_key, step_key)`` is what training and evaluation call at
every step; the source is a simulator state or one step of a recorded episode
(:class:`~igdrivsim.observation.record.ObservationRecord`, the teacher-forced episodes BC trains
on). :func:`observe_setting_arrays` is the same on plain arrays (tests, pictures). All take one
example: ``jax.vmap`` them over a batch of sources and keys.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp

from igdrivsim.observation.features import (
    DEFAULT_CONFIG,
    Observation,
    ObservationConfig,
    Selection,
    observe_arrays,
)
from igdrivsim.observation.models import ObservationSetting, apply_setting, perceive_pose
from igdrivsim.observation.record import ObservationRecord, observe_record
from igdrivsim.simulator import current_objects, sdc_yaw_rate


def observe_setting_arrays(
    sdc_xy: jax.Array,
    sdc_yaw: jax.Array,
    sdc_speed: jax.Array,
    objects: Any,
    sdc_index: jax.Array,
    roadgraph: Any,
    setting: ObservationSetting,
    episode_key: jax.Array,
    step_key: jax.Array,
    config: ObservationConfig = DEFAULT_CONFIG,
    sdc_yaw_rate: jax.Array = 0.0,
) -> tuple[Observation, Selection]:
    """The observation under ``setting`` from plain arrays (see :func:`observe_arrays`).

    ``sdc_xy``/``sdc_yaw`` is the ego's TRUE pose; the setting's pose models turn it into the
    believed pose before the frame transform and the nearest-N selection.
    """
    xy, yaw = perceive_pose(setting, jnp.asarray(sdc_xy, jnp.float32),
                            jnp.asarray(sdc_yaw, jnp.float32), episode_key, step_key)
    obs, sel = observe_arrays(xy, yaw, sdc_speed, objects, sdc_index, roadgraph, config,
                              sdc_yaw_rate)
    return apply_setting(setting, obs, episode_key, step_key), sel


def sdc_pose(objects: Any, sdc_index: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """The ego's ``(xy f32[2], yaw f32[], speed f32[])`` from per-object arrays ``[O]``."""
    pick = lambda a: jnp.take(jnp.asarray(a, jnp.float32), sdc_index, axis=-1)  # noqa: E731
    xy = jnp.stack([pick(objects.x), pick(objects.y)], axis=-1)
    return xy, pick(objects.yaw), jnp.hypot(pick(objects.vel_x), pick(objects.vel_y))


def observe_with_selection(
    state: Any,
    setting: ObservationSetting,
    episode_key: jax.Array,
    step_key: jax.Array,
    config: ObservationConfig = DEFAULT_CONFIG,
) -> tuple[Observation, Selection]:
    """:func:`observe` that also returns which object / roadgraph slots were selected."""
    objects = current_objects(state)
    xy, yaw, speed = sdc_pose(objects, state.sdc_index)
    return observe_setting_arrays(xy, yaw, speed, objects, state.sdc_index, state.roadgraph,
                                  setting, episode_key, step_key, config, sdc_yaw_rate(state))


def observe(
    source: Any,
    setting: ObservationSetting,
    episode_key: jax.Array,
    step_key: jax.Array,
    config: ObservationConfig = DEFAULT_CONFIG,
) -> Observation:
    """The imitator's observation (one example) under ``setting``, of a simulator state or of
    one step of an :class:`ObservationRecord`.

    Pass the SAME ``episode_key`` at every step of an episode (the position-noise offset is drawn
    from it) and a fresh ``step_key`` per step (random masking), e.g.
    ``jax.random.fold_in(episode_key, state.timestep)``.
    """
    if isinstance(source, ObservationRecord):
        return observe_record(source, setting, episode_key, step_key, config)
    return observe_with_selection(source, setting, episode_key, step_key, config)[0]
