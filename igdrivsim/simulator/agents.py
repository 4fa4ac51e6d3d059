"""Sim agents: who moves the objects other than the SDC (``SimParams.agents``).

``"log"`` (the paper's): every other object replays its log. ``"idm"``: reactive vehicles after
Waymax's ``IDMRoutePolicy``, each on its own logged path with its speed from the Intelligent
Driver Model, seeing the present only (docs/reactive.md describes the leader, lights, parked
and replayed objects). Pure JAX for ONE scenario, vectorised over agents x objects; the
simulator ``vmap``-s it over batch dimensions.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
from flax import struct

from igdrivsim.data.scenario import CURRENT_INDEX, DT, TYPE_VEHICLE
from igdrivsim.errors import ConfigError

AGENTS = ("log", "idm")
RED_LIGHT_STATES = (1, 4, 7)  # WOMD LANE_STATE_ARROW_STOP, LANE_STATE_STOP, FLASHING_STOP


@dataclass(frozen=True)
class IdmParams:
    """The IDM agents' parameters (Waymax ``IDMRoutePolicy`` defaults for the first six)."""

    desired_speed: float = 30.0  # m/s (v0)
    min_gap: float = 2.0  # m (s0)
    time_headway: float = 2.0  # s (T)
    max_accel: float = 2.0  # m/s^2 (a_max)
    comfort_decel: float = 4.0  # m/s^2 (b)
    exponent: float = 4.0  # (delta)
    lookahead: float = 20.0  # m beyond the desired gap s0 + v T at the agent's speed
    path_samples: int = 4  # chords of the path ahead the leader is searched along
    parked_distance: float = 1.0  # m: a vehicle whose log stays this close is parked
    max_agents: int = 32  # the moving vehicles nearest the SDC the IDM drives (others replay)

    def __post_init__(self):
        for name in ("desired_speed", "max_accel", "comfort_decel", "exponent", "lookahead"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"IdmParams.{name} must be positive, got {getattr(self, name)}")
        for name in ("min_gap", "time_headway", "parked_distance"):
            if not getattr(self, name) >= 0:
                raise ConfigError(f"IdmParams.{name} must be >= 0, got {getattr(self, name)}")
        for name in ("max_agents", "path_samples"):
            if getattr(self, name) < 1:
                raise ConfigError(f"IdmParams.{name} must be >= 1, got {getattr(self, name)}")


@struct.dataclass
class AgentState:
    """Every object's simulated trajectory ``[O, T]`` (``x`` .. ``valid``), which objects the
    IDM drives / holds still (``idm`` / ``parked`` ``[O]``), and per agent slot ``[N]``: its
    object ``slot`` (``slot_ok``: holds an agent), its logged path ``path_*`` ``[N, T]`` with
    arc length from step 10, the path's length and last pose, and ``arc`` / ``speed`` now."""

    x: jax.Array
    y: jax.Array
    yaw: jax.Array
    vel_x: jax.Array
    vel_y: jax.Array
    valid: jax.Array
    path_x: jax.Array
    path_y: jax.Array
    path_yaw: jax.Array
    path_arc: jax.Array
    path_end: jax.Array
    end_pose: jax.Array
    arc: jax.Array
    speed: jax.Array
    idm: jax.Array
    parked: jax.Array
    slot: jax.Array
    slot_ok: jax.Array


def _fill_forward(a, valid):
    """``a [O, T]``, each invalid step holding the last valid value (before any: the first)."""
    t = jnp.arange(a.shape[-1])
    idx = jax.lax.cummax(jnp.where(valid, t, -1), axis=a.ndim - 1)
    idx = jnp.where(idx < 0, jnp.argmax(valid, axis=-1)[..., None], idx)
    return jnp.take_along_axis(a, idx, axis=-1)


