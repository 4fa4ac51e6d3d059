"""Partial-observability models, their composition into settings, and the paper's six presets.

A model acts at two points of the observation pipeline (see :func:`apply_setting` and
:func:`igdrivsim.observation.observe`):

1. ``perceive_pose``: what the ego believes its own global pose is (Gaussian position noise).
   The SDC-frame observation, including the choice of the nearest N, is then computed relative
   to that belief, so every other object and road point shifts together.
2. ``apply``: hiding in the SDC-frame observation (fields of view, random masking). Hidden slots
   become invalid with all-zero features; slots are never refilled, i.e. the nearest N are
   selected first and hidden afterwards (a 4 m field of view shows only what lies within 4 m).

Randomness is explicit: ``episode_key`` is constant over an episode (per-episode draws such as the
position-noise offset), ``step_key`` changes every step (per-step draws such as masking). Model
``i`` of a setting receives ``fold_in(key, i)``, so composed models draw independently. All
functions take ONE example; ``jax.vmap`` over examples and keys gives per-example draws.

Adding a model takes one small function and a registry entry::

    def hide_behind(obs, episode_key, step_key):
        \"\"\"Hide everything behind the ego (x < 0).\"\"\"
        obs = hide_objects(obs, object_positions(obs)[..., 0] >= 0)
        return hide_roadgraph(obs, roadgraph_positions(obs)[..., 0] >= 0)

    register_setting(ObservationSetting("front_only", (FunctionModel(hide_behind),)))

A complete model with a data form (so it trains together with the paper's six) is
:mod:`igdrivsim.observation.occlusion`; ``docs/EXTENDING.md`` walks through it.

Settings compose: ``ObservationSetting("noisy_fov", (GaussianPositionNoise(3.0),
CircularFieldOfView(4.0)))``, or by name with :func:`get_setting`
(``"gaussian_noise+circular_r4"``).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from igdrivsim.errors import ConfigError
from igdrivsim.observation.features import (
    Observation,
    hide_objects,
    hide_roadgraph,
    object_positions,
    roadgraph_positions,
)
from igdrivsim.observation.sight import line_of_sight


@dataclass(frozen=True)
class ObservationModel:
    """Base model: the identity (full observability). Subclasses override one or both hooks."""

    def perceive_pose(self, sdc_xy: jax.Array, sdc_yaw: jax.Array, episode_key: jax.Array,
                      step_key: jax.Array) -> tuple[jax.Array, jax.Array]:
        """The ego's believed global pose ``(xy f32[2], yaw f32[])``; default: the true pose."""
        return sdc_xy, sdc_yaw

    def apply(self, obs: Observation, episode_key: jax.Array, step_key: jax.Array
              ) -> Observation:
        """The observation after this model's hiding; default: unchanged."""
        return obs

    def fold_params(self, params: ObservationParams, index: int) -> ObservationParams | None:
        """This model (the ``index``-th of its setting) folded into a setting-as-data
        description, or ``None`` when it has no such form (then the setting is compiled as a
        static program). Default: ``None``, so a model that overrides a hook but not this one
        is never silently treated as full observability when settings train together."""
        return None


@dataclass(frozen=True)
class FullObservability(ObservationModel):
    """Sees everything the SDC-frame observation holds."""

    def fold_params(self, params, index):
        return params  # nothing hidden: the identity


@dataclass(frozen=True)
class CircularFieldOfView(ObservationModel):
    """Hides objects (centres) and road points farther than ``radius`` metres from the ego."""

    radius: float

    def __post_init__(self) -> None:
        if not self.radius > 0:
            raise ConfigError(f"circular field of view: radius must be > 0, got {self.radius}")

    def apply(self, obs, episode_key, step_key):
        return _hide_outside(obs, lambda xy: _within(xy, self.radius))

    def fold_params(self, params, index):
        return params.replace(fov_radius=min(params.fov_radius, self.radius))


@dataclass(frozen=True)
class ConicFieldOfView(ObservationModel):
    """Hides what is farther than ``radius`` or outside ``+-angle/2`` of the ego heading (+x).

    Boundaries are inclusive; a point exactly at the ego position counts as visible.
    """

    radius: float
    angle: float  # full opening angle, radians

    def __post_init__(self) -> None:
        if not self.radius > 0 or not 0 < self.angle <= 2 * math.pi:
            raise ConfigError(f"conic field of view: need radius > 0 and 0 < angle <= 2*pi, got "
                              f"radius={self.radius}, angle={self.angle}")

    def apply(self, obs, episode_key, step_key):
        def inside(xy):
            bearing = jnp.abs(jnp.arctan2(xy[..., 1], xy[..., 0]))
            return _within(xy, self.radius) & (bearing <= self.angle / 2)

        return _hide_outside(obs, inside)

    def fold_params(self, params, index):
        return params.replace(fov_radius=min(params.fov_radius, self.radius),
                              fov_half_angle=min(params.fov_half_angle, self.angle / 2))


