"""The driving policy: object encoder + PointNet roadgraph encoder -> MLP -> GRU -> 3x257 heads.

Two shapes of the same network, chosen by :class:`PolicyConfig`: the default pools the objects
(a per-object MLP, a max over objects) and the road points (one max over the set); the
original's (``object_encoder="flatten"``, ``roadgraph_pool="type"``, ``heads_see_features``;
the ``paper`` profile) flattens the objects, pools the points per road type and feeds the heads
the GRU output next to the encoded step.

The network sees one observation step at a time (memory lives in the GRU state). For training,
``unroll`` scans it over a sequence; ``reset`` flags zero the GRU state at every episode start
(the original code never reset it). Observations are any pytree with the fields of
``igdrivsim.observation.Observation``: ``objects [..., N_obj, F_obj]``, ``objects_valid
[..., N_obj]``, ``roadgraph [..., N_rg, F_rg]``, ``roadgraph_valid [..., N_rg]``,
``sdc_speed [..., 1]``, ``sdc_yaw_rate [..., 1]``.
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
    """Layer widths and the encoders' shape. The defaults are the original code's network
    (github clemgris/IGDrivSim, ``feature_extractor.py`` and ``rnn_policy.py``): objects
    flattened -> 512 -> 512; road points 8 -> 8 -> 8, a max per road type concatenated back,
    8 -> 8 -> 8, a max per type again, 20 x 8 -> 512; LayerNorm on both, 1024 -> 512 -> 512;
    GRU 512; actor [GRU, features] 1024 -> 512 -> 512 -> 512 -> 3 x 257; critic 1024 -> 256 ->
    256 -> 1: 4,255,611 parameters without the critic (the original's 4,255,099 and one ego
    speed input more), about 10.1 MFLOP forward per step at 32 objects and 1,500 road points.
    ``POOLED_NETWORK`` is the other shape (pooled objects and road set; the laptop profile)."""

    object_hidden: tuple[int, ...] = (512, 512)  # object encoder MLP
    # "flatten": the MLP on all objects' features flattened with the ego speed (the
    # original's); "pool": the MLP on each object, then a masked max over objects
    object_encoder: str = "flatten"
    point_hidden: tuple[int, ...] = (8, 8, 8)  # per-point MLP of the polyline encoder
    roadgraph_hidden: tuple[int, ...] = (8, 8, 8)  # after concatenating the pooled feature
    # "type": the points max-pooled per road type (20), broadcast back to the points of that
    # type, and the encoder's output is the 20 pooled features side by side (the original's);
    # "set": max-pooled over the whole set
    roadgraph_pool: str = "type"
    roadgraph_out: tuple[int, ...] = (512,)  # MLP after the pooled road feature
    trunk_hidden: tuple[int, ...] = (512, 512)  # MLP on [objects, roadgraph, sdc_speed]
    gru_hidden: int = 512
    actor_hidden: tuple[int, ...] = (512, 512, 512)
    value_hidden: tuple[int, ...] = (256, 256)
    # the actor and value heads read [GRU output, trunk output] (the original's) rather than
    # the GRU output alone
    heads_see_features: bool = True
    # a value head: None, the method decides (``RunConfig.validate``: only the methods that
    # drive learn values; a network built from an undecided config has one); without one the
    # network returns zeros as values
    value_head: bool | None = None
    num_bins: int = NUM_BINS
    remat: bool = False  # recompute per-step activations in the backward pass (saves memory)
    # the dx head scores offsets from the constant-velocity displacement (speed x 0.1 s, read
    # from the observed ego speed) instead of absolute levels: the same 257-level action space,
    # but "keep my speed" is one bias away instead of a regression from a scalar input
    relative_dx: bool = False
    # the ego speed feature (speed / 50) is multiplied by this before the trunk: at 1 a change
    # of one dx level (0.47 m/s) moves it by 0.01, too little for a small network to read
    speed_input_scale: float = 1.0
    # every object's features carry the ego speed next to the object's own speed, both times
    # ``speed_input_scale``, so the object encoder can form closing speeds before pooling
    # (after it, which object was closing is lost); False: the objects as observed
    object_ego_speed: bool = False
    # a second actor head on the same GRU output, trained by imitation only (ADVISOR's
    # auxiliary policy); the method decides (training/methods), acting never reads it
    aux_head: bool = False
    # the policy keeps its last H observed speeds in its recurrent carry and sees the last H
    # speed changes, in dx levels (0.47 m/s), next to the speed: the expert's next level
    # depends on them (it corrects its quantisation error), which a GRU fed the speed alone
    # does not pick up (paper/findings.tex, "The speed walk"); 0: off (the paper's network)
    speed_history: int = 0
    # the policy sees its last H observed yaw rates (the current one, and H - 1 kept in its
    # carry) in dyaw levels (2 pi / 256 rad per step): the expert's steering labels are a
    # quantisation walk too, its next level depending on its last ones, and a yaw rate is not
    # otherwise in view (the frame turns with the ego); 0: off (the paper's network)
    yaw_history: int = 0

    def __post_init__(self):
        if self.object_encoder not in OBJECT_ENCODERS:
            raise ConfigError(f"policy.object_encoder must be one of {OBJECT_ENCODERS}, got "
                              f"{self.object_encoder!r}")
        if self.roadgraph_pool not in ROADGRAPH_POOLS:
            raise ConfigError(f"policy.roadgraph_pool must be one of {ROADGRAPH_POOLS}, got "
                              f"{self.roadgraph_pool!r}")


OBJECT_ENCODERS = ("pool", "flatten")
ROADGRAPH_POOLS = ("set", "type")

# The other shape of the network: each object encoded then max-pooled, the road points
# max-pooled over the whole set, the heads on the GRU output alone (the laptop profile; with
# the widths 512 / 256-256 / 512-512 it was a 4.15M-parameter network of 1.42 GFLOP per step).
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


def road_types(points: jax.Array, valid: jax.Array) -> jax.Array:
    """Each point's road type ``int32[..., N]`` from the roadgraph feature's one-hot columns;
    ``RG_NUM_TYPES`` (no type) for invalid points."""
    kind = roadgraph_kind(points)
    return jnp.where(valid, kind, RG_NUM_TYPES).astype(jnp.int32)


def max_per_type(x: jax.Array, types: jax.Array) -> jax.Array:
    """Max of ``x [..., N, D]`` over the points of each road type (``types int[..., N]``, from
    :func:`road_types`): ``[..., RG_NUM_TYPES, D]``, zeros for a type with no point.

    One segment max over all sets at once (each set's types offset into its own segments):
    a scatter of N x D values, rather than a masked max over N x types x D."""
    lead, (n, d) = x.shape[:-2], x.shape[-2:]
    sets = math.prod(lead)
    slots = RG_NUM_TYPES + 1  # the last one collects the invalid points
    ids = (types.reshape(sets, n) + slots * jnp.arange(sets)[:, None]).reshape(-1)
    pooled = jax.ops.segment_max(x.reshape(-1, d), ids, num_segments=sets * slots)
    pooled = pooled.reshape(*lead, slots, d)[..., :RG_NUM_TYPES, :]
    return jnp.where(jnp.isfinite(pooled), pooled, 0.0)


def own_type(pooled: jax.Array, types: jax.Array) -> jax.Array:
    """Each point's row of ``pooled [..., T, F]`` (its road type's; zeros for no type):
    ``[..., N, F]``."""
    padded = jnp.concatenate([pooled, jnp.zeros_like(pooled[..., :1, :])], -2)
    return jnp.take_along_axis(padded, types[..., None], axis=-2)


class PolylineEncoder(nn.Module):
    """PointNet/MTR-style set encoder: per-point MLP, max-pool, concat back, MLP, max-pool.
    ``by_type``: the pools are per road type and the output is the types' features side by
    side, ``[..., 20 x D]`` (the original's)."""

    point_hidden: Sequence[int]
    hidden: Sequence[int]
    by_type: bool = False

    @nn.compact
    def __call__(self, points, valid):
        h = MLP(self.point_hidden)(points)
        if not self.by_type:
            h = PooledMLP(self.hidden, name="MLP_1")(h, masked_max(h, valid))
            return masked_max(h, valid)
        types = road_types(points, valid)
        h = PooledMLP(self.hidden, name="MLP_1")(h, max_per_type(h, types), types)
        pooled = max_per_type(h, types)
        return pooled.reshape(*pooled.shape[:-2], -1)


class PooledMLP(nn.Module):
    """An :class:`MLP` on ``[h, pooled]``, each point's feature ``h [..., N, D]`` next to its
    set's pooled feature ``pooled [..., D]``, without building the concatenation: the first
    layer is ``h @ W_h + pooled @ W_p``, the pooled half computed once per set rather than once
    per point (the same parameters and values as the concatenated form, half its cost). With
    ``types int[..., N]`` (:func:`road_types`), ``pooled [..., T, D]`` holds one feature per
    road type and each point gets its own type's."""

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
        if types is not None:  # per_set [..., T, F]: each point takes its type's row
            return per_point + own_type(per_set, types)
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
        """Per-step features fed to the GRU, ``[..., trunk_hidden[-1]]`` (``history``: the
        ego-motion history features of :func:`step_history`, ``None`` without one)."""
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

    def core(self, carry, x, reset):
        """The recurrent part: ``(carry, encoded x, reset) -> (carry, GRU output)``."""
        carry = jnp.where(jnp.expand_dims(reset, -1), jnp.zeros_like(carry), carry)
        return self.gru(carry, x)

    def _logits(self, mlp, out, y, sdc_speed):
        logits = dense_2d(out, mlp(y))
        logits = logits.reshape(*logits.shape[:-1], NUM_ACTION_DIMS, self.config.num_bins)
        if self.config.relative_dx:
            logits = logits.at[..., 0, :].set(relative_to_constant_velocity(
                logits[..., 0, :], sdc_speed[..., 0]))
        return logits

    def heads(self, y, sdc_speed=None):
        """Actor logits ``[..., 3, bins]``, value ``[...]`` (zeros without ``value_head``) and
        the auxiliary head's logits (``None`` without ``aux_head``) from the heads' inputs
        (:meth:`head_inputs`; ``sdc_speed [..., 1]``, the observed feature, is needed when
        ``relative_dx``)."""
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
        h, y = self.core(h, x, reset)
        logits, value, _ = self.heads(head_inputs(self.config, y, x), obs.sdc_speed)
        return jnp.concatenate([h, past], -1), logits, value


def head_inputs(config: PolicyConfig, y: jax.Array, x: jax.Array) -> jax.Array:
    """What the heads read: the GRU output ``y``, with the step's encoded features ``x`` beside
    it when ``heads_see_features``."""
    return jnp.concatenate([y, x], -1) if config.heads_see_features else y


def history_width(config: PolicyConfig) -> int:
    """Width of the ego-motion history in the carry: ``speed_history`` speeds, then
    ``yaw_history - 1`` yaw rates."""
    return config.speed_history + max(config.yaw_history - 1, 0)


def split_carry(config: PolicyConfig, carry: jax.Array) -> tuple[jax.Array, jax.Array]:
    """The GRU state ``[..., gru_hidden]`` and the ego-motion history ``[..., W]`` of a carry
    (:func:`history_width`; the observation's last speeds, then its last yaw rates, most recent
    first)."""
    return carry[..., :config.gru_hidden], carry[..., config.gru_hidden:]


def step_history(config: PolicyConfig, sdc_speed: jax.Array, sdc_yaw_rate: jax.Array,
                 past: jax.Array, reset: jax.Array) -> tuple[jax.Array | None, jax.Array]:
    """One step of the ego-motion history: the features the network sees (the last
    ``speed_history`` speed changes in dx levels, then the last ``yaw_history`` yaw rates in
    dyaw levels; ``None`` with neither) and the updated history ``past [..., W]``. At an
    episode start (``reset [...]``) the past is taken to equal the present: no change, a steady
    turn."""
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
    """The last ``H`` speed changes in dx levels, ``[now - previous, previous - the one
    before, ...]``, from the observed ``sdc_speed [..., 1]`` and the ``H`` previous ones
    ``past [..., H]`` (most recent first), and the updated ``past``."""
    level = DX_LEVEL / DT / SPEED_SCALE  # one dx level in the feature's units
    seq = jnp.concatenate([sdc_speed, past], -1)
    return (seq[..., :-1] - seq[..., 1:]) / level, seq[..., :-1]


def yaw_rate_levels(sdc_yaw_rate: jax.Array, past: jax.Array) -> tuple[jax.Array, jax.Array]:
    """The last ``H`` observed yaw rates in dyaw levels per step, ``[now, previous, ...]``,
    from ``sdc_yaw_rate [..., 1]`` (rad/s) and the ``H - 1`` previous ones ``past [..., H-1]``
    (most recent first), and the updated ``past``."""
    seq = jnp.concatenate([sdc_yaw_rate, past], -1)
    return seq * (DT / DYAW_LEVEL), seq[..., :-1]


def relative_to_constant_velocity(offset_logits: jax.Array, sdc_speed: jax.Array) -> jax.Array:
    """Absolute dx-level logits from logits over offsets: level ``b`` gets the score of offset
    index ``b - shift``, where ``shift`` is the constant-velocity displacement (``speed x
    0.1 s``, ``sdc_speed`` being the observation's ``speed / 50``) in levels; so the middle
    index scores the constant-velocity level. Levels with no offset index get -1e9."""
    bins = offset_logits.shape[-1]
    lead = offset_logits.shape[:-1]
    shift = jnp.broadcast_to(constant_speed_offset(sdc_speed * SPEED_SCALE), lead).reshape(-1)
    # offset index o scores level o + shift: o = middle (zero offset) is the constant-velocity
    # level middle + shift, since level ``middle`` is a zero displacement. Each row is a window
    # of the row padded with -1e9 (a sliced gather; an elementwise take_along_axis built index
    # arrays that cost a tenth of a BC-RL update on XLA:CPU).
    padded = jnp.pad(offset_logits.reshape(-1, bins), ((0, 0), (bins, bins)),
                     constant_values=-1e9)
    start = jnp.clip(bins - shift, 0, 2 * bins)
    rows = jax.vmap(lambda row, s: jax.lax.dynamic_slice(row, (s,), (bins,)))(padded, start)
    return rows.reshape(*lead, bins)


def initial_carry(config: PolicyConfig, batch_shape: tuple[int, ...] = ()) -> jax.Array:
    """The zero carry, ``[*batch_shape, gru_hidden + history_width]``: the GRU state, then
    the ego-motion history (:func:`split_carry`)."""
    return jnp.zeros((*batch_shape, config.gru_hidden + history_width(config)), jnp.float32)


def init_params(config: PolicyConfig, key: jax.Array, example_obs) -> dict:
    """Parameters for one seed (example_obs: one unbatched observation)."""
    model = DrivingPolicy(config)
    return model.init(key, initial_carry(config), example_obs, jnp.zeros((), bool))


_jit_init = jax.jit(init_params, static_argnums=0)


def init_params_per_seed(config: PolicyConfig, keys: jax.Array, example_obs) -> dict:
    """Parameters for each key, stacked on a leading seed axis.

    Seeds are initialised one by one and stacked (vmapping the orthogonal initialiser of the
    GRU was seen to hang).
    """
    per_seed = [_jit_init(config, k, example_obs) for k in keys]
    return jax.tree.map(lambda *xs: jnp.stack(xs), *per_seed)


def apply_step(config: PolicyConfig, params, carry, obs, reset):
    """Functional form of one step: ``(carry, logits, value)``."""
    return DrivingPolicy(config).apply(params, carry, obs, reset)


def unroll(config: PolicyConfig, params, carry, obs_seq, reset_seq):
    """Scan the policy over time; inputs ``[B, T, ...]`` -> ``(carry, logits [B,T,3,bins],
    values [B,T])``. ``reset_seq [B, T]`` zeroes the state before the flagged steps."""
    model = DrivingPolicy(config)

    def body(c, xs):
        obs, reset = xs
        c, logits, value = model.apply(params, c, obs, reset)
        return c, (logits, value)

    if config.remat:
        body = jax.checkpoint(body)
    time_major = jax.tree.map(lambda x: jnp.swapaxes(x, 0, 1), (obs_seq, reset_seq))
    carry, (logits, values) = jax.lax.scan(body, carry, time_major)
    return carry, jnp.swapaxes(logits, 0, 1), jnp.swapaxes(values, 0, 1)


def unroll_sequence(config: PolicyConfig, params, carry, obs_seq, reset_first: bool = True,
                    with_aux: bool = False):
    """Run the network over time-major observations ``[T, B, ...]``: ``(carry, logits
    [T, B, 3, bins], values [T, B])``, plus the auxiliary head's logits when ``with_aux``; the
    GRU state is zeroed before step 0 if ``reset_first``.

    The per-step encoders and the GRU's input projection do not depend on the recurrence, so
    they run once over all ``T x B`` observations (large matrix products) and only the
    recurrence is scanned (:func:`igdrivsim.core.nn.gru_scan`, the cell's equations with a
    hand-written gradient); the same values as stepping :func:`apply_step`, several times
    faster on CPU. With ``config.remat`` the encoders run one step at a time and are
    recomputed in the backward pass: their activation memory is one step's (the per-point
    features of 1,500 road points over 90 steps would not fit at the paper's batch).
    """
    model = DrivingPolicy(config)
    t = jax.tree.leaves(obs_seq)[0].shape[0]
    resets = jnp.zeros((t, *carry.shape[:-1]), bool).at[0].set(reset_first)
    h, past = split_carry(config, carry)
    changes = None
    if config.speed_history or config.yaw_history:  # every step's, before the network runs
        past, changes = jax.lax.scan(
            lambda p, xs: step_history(config, xs[0], xs[1], p, xs[2])[::-1], past,
            (obs_seq.sdc_speed, obs_seq.sdc_yaw_rate, resets))

    def heads(ys, speed):
        return model.apply(params, ys, speed, method=DrivingPolicy.heads)

    def encode(obs, ch):
        return model.apply(params, obs, ch, method=DrivingPolicy.encode)

    if config.remat:  # one step at a time, its activations recomputed in the backward pass
        x = jax.lax.map(jax.checkpoint(lambda xs: encode(*xs)), (obs_seq, changes))
    else:
        x = encode(obs_seq, changes)
    w_i, b_i, w_h, b_hn = fused_gru_cell(params["params"]["gru"])
    x_proj = (x.reshape(-1, x.shape[-1]) @ w_i + b_i).reshape(*x.shape[:-1], -1)
    h, ys = gru_scan(x_proj, resets, h, w_h, b_hn)
    logits, values, aux = heads(head_inputs(config, ys, x), obs_seq.sdc_speed)
    carry = jnp.concatenate([h, past], -1)
    return (carry, logits, values, aux) if with_aux else (carry, logits, values)


def count_params(params) -> int:
    """Number of scalar parameters (of one seed when given unstacked parameters)."""
    return int(sum(x.size for x in jax.tree.leaves(params)))