def boxes_overlap(ax, ay, al, aw, ayaw, bx, by, bl, bw, byaw):
    """Whether oriented boxes intersect with positive area (separating axes; broadcasting)."""
    dx, dy = bx - ax, by - ay
    ca, sa, cb, sb = jnp.cos(ayaw), jnp.sin(ayaw), jnp.cos(byaw), jnp.sin(byaw)
    c, s = jnp.abs(ca * cb + sa * sb), jnp.abs(ca * sb - sa * cb)
    hla, hwa, hlb, hwb = 0.5 * al, 0.5 * aw, 0.5 * bl, 0.5 * bw
    return ~((jnp.abs(dx * ca + dy * sa) >= hla + hlb * c + hwb * s)
             | (jnp.abs(-dx * sa + dy * ca) >= hwa + hlb * s + hwb * c)
             | (jnp.abs(dx * cb + dy * sb) >= hlb + hla * c + hwa * s)
             | (jnp.abs(-dx * sb + dy * cb) >= hwb + hla * s + hwa * c))


def init_agents(log, metadata, sdc_index, params: IdmParams) -> AgentState:
    """The agents at the current step (10) of ONE scenario (``log`` ``[O, T]``)."""
    o, t = log.x.shape
    c = CURRENT_INDEX
    valid = jnp.asarray(log.valid, bool)
    px, py, pyaw = (_fill_forward(a, valid) for a in (log.x, log.y, log.yaw))
    seg = jnp.hypot(jnp.diff(px, axis=-1), jnp.diff(py, axis=-1))
    seg = jnp.where(jnp.arange(1, t) > c, seg, 0.0)  # the path starts at step 10
    arc = jnp.concatenate([jnp.zeros((o, 1), seg.dtype), jnp.cumsum(seg, axis=-1)], axis=-1)
    last = jnp.max(jnp.where(valid, jnp.arange(t), 0), axis=-1)
    end = jnp.take_along_axis(arc, last[:, None], axis=-1)[:, 0]

    now = valid[:, c]
    others = jnp.arange(o) != sdc_index
    xs, ys, yaws = log.x[:, c], log.y[:, c], log.yaw[:, c]
    ls, ws = log.length[:, c], log.width[:, c]
    hit = boxes_overlap(xs[:, None], ys[:, None], ls[:, None], ws[:, None], yaws[:, None],
                       xs[None], ys[None], ls[None], ws[None], yaws[None])
    hit = hit & now[:, None] & now[None] & ~jnp.eye(o, dtype=bool)
    vehicle = (jnp.asarray(metadata.object_type) == TYPE_VEHICLE) & jnp.asarray(metadata.valid)
    controlled = vehicle & now & others & ~jnp.any(hit, axis=-1)
    future = valid & (jnp.arange(t) >= c)
    far = jnp.hypot(log.x - xs[:, None], log.y - ys[:, None]) > params.parked_distance
    parked = controlled & ~jnp.any(far & future, axis=-1)
    moving = controlled & ~parked
    d2 = (xs - xs[sdc_index]) ** 2 + (ys - ys[sdc_index]) ** 2
    key, slot = jax.lax.top_k(jnp.where(moving, -d2, -jnp.inf), min(params.max_agents, o))
    ok = jnp.isfinite(key)
    idm = jnp.zeros((o,), bool).at[slot].set(ok)
    speed = jnp.hypot(log.vel_x[slot, c], log.vel_y[slot, c])
    end_pose = jnp.stack([jnp.take_along_axis(v, last[:, None], axis=-1)[:, 0]
                          for v in (px, py, pyaw)], axis=-1)
    return AgentState(
        x=log.x, y=log.y, yaw=log.yaw, vel_x=log.vel_x, vel_y=log.vel_y, valid=valid,
        path_x=px[slot], path_y=py[slot], path_yaw=pyaw[slot], path_arc=arc[slot],
        path_end=end[slot], end_pose=end_pose[slot],
        arc=jnp.zeros(slot.shape, arc.dtype), speed=jnp.where(ok, speed, 0.0).astype(arc.dtype),
        idm=idm, parked=parked, slot=slot.astype(jnp.int32), slot_ok=ok)