@dataclass(frozen=True)
class GaussianPositionNoise(ObservationModel):
    """The ego believes it is at ``p + eps``, ``eps ~ N(0, sigma^2 I)`` drawn ONCE per episode.

    Everything else is observed relative to that belief, so all other objects and road points
    shift together by ``-eps`` (rotated into the ego frame). The heading is not perturbed.
    """

    sigma: float

    def __post_init__(self) -> None:
        if not self.sigma >= 0:
            raise ConfigError(f"gaussian position noise: sigma must be >= 0, got {self.sigma}")

    def offset(self, episode_key: jax.Array) -> jax.Array:
        """The episode's global position offset ``f32[2]`` (metres)."""
        return self.sigma * jax.random.normal(episode_key, (2,), jnp.float32)

    def perceive_pose(self, sdc_xy, sdc_yaw, episode_key, step_key):
        return sdc_xy + self.offset(episode_key), sdc_yaw

    def fold_params(self, params, index):
        if params.noise_sigma > 0:  # two noise models: no single-offset form
            return None
        return params.replace(noise_sigma=self.sigma, noise_key=index)


@dataclass(frozen=True)
class RandomMasking(ObservationModel):
    """Hides each other object independently with probability ``p``, redrawn every step."""

    p: float

    def __post_init__(self) -> None:
        if not 0 <= self.p <= 1:
            raise ConfigError(f"random masking: p must be in [0, 1], got {self.p}")

    def apply(self, obs, episode_key, step_key):
        hidden = jax.random.bernoulli(step_key, self.p, obs.objects_valid.shape)
        return hide_objects(obs, ~hidden)

    def fold_params(self, params, index):
        if params.mask_p > 0:
            return None
        return params.replace(mask_p=self.p, mask_key=index)


@dataclass(frozen=True)
class FunctionModel(ObservationModel):
    """A model from one function ``fn(obs, episode_key, step_key) -> Observation``.

    Define ``fn`` at module level so the setting stays hashable and ``jit`` caches it.
    """

    fn: Callable[[Observation, jax.Array, jax.Array], Observation]

    def apply(self, obs, episode_key, step_key):
        return self.fn(obs, episode_key, step_key)


def _within(xy: jax.Array, radius: float) -> jax.Array:
    return jnp.sum(xy**2, axis=-1) <= radius**2


def _hide_outside(obs: Observation, inside: Callable[[jax.Array], jax.Array]) -> Observation:
    obs = hide_objects(obs, inside(object_positions(obs)))
    return hide_roadgraph(obs, inside(roadgraph_positions(obs)))


@dataclass(frozen=True)
class ObservationSetting:
    """A named composition of models, applied in order (hashable: usable as a static jit arg)."""

    name: str
    models: tuple[ObservationModel, ...] = ()

    def describe(self) -> dict[str, Any]:
        """A JSON-ready description (for ``config.json``)."""
        def one(m: ObservationModel) -> dict[str, Any]:
            fields = {f.name: getattr(m, f.name) for f in dataclasses.fields(m)}
            fields = {k: (getattr(v, "__qualname__", repr(v)) if callable(v) else v)
                      for k, v in fields.items()}
            return {"model": type(m).__name__, **fields}

        return {"name": self.name, "models": [one(m) for m in self.models]}


@struct.dataclass
class ObservationParams:
    """A setting as data: the built-in models' parameters in one pytree of scalars.

    Settings that differ only by these numbers share one compiled program (stack them and
    ``vmap``; training and evaluation run every setting of a method together this way). The
    draws equal the static setting's: the noise offset and the masking use the keys of the
    models' positions ``noise_key`` / ``mask_key`` in the setting. Neutral values: ``noise_sigma
    = 0``, ``fov_radius = inf``, ``fov_half_angle = inf``, ``mask_p = 0``. The occluder box
    (:mod:`.occlusion`) is ``None`` when no setting occludes, so the paper's six settings never
    trace the occlusion geometry; a stack that mixes both uses ``0`` for "no occlusion".
    """

    noise_sigma: Any = 0.0
    fov_radius: Any = math.inf
    fov_half_angle: Any = math.inf
    mask_p: Any = 0.0
    noise_key: Any = 0
    mask_key: Any = 0
    occluder_length: Any = None
    occluder_width: Any = None

    def as_arrays(self) -> ObservationParams:
        f32 = lambda v: None if v is None else jnp.asarray(v, jnp.float32)  # noqa: E731
        i32 = lambda v: jnp.asarray(v, jnp.int32)  # noqa: E731
        return ObservationParams(f32(self.noise_sigma), f32(self.fov_radius),
                                 f32(self.fov_half_angle), f32(self.mask_p),
                                 i32(self.noise_key), i32(self.mask_key),
                                 f32(self.occluder_length), f32(self.occluder_width))


def setting_params(setting: ObservationSetting | str) -> ObservationParams | None:
    """``setting`` as :class:`ObservationParams`, or ``None`` when one of its models has no
    such form (a :class:`FunctionModel`, two noise or two masking models)."""
    params: ObservationParams | None = ObservationParams()
    for i, m in enumerate(get_setting(setting).models):
        params = m.fold_params(params, i)
        if params is None:
            return None
    return params.as_arrays()


