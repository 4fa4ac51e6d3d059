"""The driving policy: object encoder + PointNet roadgraph encoder -> MLP -> GRU -> 3x257 heads.

Two shapes (:class:`PolicyConfig`): the original's (objects flattened, road points pooled per
road type, the heads reading the GRU output next to the encoded step; the ``paper`` profile) and
:data:`POOLED_NETWORK` (objects and road points max-pooled). The network sees one step at a time
(memory lives in the GRU state, zeroed at every episode start by ``reset`` flags, which the
original code never did); :func:`unroll_sequence` runs it over time.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import flax.linen as nn
import jax
import jax.numpy as jnp

from igdrivsim.core.nn import dense_2d, fused_gru_cell, gru_scan
from igdrivsim.data.scenario import DT, RG_NUM_TYPES
from igdrivsim.errors import ConfigError
from igdrivsim.observation.features import OBJECT_SPEED, SPEED_SCALE, roadgraph_kind
from igdrivsim.simulator.dynamics import DX_LEVEL, DYAW_LEVEL, constant_speed_offset

NUM_BINS = 257  # 256 bins per action dimension, 257 levels from min to max inclusive
NUM_ACTION_DIMS = 3  # dx, dy, dyaw (delta-local)


@dataclass(frozen=True)
class PolicyConfig:
    """Layer widths and the encoders' shape; the defaults are the original code's network
    (github clemgris/IGDrivSim, ``feature_extractor.py`` and ``rnn_policy.py``) with one ego
    speed input more."""

    object_hidden: tuple[int, ...] = (512, 512)  # object encoder MLP
    # "flatten": the MLP on all objects flattened with the ego speed (the original's); "pool":
    # the MLP on each object, then a masked max
    object_encoder: str = "flatten"
    point_hidden: tuple[int, ...] = (8, 8, 8)  # per-point MLP of the polyline encoder
    roadgraph_hidden: tuple[int, ...] = (8, 8, 8)  # after concatenating the pooled feature
    # "type": max-pooled per road type, the 20 types' features side by side (the original's);
    # "set": max-pooled over the whole set
    roadgraph_pool: str = "type"
    roadgraph_out: tuple[int, ...] = (512,)  # MLP after the pooled road feature
    trunk_hidden: tuple[int, ...] = (512, 512)  # MLP on [objects, roadgraph, sdc_speed]
    gru_hidden: int = 512
    actor_hidden: tuple[int, ...] = (512, 512, 512)
    value_hidden: tuple[int, ...] = (256, 256)
    heads_see_features: bool = True  # the heads read [GRU output, trunk output] (the original's)
    # a value head (None: the method decides, else one); without one the values are zeros
    value_head: bool | None = None
    num_bins: int = NUM_BINS
    remat: bool = False  # recompute per-step activations in the backward pass (saves memory)
    # the dx head scores offsets from the constant-velocity level ("keep my speed" is one bias)
    relative_dx: bool = False
    # the ego speed feature (speed / 50) times this before the trunk
    speed_input_scale: float = 1.0
    # every object's features carry the scaled ego speed too (closing speeds before pooling)
    object_ego_speed: bool = False
    # a second actor head trained by imitation only (ADVISOR's auxiliary policy)
    aux_head: bool = False
    # the last H speed changes in dx levels, from speeds kept in the carry (paper/findings.tex,
    # "The speed walk"); 0: off
    speed_history: int = 0
    # the last H observed yaw rates in dyaw levels (H - 1 kept in the carry); 0: off
    yaw_history: int = 0

    def __post_init__(self):
        for name, choices in (("object_encoder", OBJECT_ENCODERS),
                              ("roadgraph_pool", ROADGRAPH_POOLS)):
            if getattr(self, name) not in choices:
                raise ConfigError(f"policy.{name} must be one of {choices}, got "
                                  f"{getattr(self, name)!r}")


OBJECT_ENCODERS = ("pool", "flatten")
ROADGRAPH_POOLS = ("set", "type")

# The other shape: objects encoded then max-pooled, the road points max-pooled over the set,
# the heads on the GRU output alone (the laptop profile).
POOLED_NETWORK = dict(object_encoder="pool", roadgraph_pool="set", roadgraph_out=(),
                      heads_see_features=False)


class MLP(nn.Module):
    """Dense + ReLU stack (ReLU after every layer)."""

    features: Sequence[int]

    @nn.compact
    def __call__(self, x):
        for width in self.features:
            x = nn.relu(dense_2d(nn.Dense(width), x))
        return x


def masked_max(x: jax.Array, valid: jax.Array, axis: int = -2) -> jax.Array:
    """Max over ``axis`` of the valid entries; zeros where no entry is valid."""
    valid = jnp.expand_dims(valid, -1)
    pooled = jnp.max(jnp.where(valid, x, -jnp.inf), axis=axis)
    return jnp.where(jnp.any(valid, axis=axis), pooled, 0.0)


def max_per_type(x: jax.Array, types: jax.Array) -> jax.Array:
    """Max of ``x [..., N, D]`` over the points of each road type: ``[..., RG_NUM_TYPES, D]``,
    zeros for a type with no point (one segment max over all sets at once)."""
    lead, (n, d) = x.shape[:-2], x.shape[-2:]
    sets = math.prod(lead)
    slots = RG_NUM_TYPES + 1  # the last one collects the invalid points
    ids = (types.reshape(sets, n) + slots * jnp.arange(sets)[:, None]).reshape(-1)
    pooled = jax.ops.segment_max(x.reshape(-1, d), ids, num_segments=sets * slots)
    pooled = pooled.reshape(*lead, slots, d)[..., :RG_NUM_TYPES, :]
    return jnp.where(jnp.isfinite(pooled), pooled, 0.0)


class PolylineEncoder(nn.Module):
    """PointNet/MTR-style set encoder: per-point MLP, max-pool, concat back, MLP, max-pool
    (``by_type``: per road type, the types' features side by side)."""

    point_hidden: Sequence[int]
    hidden: Sequence[int]
    by_type: bool = False

    @nn.compact
    def __call__(self, points, valid):
        h = MLP(self.point_hidden)(points)
        if not self.by_type:
            h = PooledMLP(self.hidden, name="MLP_1")(h, masked_max(h, valid))
            return masked_max(h, valid)
        types = jnp.where(valid, roadgraph_kind(points), RG_NUM_TYPES).astype(jnp.int32)
        h = PooledMLP(self.hidden, name="MLP_1")(h, max_per_type(h, types), types)
        pooled = max_per_type(h, types)
        return pooled.reshape(*pooled.shape[:-2], -1)


class PooledMLP(nn.Module):
    """An :class:`MLP` on ``[h, pooled]`` (each point next to its set's, or with ``types`` its
    road type's, pooled feature) with the first layer ``h @ W_h + pooled @ W_p``: the pooled
    half once per set, the same values as the concatenation at half its cost."""

    features: Sequence[int]

    @nn.compact
    def __call__(self, h, pooled, types=None):
        x = nn.relu(_SplitDense(self.features[0], name="Dense_0")(h, pooled, types))
        for i, width in enumerate(self.features[1:], start=1):
            x = nn.relu(dense_2d(nn.Dense(width, name=f"Dense_{i}"), x))
        return x


class _SplitDense(nn.Module):
    """``nn.Dense`` on ``concatenate([h, broadcast(pooled)])``, computed in two parts."""

    features: int

    @nn.compact
    def __call__(self, h, pooled, types=None):
        d = h.shape[-1]
        kernel = self.param("kernel", nn.initializers.lecun_normal(),
                            (d + pooled.shape[-1], self.features))
        bias = self.param("bias", nn.initializers.zeros_init(), (self.features,))
        per_set = pooled @ kernel[d:] + bias
        per_point = (h.reshape(-1, d) @ kernel[:d]).reshape(*h.shape[:-1], -1)
        if types is not None:  # per_set [..., T, F]: each point takes its type's row (or zeros)
            padded = jnp.concatenate([per_set, jnp.zeros_like(per_set[..., :1, :])], -2)
            return per_point + jnp.take_along_axis(padded, types[..., None], axis=-2)
        return per_point + per_set[..., None, :]


class DrivingPolicy(nn.Module):
    """One recurrent step: ``(carry, obs, reset) -> (carry, logits [..., 3, bins], value)``."""

    config: PolicyConfig

    def setup(self):
        c = self.config
        self.object_mlp = MLP(c.object_hidden)
        self.object_norm = nn.LayerNorm()
        self.roadgraph_encoder = PolylineEncoder(c.point_hidden, c.roadgraph_hidden,
                                                 by_type=c.roadgraph_pool == "type")
        if c.roadgraph_out:
            self.roadgraph_out = MLP(c.roadgraph_out)
        self.roadgraph_norm = nn.LayerNorm()
        self.trunk = MLP(c.trunk_hidden)
        self.gru = nn.GRUCell(features=c.gru_hidden)
        self.actor_mlp = MLP(c.actor_hidden)
        self.actor_out = nn.Dense(NUM_ACTION_DIMS * c.num_bins)
        if c.value_head is not False:
            self.value_mlp = MLP(c.value_hidden)
            self.value_out = nn.Dense(1)
        if c.aux_head:
            self.aux_mlp = MLP(c.actor_hidden)
            self.aux_out = nn.Dense(NUM_ACTION_DIMS * c.num_bins)

    def encode(self, obs, history=None):
        """Per-step features fed to the GRU (``history``: :func:`step_history`'s features)."""
        objects = obs.objects
        if self.config.object_ego_speed:
            k = self.config.speed_input_scale
            ego = jnp.broadcast_to(obs.sdc_speed[..., None, :], (*objects.shape[:-1], 1))
            objects = jnp.concatenate([objects.at[..., OBJECT_SPEED].multiply(k), ego * k], -1)
        if self.config.object_encoder == "flatten":
            flat = objects.reshape(*objects.shape[:-2], -1)
            objects = self.object_mlp(jnp.concatenate([flat, obs.sdc_speed], -1))
        else:
            objects = masked_max(self.object_mlp(objects), obs.objects_valid)
        roads = self.roadgraph_encoder(obs.roadgraph, obs.roadgraph_valid)
        if self.config.roadgraph_out:
            roads = self.roadgraph_out(roads)
        parts = [self.object_norm(objects), self.roadgraph_norm(roads),
                 obs.sdc_speed * self.config.speed_input_scale]
        if history is not None:
            parts.append(history)
        return self.trunk(jnp.concatenate(parts, axis=-1))

    def _logits(self, mlp, out, y, sdc_speed):
        logits = dense_2d(out, mlp(y))
        logits = logits.reshape(*logits.shape[:-1], NUM_ACTION_DIMS, self.config.num_bins)
        if self.config.relative_dx:
            logits = logits.at[..., 0, :].set(relative_to_constant_velocity(
                logits[..., 0, :], sdc_speed[..., 0]))
        return logits

    def heads(self, y, sdc_speed=None):
        """Actor logits ``[..., 3, bins]``, value ``[...]`` and the auxiliary logits (or ``None``)
        from :func:`head_inputs` (``sdc_speed``: needed when ``relative_dx``)."""
        logits = self._logits(self.actor_mlp, self.actor_out, y, sdc_speed)
        aux = (self._logits(self.aux_mlp, self.aux_out, y, sdc_speed)
               if self.config.aux_head else None)
        value = (dense_2d(self.value_out, self.value_mlp(y))[..., 0]
                 if self.config.value_head is not False else jnp.zeros(y.shape[:-1], y.dtype))
        return logits, value, aux

    def __call__(self, carry, obs, reset):
        h, past = split_carry(self.config, carry)
        history, past = step_history(self.config, obs.sdc_speed, obs.sdc_yaw_rate, past, reset)
        x = self.encode(obs, history)
        h = jnp.where(jnp.expand_dims(reset, -1), jnp.zeros_like(h), h)
        h, y = self.gru(h, x)
        logits, value, _ = self.heads(head_inputs(self.config, y, x), obs.sdc_speed)
        return jnp.concatenate([h, past], -1), logits, value


def head_inputs(config: PolicyConfig, y: jax.Array, x: jax.Array) -> jax.Array:
    """What the heads read: the GRU output, with the encoded step beside it if configured."""
    return jnp.concatenate([y, x], -1) if config.heads_see_features else y


def split_carry(config: PolicyConfig, carry: jax.Array) -> tuple[jax.Array, jax.Array]:
    """The GRU state and the ego-motion history (last speeds, then yaw rates) of a carry."""
    return carry[..., :config.gru_hidden], carry[..., config.gru_hidden:]


def step_history(config: PolicyConfig, sdc_speed: jax.Array, sdc_yaw_rate: jax.Array,
                 past: jax.Array, reset: jax.Array) -> tuple[jax.Array | None, jax.Array]:
    """One step of the ego-motion history: the features the network sees (speed changes, then
    yaw rates, in levels; ``None`` with neither) and the updated ``past``; at an episode start
    the past equals the present."""
    hs = config.speed_history
    start = jnp.expand_dims(reset, -1)
    speeds = jnp.where(start, sdc_speed, past[..., :hs])
    yaws = jnp.where(start, sdc_yaw_rate, past[..., hs:])
    features = []
    if hs:
        changes, speeds = speed_changes(sdc_speed, speeds)
        features.append(changes)
    if config.yaw_history:
        levels, yaws = yaw_rate_levels(sdc_yaw_rate, yaws)
        features.append(levels)
    history = jnp.concatenate(features, -1) if features else None
    return history, jnp.concatenate([speeds, yaws], -1)


def speed_changes(sdc_speed: jax.Array, past: jax.Array) -> tuple[jax.Array, jax.Array]:
    """The last ``H`` speed changes in dx levels (most recent first) from ``sdc_speed [..., 1]``
    and the ``H`` previous speeds ``past``, and the updated ``past``."""
    level = DX_LEVEL / DT / SPEED_SCALE  # one dx level in the feature's units
    seq = jnp.concatenate([sdc_speed, past], -1)
    return (seq[..., :-1] - seq[..., 1:]) / level, seq[..., :-1]


def yaw_rate_levels(sdc_yaw_rate: jax.Array, past: jax.Array) -> tuple[jax.Array, jax.Array]:
    """The last ``H`` yaw rates in dyaw levels per step (most recent first) from
    ``sdc_yaw_rate [..., 1]`` (rad/s) and the ``H - 1`` previous ones, and the updated ``past``."""
    seq = jnp.concatenate([sdc_yaw_rate, past], -1)
    return seq * (DT / DYAW_LEVEL), seq[..., :-1]


def relative_to_constant_velocity(offset_logits: jax.Array, sdc_speed: jax.Array) -> jax.Array:
    """Absolute dx-level logits from logits over offsets from the constant-velocity level (the
    middle index scores it); levels with no offset index get -1e9."""
    bins = offset_logits.shape[-1]
    lead = offset_logits.shape[:-1]
    shift = jnp.broadcast_to(constant_speed_offset(sdc_speed * SPEED_SCALE), lead).reshape(-1)
    # each row is a window of the row padded with -1e9 (a sliced gather: take_along_axis cost a
    # tenth of a BC-RL update on XLA:CPU)
    padded = jnp.pad(offset_logits.reshape(-1, bins), ((0, 0), (bins, bins)),
                     constant_values=-1e9)
    start = jnp.clip(bins - shift, 0, 2 * bins)
    rows = jax.vmap(lambda row, s: jax.lax.dynamic_slice(row, (s,), (bins,)))(padded, start)
    return rows.reshape(*lead, bins)


def initial_carry(config: PolicyConfig, batch_shape: tuple[int, ...] = ()) -> jax.Array:
    """The zero carry ``[*batch_shape, gru_hidden + H]``: the GRU state, then the ego-motion
    history (``H``: ``speed_history`` speeds, then ``yaw_history - 1`` yaw rates)."""
    history = config.speed_history + max(config.yaw_history - 1, 0)
    return jnp.zeros((*batch_shape, config.gru_hidden + history), jnp.float32)


def init_params(config: PolicyConfig, key: jax.Array, example_obs) -> dict:
    """Parameters for one seed (example_obs: one unbatched observation)."""
    model = DrivingPolicy(config)
    return model.init(key, initial_carry(config), example_obs, jnp.zeros((), bool))


_jit_init = jax.jit(init_params, static_argnums=0)


def init_params_per_seed(config: PolicyConfig, keys: jax.Array, example_obs) -> dict:
    """Parameters for each key, stacked on a leading seed axis (one by one: vmapping the GRU's
    orthogonal initialiser was seen to hang)."""
    per_seed = [_jit_init(config, k, example_obs) for k in keys]
    return jax.tree.map(lambda *xs: jnp.stack(xs), *per_seed)


def apply_step(config: PolicyConfig, params, carry, obs, reset):
    """Functional form of one step: ``(carry, logits, value)``."""
    return DrivingPolicy(config).apply(params, carry, obs, reset)


def unroll_sequence(config: PolicyConfig, params, carry, obs_seq, with_aux: bool = False):
    """Run the network over time-major observations ``[T, B, ...]``: ``(carry, logits
    [T, B, 3, bins], values [T, B])`` (and the auxiliary logits when ``with_aux``), the GRU
    state zeroed before step 0. The values of stepping :func:`apply_step`, faster: the
    encoders run once over all ``T x B`` steps and only the recurrence is scanned."""
    model = DrivingPolicy(config)
    t = jax.tree.leaves(obs_seq)[0].shape[0]
    resets = jnp.zeros((t, *carry.shape[:-1]), bool).at[0].set(True)
    h, past = split_carry(config, carry)
    changes = None
    if config.speed_history or config.yaw_history:  # every step's, before the network runs
        past, changes = jax.lax.scan(
            lambda p, xs: step_history(config, xs[0], xs[1], p, xs[2])[::-1], past,
            (obs_seq.sdc_speed, obs_seq.sdc_yaw_rate, resets))

    def encode(obs, ch):
        return model.apply(params, obs, ch, method=DrivingPolicy.encode)

    if config.remat:  # one step at a time, its activations recomputed in the backward pass
        x = jax.lax.map(jax.checkpoint(lambda xs: encode(*xs)), (obs_seq, changes))
    else:
        x = encode(obs_seq, changes)
    w_i, b_i, w_h, b_hn = fused_gru_cell(params["params"]["gru"])
    x_proj = (x.reshape(-1, x.shape[-1]) @ w_i + b_i).reshape(*x.shape[:-1], -1)
    h, ys = gru_scan(x_proj, resets, h, w_h, b_hn)
    logits, values, aux = model.apply(params, head_inputs(config, ys, x), obs_seq.sdc_speed,
                                      method=DrivingPolicy.heads)
    carry = jnp.concatenate([h, past], -1)
    return (carry, logits, values, aux) if with_aux else (carry, logits, values)


def count_params(params) -> int:
    """Number of scalar parameters (of one seed when given unstacked parameters)."""
    return int(sum(x.size for x in jax.tree.leaves(params)))