def _on_path(a: AgentState, s):
    """Poses ``(x, y, yaw)`` at arc lengths ``s [N, K]`` along each agent's path (past its end,
    straight on); one gather per waypoint end (gathers are dear under ``vmap`` on XLA:CPU)."""
    arc = a.path_arc  # [O, T]
    t = arc.shape[-1]
    k = jnp.clip(jnp.sum(arc[:, None, 1:] <= s[..., None], axis=-1), 0, t - 2)  # [O, K]
    packed = jnp.stack([a.path_x, a.path_y, a.path_yaw, arc], axis=-1)  # [O, T, 4]
    w0 = jnp.take_along_axis(packed, k[..., None], axis=1)  # [O, K, 4]
    w1 = jnp.take_along_axis(packed, k[..., None] + 1, axis=1)
    x0, y0, yaw0, s0 = w0[..., 0], w0[..., 1], w0[..., 2], w0[..., 3]
    x1, y1, yaw1, s1 = w1[..., 0], w1[..., 1], w1[..., 2], w1[..., 3]
    u = jnp.clip((s - s0) / jnp.maximum(s1 - s0, 1e-6), 0.0, 1.0)
    dyaw = (yaw1 - yaw0 + jnp.pi) % (2 * jnp.pi) - jnp.pi
    x, y, yaw = x0 + u * (x1 - x0), y0 + u * (y1 - y0), yaw0 + u * dyaw
    # beyond the end: the last valid pose, then straight on along its heading
    end = a.path_end[:, None]
    ex, ey, eyaw = a.end_pose[:, 0:1], a.end_pose[:, 1:2], a.end_pose[:, 2:3]
    over = jnp.maximum(s - end, 0.0)
    past = s > end
    x = jnp.where(past, ex + over * jnp.cos(eyaw), x)
    y = jnp.where(past, ey + over * jnp.sin(eyaw), y)
    yaw = jnp.where(past, eyaw, yaw)
    return x, y, (yaw + jnp.pi) % (2 * jnp.pi) - jnp.pi


def _at(a, t):
    """``a[:, t]`` of ``[N, T]`` for a scalar step ``t``."""
    return jax.lax.dynamic_index_in_dim(a, t, axis=1, keepdims=False)


def leader_gaps(a: AgentState, objects, lights, t, params: IdmParams):
    """``(gap [N], lead_speed [N])``: bumper-to-bumper distance along its path from each agent
    to its leader or red light (``inf``: none within the lookahead) and the leader's speed along
    the agent's heading, from ``objects`` now ``[O]`` and ``lights`` ``[L, T]`` at step ``t``.
    One elementwise pass per chord of the path ahead (small reductions are slow under ``vmap``
    on XLA:CPU)."""
    p = params
    o = objects.x.shape[0]
    reach = p.lookahead + p.min_gap + a.speed * p.time_headway  # [N]
    fractions = jnp.linspace(0.0, 1.0, p.path_samples + 1)
    sx, sy, _ = _on_path(a, a.arc[:, None] + reach[:, None] * fractions[None])  # [O, K+1]
    hl_i = 0.5 * objects.length[a.slot][:, None]  # agents [N, 1]
    hw_i = 0.5 * objects.width[a.slot][:, None]
    cj, sj = jnp.cos(objects.yaw)[None], jnp.sin(objects.yaw)[None]  # objects [1, O]
    hl_j, hw_j = 0.5 * objects.length[None], 0.5 * objects.width[None]
    cand = objects.valid[None] & (jnp.arange(o)[None] != a.slot[:, None])  # [N, O]
    red = _at(lights.valid, t) & jnp.isin(_at(lights.state, t), jnp.asarray(RED_LIGHT_STATES))
    lx, ly = _at(lights.x, t)[None], _at(lights.y, t)[None]  # [1, L]
    n = a.slot.shape[0]
    obj_gap = jnp.full((n, o), jnp.inf)
    light_gap = jnp.full((n, lx.shape[-1]), jnp.inf)
    start = jnp.zeros((n, 1))
    for k in range(p.path_samples):
        ax, ay = sx[:, k:k + 1], sy[:, k:k + 1]
        dx, dy = sx[:, k + 1:k + 2] - ax, sy[:, k + 1:k + 2] - ay
        ln = jnp.maximum(jnp.sqrt(dx * dx + dy * dy), 1e-6)
        ux, uy = dx / ln, dy / ln

        def along(cx, cy, ax=ax, ay=ay, ux=ux, uy=uy, ln=ln, k=k, start=start):
            """Squared lateral distance to the chord, distance along the path, ahead."""
            rx, ry = cx - ax, cy - ay
            proj = rx * ux + ry * uy
            u = jnp.clip(proj, 0.0, ln)
            qx, qy = rx - u * ux, ry - u * uy
            return qx * qx + qy * qy, start + u, (proj > 0) if k == 0 else True

        lat2, dist, ahead = along(objects.x[None], objects.y[None])
        cos_rel = jnp.abs(cj * ux + sj * uy)
        sin_rel = jnp.abs(sj * ux - cj * uy)
        room = hw_i + hl_j * sin_rel + hw_j * cos_rel  # the box within the swept width
        gap = dist - (hl_j * cos_rel + hw_j * sin_rel) - hl_i
        on = cand & (lat2 < room * room) & ahead & (dist <= reach[:, None])
        obj_gap = jnp.minimum(obj_gap, jnp.where(on, gap, jnp.inf))
        lat2, dist, ahead = along(lx, ly)
        lgap = dist - hl_i
        lon = red[None] & (lat2 < hw_i * hw_i) & ahead & (lgap > 0) & (dist <= reach[:, None])
        light_gap = jnp.minimum(light_gap, jnp.where(lon, lgap, jnp.inf))
        start = start + ln
    j = jnp.argmin(obj_gap, axis=-1)
    gap = jnp.min(obj_gap, axis=-1)
    yaw_i = _at(a.yaw, t)[a.slot]
    lead_v = jnp.maximum(objects.vel_x[j] * jnp.cos(yaw_i) + objects.vel_y[j] * jnp.sin(yaw_i), 0.0)
    light = jnp.min(light_gap, axis=-1)
    use_light = light < gap
    return (jnp.where(use_light, light, gap),
            jnp.where(use_light | ~jnp.isfinite(gap), 0.0, lead_v))