def stack_params(settings: list[ObservationParams]) -> ObservationParams:
    """Stack per-setting parameters on a leading axis (for ``vmap``)."""
    if any(p.occluder_length is not None for p in settings):
        zero = jnp.zeros((), jnp.float32)
        settings = [p if p.occluder_length is not None else
                    p.replace(occluder_length=zero, occluder_width=zero) for p in settings]
    return jax.tree.map(lambda *xs: jnp.stack(xs), *settings)


def _params_pose(p: ObservationParams, sdc_xy, sdc_yaw, episode_key, step_key):
    noise = jax.random.normal(jax.random.fold_in(episode_key, p.noise_key), (2,), jnp.float32)
    return sdc_xy + p.noise_sigma * noise, sdc_yaw


def _params_apply(p: ObservationParams, obs: Observation, episode_key, step_key) -> Observation:
    if p.occluder_length is not None:  # first, so that every object occludes
        keep_objects, keep_roadgraph = line_of_sight(obs, p.occluder_length, p.occluder_width)
        off = p.occluder_length <= 0
        obs = hide_roadgraph(hide_objects(obs, keep_objects | off), keep_roadgraph | off)

    def inside(xy):
        bearing = jnp.abs(jnp.arctan2(xy[..., 1], xy[..., 0]))
        return (jnp.sum(xy**2, axis=-1) <= p.fov_radius**2) & (bearing <= p.fov_half_angle)

    obs = _hide_outside(obs, inside)
    key = jax.random.fold_in(step_key, p.mask_key)
    hidden = jax.random.bernoulli(key, p.mask_p, obs.objects_valid.shape)
    return hide_objects(obs, ~hidden)


Setting = ObservationSetting | ObservationParams


def _model_keys(key: jax.Array, i: int) -> jax.Array:
    return jax.random.fold_in(key, i)


def perceive_pose(setting: Setting, sdc_xy: jax.Array, sdc_yaw: jax.Array,
                  episode_key: jax.Array, step_key: jax.Array) -> tuple[jax.Array, jax.Array]:
    """The ego's believed pose under ``setting`` (stage 1 of the pipeline)."""
    if isinstance(setting, ObservationParams):
        return _params_pose(setting, sdc_xy, sdc_yaw, episode_key, step_key)
    for i, m in enumerate(setting.models):
        sdc_xy, sdc_yaw = m.perceive_pose(sdc_xy, sdc_yaw, _model_keys(episode_key, i),
                                          _model_keys(step_key, i))
    return sdc_xy, sdc_yaw


def apply_setting(setting: Setting, obs: Observation, episode_key: jax.Array,
                  step_key: jax.Array) -> Observation:
    """The hiding of every model of ``setting``, in order (stage 2 of the pipeline)."""
    if isinstance(setting, ObservationParams):
        return _params_apply(setting, obs, episode_key, step_key)
    for i, m in enumerate(setting.models):
        obs = m.apply(obs, _model_keys(episode_key, i), _model_keys(step_key, i))
    return obs


# The paper's six settings (Table I columns, left to right).
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

# Panel titles as in the paper's Table I.
PRESET_TITLES: dict[str, str] = {
    "full": "Full obs",
    "gaussian_noise": "Gaussian noise (σ=3 m)",
    "circular_r4": "Circular FoV (r=4 m)",
    "circular_r6": "Circular FoV (r=6 m)",
    "conic_r4": "Conic FoV (r=4 m, α=2π/3)",
    "random_masking": "Random masking (p=0.7)",
}


PRESET_SHORT: dict[str, str] = {
    "full": "Full", "gaussian_noise": "Gauss σ=3", "circular_r4": "Circ r=4",
    "circular_r6": "Circ r=6", "conic_r4": "Conic r=4", "random_masking": "Mask p=.7",
}


def register_setting(setting: ObservationSetting, title: str | None = None,
                     short: str | None = None) -> ObservationSetting:
    """Add ``setting`` to the registry under its name: ``--obs NAME`` in every command, the
    pipeline's ``--obs`` and the tables' and figures' columns (``title`` and ``short`` label
    them; default: the name). Returns the setting."""
    if setting.name in PRESETS and PRESETS[setting.name] != setting:
        raise ConfigError(f"observation setting {setting.name!r} is already registered")
    PRESETS[setting.name] = setting
    PRESET_TITLES[setting.name] = title or setting.name
    PRESET_SHORT[setting.name] = short or title or setting.name
    return setting


def get_setting(spec: str | ObservationSetting) -> ObservationSetting:
    """A preset by name, or several composed with ``+`` (e.g. ``"gaussian_noise+circular_r4"``)."""
    if isinstance(spec, ObservationSetting):
        return spec
    names = [s.strip() for s in str(spec).split("+")]
    unknown = [n for n in names if n not in PRESETS]
    if unknown or not names:
        raise ConfigError(f"unknown observation setting {(unknown or [spec])[0]!r}; "
                          f"choose from {', '.join(PRESETS)} (compose with '+')")
    if len(names) == 1:
        return PRESETS[names[0]]
    models = tuple(m for n in names for m in PRESETS[n].models)
    return ObservationSetting("+".join(names), models)
