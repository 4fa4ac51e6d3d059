"""Sim agents: who moves the objects other than the SDC (``SimParams.agents``).

* ``"log"`` (the default and the paper's setting): every other object replays its log.
* ``"idm"``: reactive traffic after Waymax's ``IDMRoutePolicy``. Each *vehicle* other than the
  SDC, valid at the current step (10), follows its own logged path: its position is a point of
  the logged polyline at arc length ``s`` and its heading the logged heading there (interpolated
  between waypoints), so it never leaves the path sideways; only its speed is controlled, by the
  Intelligent Driver Model::

      a = a_max [1 - (v / v0)^delta - (s* / gap)^2]
      s* = s0 + max(0, v T + v dv / (2 sqrt(a_max b)))

  with ``dv = v - v_lead``. The leader is the nearest object (the SDC included, at its simulated
  pose) whose box comes within half the agent's width of the path ahead (the agent's box swept
  along its path), over a lookahead of ``lookahead + s0 + v T`` metres (always longer than the
  desired gap; Waymax's 10 m missed stopped cars, its issue #52); the path ahead is sampled at
  ``path_samples`` chords. The leader's speed is its velocity projected on the agent's heading
  (at least 0). The stop point of a traffic light that is red now (WOMD states 1, 4, 7: arrow
  stop, stop, flashing stop) on the path ahead is a stopped leader of zero length, so agents stop
  before the line. Past the end of its log an agent keeps its last heading and brakes at
  ``comfort_decel`` (it stays valid and does not vanish).

Left on log replay: pedestrians, cyclists and other non-vehicles (Waymax's issue #71), objects
not valid at step 10, and vehicles whose box overlaps another object's at step 10 (articulated
vehicles, nuPlan #421). Parked vehicles (every valid logged position from step 10 on within
``parked_distance`` of the one at step 10) stay where they are, valid, at zero speed (a comment
in Waymax's code notes its parked cars drive off).

The agents see the present only (positions, speeds, lights now); the logged future gives only
each agent's own path, as in Waymax. Everything is pure JAX, vectorised over agents (pairwise
agent x object x chord arrays, no Python loop over objects), for ONE scenario; the simulator
``vmap``-s it over batch dimensions.
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
    """The IDM agents' parameters (Waymax ``IDMRoutePolicy`` defaults for the first six).

    ``desired_speed`` is Waymax's 30 m/s whatever the log's speed: a free agent accelerates
    towards it along its path (and so may run ahead of its log); lower it for urban traffic.
    """

    desired_speed: float = 30.0  # m/s (v0)
    min_gap: float = 2.0  # m (s0)
    time_headway: float = 2.0  # s (T)
    max_accel: float = 2.0  # m/s^2 (a_max)
    comfort_decel: float = 4.0  # m/s^2 (b)
    exponent: float = 4.0  # (delta)
    lookahead: float = 20.0  # m beyond the desired gap s0 + v T at the agent's speed
    path_samples: int = 4  # chords of the path ahead the leader is searched along
    parked_distance: float = 1.0  # m: a vehicle whose log stays this close is parked

    def __post_init__(self):
        for name in ("desired_speed", "max_accel", "comfort_decel", "exponent", "lookahead"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"IdmParams.{name} must be positive, got {getattr(self, name)}")
        for name in ("min_gap", "time_headway", "parked_distance"):
            if not getattr(self, name) >= 0:
                raise ConfigError(f"IdmParams.{name} must be >= 0, got {getattr(self, name)}")
        if self.path_samples < 1:
            raise ConfigError(f"IdmParams.path_samples must be >= 1, got {self.path_samples}")


def check_agents(name: str) -> None:
    if name not in AGENTS:
        raise ConfigError(f"sim agents must be one of {', '.join(AGENTS)}, got {name!r}")


@struct.dataclass
class AgentState:
    """Every object's simulated trajectory and the IDM agents' own state (one scenario).

    ``x, y, yaw, vel_x, vel_y, valid`` ``[O, T]``: the log up to the current step and for the
    objects left on replay; the agents' simulated states after step 10. ``path_*`` ``[O, T]``:
    each object's logged path (invalid steps filled with the last valid pose) and its arc length
    from step 10 (constant). ``arc``, ``speed`` ``[O]``: where each agent is on its path and
    its speed. ``idm`` / ``parked`` ``[O]``: which objects the IDM drives / holds still.
    """

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
    arc: jax.Array
    speed: jax.Array
    idm: jax.Array
    parked: jax.Array


def _fill_forward(a, valid):
    """``a [O, T]`` with each invalid step holding the last valid value (the first valid one
    before any)."""
    t = jnp.arange(a.shape[-1])
    idx = jax.lax.cummax(jnp.where(valid, t, -1), axis=a.ndim - 1)
    idx = jnp.where(idx < 0, jnp.argmax(valid, axis=-1)[..., None], idx)
    return jnp.take_along_axis(a, idx, axis=-1)


def _box_overlap(ax, ay, al, aw, ayaw, bx, by, bl, bw, byaw):
    """Separating-axis overlap of oriented boxes (broadcasting), positive area only."""
    dx, dy = bx - ax, by - ay
    ca, sa, cb, sb = jnp.cos(ayaw), jnp.sin(ayaw), jnp.cos(byaw), jnp.sin(byaw)
    c, s = jnp.abs(ca * cb + sa * sb), jnp.abs(ca * sb - sa * cb)
    hla, hwa, hlb, hwb = 0.5 * al, 0.5 * aw, 0.5 * bl, 0.5 * bw
    return ~((jnp.abs(dx * ca + dy * sa) >= hla + hlb * c + hwb * s)
             | (jnp.abs(-dx * sa + dy * ca) >= hwa + hlb * s + hwb * c)
             | (jnp.abs(dx * cb + dy * sb) >= hlb + hla * c + hwa * s)
             | (jnp.abs(-dx * sb + dy * cb) >= hwb + hla * s + hwa * c))


def init_agents(log, metadata, sdc_index, params: IdmParams) -> AgentState:
    """The agents at the current step (10) of ONE scenario: ``log`` a ``Trajectory [O, T]``,
    ``metadata`` ``[O]``, ``sdc_index`` a scalar."""
    o, t = log.x.shape
    c = CURRENT_INDEX
    valid = jnp.asarray(log.valid, bool)
    px, py = _fill_forward(log.x, valid), _fill_forward(log.y, valid)
    pyaw = _fill_forward(log.yaw, valid)
    seg = jnp.hypot(jnp.diff(px, axis=-1), jnp.diff(py, axis=-1))
    seg = jnp.where(jnp.arange(1, t) > c, seg, 0.0)  # the path starts at step 10
    arc = jnp.concatenate([jnp.zeros((o, 1), seg.dtype), jnp.cumsum(seg, axis=-1)], axis=-1)
    last = jnp.max(jnp.where(valid, jnp.arange(t), 0), axis=-1)
    end = jnp.take_along_axis(arc, last[:, None], axis=-1)[:, 0]

    now = valid[:, c]
    others = jnp.arange(o) != sdc_index
    xs, ys, yaws = log.x[:, c], log.y[:, c], log.yaw[:, c]
    ls, ws = log.length[:, c], log.width[:, c]
    hit = _box_overlap(xs[:, None], ys[:, None], ls[:, None], ws[:, None], yaws[:, None],
                       xs[None], ys[None], ls[None], ws[None], yaws[None])
    hit = hit & now[:, None] & now[None] & ~jnp.eye(o, dtype=bool)
    vehicle = (jnp.asarray(metadata.object_type) == TYPE_VEHICLE) & jnp.asarray(metadata.valid)
    controlled = vehicle & now & others & ~jnp.any(hit, axis=-1)
    future = valid & (jnp.arange(t) >= c)
    far = jnp.hypot(log.x - xs[:, None], log.y - ys[:, None]) > params.parked_distance
    parked = controlled & ~jnp.any(far & future, axis=-1)
    speed = jnp.hypot(log.vel_x[:, c], log.vel_y[:, c])
    return AgentState(
        x=log.x, y=log.y, yaw=log.yaw, vel_x=log.vel_x, vel_y=log.vel_y, valid=valid,
        path_x=px, path_y=py, path_yaw=pyaw, path_arc=arc, path_end=end,
        arc=jnp.zeros((o,), arc.dtype), speed=jnp.where(parked, 0.0, speed).astype(arc.dtype),
        idm=controlled & ~parked, parked=parked)


def _on_path(a: AgentState, s):
    """Poses at arc lengths ``s [O, K]`` along each object's path: ``(x, y, yaw)`` ``[O, K]``;
    past the path's end, straight on along its last heading."""
    arc = a.path_arc  # [O, T]
    t = arc.shape[-1]
    k = jnp.sum(arc[:, None, 1:] <= s[..., None], axis=-1)  # [O, K]
    k = jnp.clip(k, 0, t - 2)
    take = lambda v, i: jnp.take_along_axis(v, i, axis=-1)  # noqa: E731
    x0, y0, yaw0, s0 = take(a.path_x, k), take(a.path_y, k), take(a.path_yaw, k), take(arc, k)
    x1, y1, yaw1, s1 = (take(a.path_x, k + 1), take(a.path_y, k + 1), take(a.path_yaw, k + 1),
                        take(arc, k + 1))
    u = jnp.clip((s - s0) / jnp.maximum(s1 - s0, 1e-6), 0.0, 1.0)
    dyaw = (yaw1 - yaw0 + jnp.pi) % (2 * jnp.pi) - jnp.pi
    x, y, yaw = x0 + u * (x1 - x0), y0 + u * (y1 - y0), yaw0 + u * dyaw
    # beyond the end: the last valid pose, then straight on along its heading
    last = jnp.sum(arc[:, 1:] < a.path_end[:, None], axis=-1) + 1
    last = jnp.minimum(last, t - 1)[:, None]
    ex, ey, eyaw = take(a.path_x, last), take(a.path_y, last), take(a.path_yaw, last)
    over = jnp.maximum(s - a.path_end[:, None], 0.0)
    past = s > a.path_end[:, None]
    x = jnp.where(past, ex + over * jnp.cos(eyaw), x)
    y = jnp.where(past, ey + over * jnp.sin(eyaw), y)
    yaw = jnp.where(past, eyaw, yaw)
    return x, y, (yaw + jnp.pi) % (2 * jnp.pi) - jnp.pi