def idm_accel(v, gap, lead_v, params: IdmParams):
    """The IDM acceleration ``[N]`` (``gap`` ``inf``: free road)."""
    p = params
    dv = v - lead_v
    desired = p.min_gap + jnp.maximum(0.0, v * p.time_headway
                                      + v * dv / (2.0 * jnp.sqrt(p.max_accel * p.comfort_decel)))
    free = 1.0 - (v / p.desired_speed) ** p.exponent
    interact = jnp.where(jnp.isfinite(gap), (desired / jnp.maximum(gap, 1e-3)) ** 2, 0.0)
    return p.max_accel * (free - interact)


def step_agents(a: AgentState, objects, lights, t, params: IdmParams) -> AgentState:
    """Advance the agents of ONE scenario from step ``t`` to ``t + 1``, from the objects now."""
    gap, lead_v = leader_gaps(a, objects, lights, t, params)
    acc = idm_accel(a.speed, gap, lead_v, params)
    acc = jnp.where(a.arc >= a.path_end, jnp.minimum(acc, -params.comfort_decel), acc)
    v1 = jnp.maximum(a.speed + acc * DT, 0.0)
    arc1 = a.arc + 0.5 * (a.speed + v1) * DT
    arc1 = jnp.where(a.slot_ok, arc1, a.arc)
    v1 = jnp.where(a.slot_ok, v1, 0.0)
    x, y, yaw = (q[:, 0] for q in _on_path(a, arc1[:, None]))
    t1 = jnp.minimum(t + 1, a.x.shape[-1] - 1)

    def put(old, new, still):
        """Column ``t1`` of ``old [O, T]``: the agents' ``new [N]``, the parked ``still``."""
        col = _at(old, t1)
        col = col.at[a.slot].set(jnp.where(a.slot_ok, jnp.asarray(new, old.dtype), col[a.slot]))
        col = jnp.where(a.parked, jnp.asarray(still, old.dtype), col)  # the pose at step 10
        return jax.lax.dynamic_update_index_in_dim(old, col, t1, axis=1)

    c = CURRENT_INDEX
    return a.replace(x=put(a.x, x, a.x[:, c]), y=put(a.y, y, a.y[:, c]),
                     yaw=put(a.yaw, yaw, a.yaw[:, c]), vel_x=put(a.vel_x, v1 * jnp.cos(yaw), 0.0),
                     vel_y=put(a.vel_y, v1 * jnp.sin(yaw), 0.0), valid=put(a.valid, True, True),
                     arc=arc1, speed=v1.astype(a.speed.dtype))
