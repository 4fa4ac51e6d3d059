"""Partial-observability models, their composition into settings, and the paper's six presets.

A model acts at two points of the observation pipeline: ``perceive_pose``, the ego's believed
global pose, relative to which the nearest N are selected; and ``apply``, hiding in the
SDC-frame observation: hidden slots become invalid with zero features and are never refilled.

``episode_key`` is constant over an episode, ``step_key`` changes every step; model ``i`` of a
setting draws from ``fold_in(key, i)``. Functions take ONE example. Settings compose by name
with ``+`` (:func:`get_setting`) and stack as one ``vmap``-ed program (:func:`stack_settings`).
Adding a model: docs/EXTENDING.md.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from igdrivsim.errors import ConfigError
from igdrivsim.names import SETTING_TITLES
from igdrivsim.observation.features import (
    Observation,
    hide_objects,
    hide_roadgraph,
    object_positions,
    roadgraph_positions,
)


def concrete(value: Any) -> bool:
    """A Python number (a model's parameters are checked when built, not when traced)."""
    return isinstance(value, int | float)


@struct.dataclass
class ObservationModel:
    """Base model: the identity (full observability). Subclasses override one or both hooks; a
    :func:`flax.struct.dataclass` subclass stacks with other settings, a plain frozen
    dataclass trains on its own."""

    def perceive_pose(self, sdc_xy: jax.Array, sdc_yaw: jax.Array, episode_key: jax.Array,
                      step_key: jax.Array) -> tuple[jax.Array, jax.Array]:
        """The ego's believed global pose ``(xy f32[2], yaw f32[])``; default: the true pose."""
        return sdc_xy, sdc_yaw

    def apply(self, obs: Observation, episode_key: jax.Array, step_key: jax.Array) -> Observation:
        """The observation after this model's hiding; default: unchanged."""
        return obs

    def neutral(self) -> ObservationModel | None:
        """This model with parameters under which it changes nothing (padding a stack), or
        ``None`` when it has none (the default)."""
        return None


@struct.dataclass
class FullObservability(ObservationModel):
    """Sees everything the SDC-frame observation holds."""

    def neutral(self):
        return self


@struct.dataclass
class CircularFieldOfView(ObservationModel):
    """Hides objects (centres) and road points farther than ``radius`` metres from the ego."""

    radius: float

    def __post_init__(self) -> None:
        if concrete(self.radius) and not self.radius > 0:
            raise ConfigError(f"circular field of view: radius must be > 0, got {self.radius}")

    def apply(self, obs, episode_key, step_key):
        return _hide_outside(obs, lambda xy: _within(xy, self.radius))

    def neutral(self):
        return self.replace(radius=math.inf)


@struct.dataclass
class ConicFieldOfView(ObservationModel):
    """Hides what is farther than ``radius`` or beyond ``+-angle/2`` of the heading (inclusive)."""

    radius: float
    angle: float  # full opening angle, radians

    def __post_init__(self) -> None:
        if concrete(self.radius) and concrete(self.angle) and not (
                self.radius > 0 and 0 < self.angle <= 2 * math.pi):
            raise ConfigError(f"conic field of view: need radius > 0 and 0 < angle <= 2*pi, got "
                              f"radius={self.radius}, angle={self.angle}")

    def apply(self, obs, episode_key, step_key):
        def inside(xy):
            bearing = jnp.abs(jnp.arctan2(xy[..., 1], xy[..., 0]))
            return _within(xy, self.radius) & (bearing <= self.angle / 2)

        return _hide_outside(obs, inside)

    def neutral(self):
        return self.replace(radius=math.inf, angle=2 * math.pi)


@struct.dataclass
class GaussianPositionNoise(ObservationModel):
    """The ego believes it is at ``p + eps``, ``eps ~ N(0, sigma^2 I)`` drawn ONCE per episode
    (everything else shifts together; the heading is not perturbed)."""

    sigma: float

    def __post_init__(self) -> None:
        if concrete(self.sigma) and not self.sigma >= 0:
            raise ConfigError(f"gaussian position noise: sigma must be >= 0, got {self.sigma}")

    def offset(self, episode_key: jax.Array) -> jax.Array:
        """The episode's global position offset ``f32[2]`` (metres)."""
        return self.sigma * jax.random.normal(episode_key, (2,), jnp.float32)

    def perceive_pose(self, sdc_xy, sdc_yaw, episode_key, step_key):
        return sdc_xy + self.offset(episode_key), sdc_yaw

    def neutral(self):
        return self.replace(sigma=0.0)


@struct.dataclass
class RandomMasking(ObservationModel):
    """Hides each other object independently with probability ``p``, redrawn every step."""

    p: float

    def __post_init__(self) -> None:
        if concrete(self.p) and not 0 <= self.p <= 1:
            raise ConfigError(f"random masking: p must be in [0, 1], got {self.p}")

    def apply(self, obs, episode_key, step_key):
        hidden = jax.random.bernoulli(step_key, self.p, obs.objects_valid.shape)
        return hide_objects(obs, ~hidden)

    def neutral(self):
        return self.replace(p=0.0)


@struct.dataclass
class FunctionModel(ObservationModel):
    """A model from one module-level function ``fn(obs, episode_key, step_key) -> Observation``."""

    fn: Callable[[Observation, jax.Array, jax.Array], Observation] = struct.field(pytree_node=False)

    def apply(self, obs, episode_key, step_key):
        return self.fn(obs, episode_key, step_key)


def _within(xy: jax.Array, radius: float) -> jax.Array:
    return jnp.sum(xy**2, axis=-1) <= radius**2


def _hide_outside(obs: Observation, inside: Callable[[jax.Array], jax.Array]) -> Observation:
    obs = hide_objects(obs, inside(object_positions(obs)))
    return hide_roadgraph(obs, inside(roadgraph_positions(obs)))


@struct.dataclass
class ObservationSetting:
    """A named composition of models, applied in order (hashable while its numbers are Python
    numbers). Model ``i`` draws from ``fold_in(key, keys[i])`` (``keys`` None: ``i``), so a
    stacked setting draws as the setting alone does."""

    name: str = struct.field(pytree_node=False)
    models: tuple[ObservationModel, ...] = ()
    keys: tuple[Any, ...] | None = None


def _merged_order(sequences: list[list[Any]]) -> list[Any] | None:
    """One order of every slot that keeps each sequence's order (first seen first), or
    ``None`` when two sequences order two slots oppositely."""
    slots = list(dict.fromkeys(s for seq in sequences for s in seq))
    after = {s: set() for s in slots}
    for seq in sequences:
        for a, b in zip(seq, seq[1:], strict=False):
            after[b].add(a)
    order: list[Any] = []
    while len(order) < len(slots):
        ready = [s for s in slots if s not in order and after[s] <= set(order)]
        if not ready:
            return None
        order.append(ready[0])
    return order


def stack_settings(settings: Sequence[ObservationSetting | str]) -> ObservationSetting | None:
    """``settings`` as ONE setting whose numbers carry a leading axis ``[G]`` (a setting lacking
    a model gets its ``neutral()`` form), or ``None`` when they cannot share a program (a model
    not a pytree or without a neutral form, or models ordered oppositely)."""
    found = [get_setting(s) for s in settings]
    rows: list[dict[Any, tuple[ObservationModel, int]]] = []
    for setting in found:
        row: dict[Any, tuple[ObservationModel, int]] = {}
        for i, m in enumerate(setting.models):
            if jax.tree.structure(m) == jax.tree.structure(0.0):  # an opaque leaf, not a node
                return None
            kind = (type(m), jax.tree.structure(m))  # a treedef alone may not tell classes apart
            row[(kind, sum(k[0] == kind for k in row))] = (m, i)
        rows.append(row)
    order = _merged_order([list(row) for row in rows])
    if order is None:
        return None
    models, keys = [], []
    for slot in order:
        present = next(row[slot][0] for row in rows if slot in row)
        column = [row.get(slot, (present.neutral(), 0)) for row in rows]
        if any(m is None for m, _ in column):
            return None
        # Python numbers -> strongly typed arrays (float32, int32): traced data
        models.append(jax.tree.map(lambda *v: jnp.array(v), *[m for m, _ in column]))
        keys.append(jnp.asarray([i for _, i in column], jnp.int32))
    return ObservationSetting(",".join(s.name for s in found), tuple(models), tuple(keys))


def perceive_pose(setting: ObservationSetting, sdc_xy: jax.Array, sdc_yaw: jax.Array,
                  episode_key: jax.Array, step_key: jax.Array) -> tuple[jax.Array, jax.Array]:
    """The ego's believed pose under ``setting`` (stage 1 of the pipeline)."""
    for m, k in zip(setting.models, setting.keys or range(len(setting.models)), strict=True):
        sdc_xy, sdc_yaw = m.perceive_pose(sdc_xy, sdc_yaw, jax.random.fold_in(episode_key, k),
                                          jax.random.fold_in(step_key, k))
    return sdc_xy, sdc_yaw


def apply_setting(setting: ObservationSetting, obs: Observation, episode_key: jax.Array,
                  step_key: jax.Array) -> Observation:
    """The hiding of every model of ``setting``, in order (stage 2 of the pipeline)."""
    for m, k in zip(setting.models, setting.keys or range(len(setting.models)), strict=True):
        obs = m.apply(obs, jax.random.fold_in(episode_key, k), jax.random.fold_in(step_key, k))
    return obs


PRESETS: dict[str, ObservationSetting] = {
    "full": ObservationSetting("full", (FullObservability(),)),
    "gaussian_noise": ObservationSetting("gaussian_noise", (GaussianPositionNoise(sigma=3.0),)),
    "circular_r4": ObservationSetting("circular_r4", (CircularFieldOfView(radius=4.0),)),
    "circular_r6": ObservationSetting("circular_r6", (CircularFieldOfView(radius=6.0),)),
    "conic_r4": ObservationSetting("conic_r4",
                                   (ConicFieldOfView(radius=4.0, angle=2 * math.pi / 3),)),
    "random_masking": ObservationSetting("random_masking", (RandomMasking(p=0.7),)),
}

# The paper's six, in Table I column order (the registry may hold more: register_setting).
PAPER_SETTINGS: tuple[str, ...] = tuple(PRESETS)

# Panel titles (igdrivsim.names; register_setting adds a new setting's).
PRESET_TITLES: dict[str, str] = {name: SETTING_TITLES[name] for name in PRESETS}


def register_setting(setting: ObservationSetting, title: str | None = None
                     ) -> ObservationSetting:
    """Add ``setting`` to the registry under its name: ``--obs NAME`` in every command, the
    pipeline's ``--obs`` and the tables' and figures' columns (labelled as in
    :mod:`igdrivsim.names`, else by the name); ``title`` heads its render panels (default:
    :mod:`igdrivsim.names`', else the name). Returns the setting."""
    if setting.name in PRESETS and PRESETS[setting.name] != setting:
        raise ConfigError(f"observation setting {setting.name!r} is already registered")
    PRESETS[setting.name] = setting
    PRESET_TITLES[setting.name] = title or SETTING_TITLES.get(setting.name) or setting.name
    return setting


def get_setting(spec: str | ObservationSetting) -> ObservationSetting:
    """A preset by name, or several composed with ``+`` (e.g. ``"gaussian_noise+circular_r4"``)."""
    if isinstance(spec, ObservationSetting):
        return spec
    names = [s.strip() for s in str(spec).split("+")]
    unknown = [n for n in names if n not in PRESETS]
    if unknown:
        raise ConfigError(f"unknown observation setting {unknown[0]!r}; "
                          f"choose from {', '.join(PRESETS)} (compose with '+')")
    if len(names) == 1:
        return PRESETS[names[0]]
    return ObservationSetting("+".join(names), tuple(m for n in names for m in PRESETS[n].models))