def leader_gaps(a: AgentState, objects, lights, t, params: IdmParams):
    """``(gap [O], lead_speed [O])``: bumper-to-bumper distance along its path from each agent
    to its leader (``inf`` when none within the lookahead) and the leader's speed along the
    agent's heading. ``objects``: every object now (an ``ObjectState``-like ``[O]``, the SDC at
    its simulated pose); ``lights``: ``TrafficLights [L, T]``; ``t`` the current step."""
    p = params
    o = a.arc.shape[0]
    k = p.path_samples
    v = a.speed
    reach = p.lookahead + p.min_gap + v * p.time_headway  # [O]
    s = a.arc[:, None] + reach[:, None] * jnp.linspace(0.0, 1.0, k + 1)[None]  # [O, K+1]
    sx, sy, _ = _on_path(a, s)
    dx, dy = jnp.diff(sx, axis=-1), jnp.diff(sy, axis=-1)  # chords [O, K]
    ln = jnp.maximum(jnp.hypot(dx, dy), 1e-6)
    ux, uy = dx / ln, dy / ln
    start = jnp.concatenate([jnp.zeros((o, 1)), jnp.cumsum(ln, axis=-1)[:, :-1]], axis=-1)
    hl_self = 0.5 * objects.length
    hw_self = 0.5 * objects.width

    def along_path(cx, cy):
        """Lateral distance to the path and arc distance along it, ``[O(agent), N, K]``."""
        rx = cx[None, :, None] - sx[:, None, :-1]
        ry = cy[None, :, None] - sy[:, None, :-1]
        proj = rx * ux[:, None] + ry * uy[:, None]
        u = jnp.clip(proj, 0.0, ln[:, None])
        lat = jnp.hypot(rx - u * ux[:, None], ry - u * uy[:, None])
        ahead = (proj > 0) | (jnp.arange(k) > 0)  # the first chord: the centre must be ahead
        return lat, start[:, None] + u, ahead

    # objects: their box's extent across and along each chord
    lat, dist, ahead = along_path(objects.x, objects.y)
    cj, sj = jnp.cos(objects.yaw)[None, :, None], jnp.sin(objects.yaw)[None, :, None]
    cos_rel = jnp.abs(cj * ux[:, None] + sj * uy[:, None])
    sin_rel = jnp.abs(sj * ux[:, None] - cj * uy[:, None])
    hl, hw = 0.5 * objects.length[None, :, None], 0.5 * objects.width[None, :, None]
    across = lat - (hl * sin_rel + hw * cos_rel)
    gap = dist - (hl * cos_rel + hw * sin_rel) - hl_self[:, None, None]
    on = (across < hw_self[:, None, None]) & ahead & objects.valid[None, :, None]
    on = on & ~jnp.eye(o, dtype=bool)[:, :, None] & (dist <= reach[:, None, None])
    gap = jnp.min(jnp.where(on, gap, jnp.inf), axis=-1)  # [O, O]
    j = jnp.argmin(gap, axis=-1)
    obj_gap = jnp.take_along_axis(gap, j[:, None], axis=-1)[:, 0]
    yaw_i = jnp.take_along_axis(a.yaw, jnp.full((o, 1), t), axis=-1)[:, 0]
    lead_v = (objects.vel_x[j] * jnp.cos(yaw_i) + objects.vel_y[j] * jnp.sin(yaw_i))
    lead_v = jnp.maximum(lead_v, 0.0)

    # red lights: a stopped leader of zero size at the stop point
    state = jnp.take_along_axis(lights.state, jnp.full((lights.state.shape[0], 1), t), -1)[:, 0]
    lvalid = jnp.take_along_axis(lights.valid, jnp.full((lights.state.shape[0], 1), t), -1)[:, 0]
    lx = jnp.take_along_axis(lights.x, jnp.full((lights.state.shape[0], 1), t), -1)[:, 0]
    ly = jnp.take_along_axis(lights.y, jnp.full((lights.state.shape[0], 1), t), -1)[:, 0]
    red = lvalid & jnp.isin(state, jnp.asarray(RED_LIGHT_STATES))
    llat, ldist, lahead = along_path(lx, ly)
    lgap = ldist - hl_self[:, None, None]
    lon = (llat < hw_self[:, None, None]) & lahead & red[None, :, None] & (lgap > 0)
    lon = lon & (ldist <= reach[:, None, None])
    light_gap = jnp.min(jnp.where(lon, lgap, jnp.inf), axis=(-1, -2))
    use_light = light_gap < obj_gap
    return (jnp.where(use_light, light_gap, obj_gap),
            jnp.where(use_light, 0.0, jnp.where(jnp.isfinite(obj_gap), lead_v, 0.0)))


def idm_accel(v, gap, lead_v, params: IdmParams):
    """The IDM acceleration ``[O]`` (``gap`` ``inf``: free road)."""
    p = params
    dv = v - lead_v
    desired = p.min_gap + jnp.maximum(0.0, v * p.time_headway
                                      + v * dv / (2.0 * jnp.sqrt(p.max_accel * p.comfort_decel)))
    free = 1.0 - (v / p.desired_speed) ** p.exponent
    interact = jnp.where(jnp.isfinite(gap), (desired / jnp.maximum(gap, 1e-3)) ** 2, 0.0)
    return p.max_accel * (free - interact)


def step_agents(a: AgentState, objects, lights, t, params: IdmParams) -> AgentState:
    """Advance the agents of ONE scenario from step ``t`` to ``t + 1`` (all at once, from the
    objects now, ``objects`` with the SDC at its simulated pose)."""
    gap, lead_v = leader_gaps(a, objects, lights, t, params)
    acc = idm_accel(a.speed, gap, lead_v, params)
    acc = jnp.where(a.arc >= a.path_end, jnp.minimum(acc, -params.comfort_decel), acc)
    v1 = jnp.maximum(a.speed + acc * DT, 0.0)
    arc1 = a.arc + 0.5 * (a.speed + v1) * DT
    arc1 = jnp.where(a.idm, arc1, a.arc)
    v1 = jnp.where(a.idm, v1, 0.0)
    x, y, yaw = (q[:, 0] for q in _on_path(a, arc1[:, None]))
    t1 = jnp.minimum(t + 1, a.x.shape[-1] - 1)
    moved = a.idm | a.parked
    # parked: the pose at step 10
    x = jnp.where(a.parked, a.x[:, CURRENT_INDEX], x)
    y = jnp.where(a.parked, a.y[:, CURRENT_INDEX], y)
    yaw = jnp.where(a.parked, a.yaw[:, CURRENT_INDEX], yaw)

    def put(old, new):
        return old.at[:, t1].set(jnp.where(moved, jnp.asarray(new, old.dtype), old[:, t1]))

    return a.replace(x=put(a.x, x), y=put(a.y, y), yaw=put(a.yaw, yaw),
                     vel_x=put(a.vel_x, v1 * jnp.cos(yaw)), vel_y=put(a.vel_y, v1 * jnp.sin(yaw)),
                     valid=put(a.valid, True), arc=arc1, speed=v1.astype(a.speed.dtype))
