"""Trajectory-level metrics of one episode, from its final state (definitions: docs/metrics.md).

Each function takes the ``SimState`` *after* the episode (one scenario; the rollout ``vmap``-s
them) and returns a ``f32[]`` scalar. Derivatives are Savitzky-Golay fits over
``SMOOTH_WINDOW`` steps (the action grid's 4.7 cm quantisation makes raw differences noisy).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from igdrivsim.data.scenario import CURRENT_INDEX, DT
from igdrivsim.simulator import metrics as step_rules
from igdrivsim.simulator.agents import boxes_overlap
from igdrivsim.simulator.dynamics import wrap_angle
from igdrivsim.simulator.state import SimParams, SimState, current_objects, log_sdc_row

# nuPlan's ego-is-comfortable bounds (nuplan-devkit docs/metrics_description.md).
LON_ACCEL_MIN, LON_ACCEL_MAX = -4.05, 2.40  # m/s^2
LAT_ACCEL_MAX = 4.89  # m/s^2
YAW_RATE_MAX = 0.95  # rad/s
YAW_ACCEL_MAX = 1.93  # rad/s^2
LON_JERK_MAX = 4.13  # m/s^3
JERK_MAX = 8.37  # m/s^3
# nuPlan: "making progress" passes at a progress ratio >= 0.2.
PROGRESS_THRESHOLD = 0.2
MIN_LOG_PROGRESS = 5.0  # m: below this the log barely moves and progress counts as full (ours)
# nuPlan: time to collision over a 3 s horizon at 0.1 s, compliant when >= 0.95 s.
TTC_HORIZON, TTC_STEP, TTC_BOUND = 3.0, 0.1, 0.95
STOPPED_SPEED = 0.1  # m/s: a stopped SDC has no time-to-collision of its own (ours)
# Kinematic infeasibility (ours, the scale of Waymax's bicycle-model limits).
ACCEL_LIMIT = 6.0  # m/s^2, |acceleration vector|
CURVATURE_LIMIT = 0.3  # 1/m
CURVATURE_MIN_SPEED = 1.0  # m/s: curvature = yaw rate / speed is checked above this speed
SMOOTH_WINDOW = 15  # steps (1.5 s), Savitzky-Golay window (odd)
SMOOTH_ORDER = 3


def _savgol_kernels(window: int, order: int) -> np.ndarray:
    """``[order + 1, window]`` kernels: row ``d`` maps a window of samples to the ``d``-th
    derivative (per ``DT``) of their least-squares polynomial at the centre."""
    half = window // 2
    t = np.arange(-half, half + 1, dtype=np.float64) * DT
    vander = np.vander(t, order + 1, increasing=True)  # [window, order + 1]
    coef = np.linalg.pinv(vander)  # polynomial coefficients from samples
    factorial = np.array([float(np.prod(np.arange(1, d + 1))) for d in range(order + 1)])
    return (coef * factorial[:, None]).astype(np.float32)


_KERNELS = _savgol_kernels(SMOOTH_WINDOW, SMOOTH_ORDER)


def _windows(a, half: int):
    """``[C, 2 half + 1]`` windows of ``a [T]`` centred at ``half .. T - half - 1``."""
    n = a.shape[-1] - 2 * half
    idx = np.arange(n)[:, None] + np.arange(2 * half + 1)[None, :]
    return a[..., idx]


def kinematics(state: SimState) -> dict[str, jax.Array]:
    """Smoothed kinematics of the simulated SDC at the window centres ``[C]`` (see module)."""
    sdc, half = state.sdc, SMOOTH_WINDOW // 2
    yaw = jnp.concatenate([sdc.yaw[:1], sdc.yaw[:1] + jnp.cumsum(
        wrap_angle(jnp.diff(sdc.yaw)))])  # unwrapped
    k = jnp.asarray(_KERNELS)
    wx, wy, wyaw = (_windows(a, half) for a in (sdc.x, sdc.y, yaw))
    vx, ax, jx = (wx @ k[d] for d in (1, 2, 3))
    vy, ay, jy = (wy @ k[d] for d in (1, 2, 3))
    heading = wyaw[:, half]
    c, s = jnp.cos(heading), jnp.sin(heading)
    # valid: every sample of the window is valid and its centre is a controlled step
    centre = np.arange(half, sdc.valid.shape[-1] - half)
    valid = jnp.all(_windows(sdc.valid, half), axis=-1) & (centre > CURRENT_INDEX)
    return dict(
        speed=jnp.hypot(vx, vy), lon_accel=ax * c + ay * s, lat_accel=-ax * s + ay * c,
        accel=jnp.hypot(ax, ay), lon_jerk=jx * c + jy * s, jerk=jnp.hypot(jx, jy),
        yaw_rate=wyaw @ k[1], yaw_accel=wyaw @ k[2], valid=valid)


def max_abs(name: str):
    """A metric ``(state, params) -> f32[]``: the largest ``|kinematics[name]|`` (0 if none)."""
    def fn(state: SimState, params: SimParams | None = None):
        kin = kinematics(state)
        return jnp.max(jnp.where(kin["valid"], jnp.abs(kin[name]), 0.0))
    fn.__name__ = f"max_abs_{name}"
    return fn


def comfortable(state: SimState, params: SimParams | None = None):
    """1.0 when every nuPlan comfort bound holds at every evaluated step, else 0.0."""
    kin = kinematics(state)
    ok = ((kin["lon_accel"] >= LON_ACCEL_MIN) & (kin["lon_accel"] <= LON_ACCEL_MAX)
          & (jnp.abs(kin["lat_accel"]) <= LAT_ACCEL_MAX)
          & (jnp.abs(kin["yaw_rate"]) <= YAW_RATE_MAX)
          & (jnp.abs(kin["yaw_accel"]) <= YAW_ACCEL_MAX)
          & (jnp.abs(kin["lon_jerk"]) <= LON_JERK_MAX) & (kin["jerk"] <= JERK_MAX))
    return jnp.all(ok | ~kin["valid"]).astype(jnp.float32)


def kinematic_infeasible(state: SimState, params: SimParams | None = None):
    """1.0 when some step needs ``|acceleration| > ACCEL_LIMIT`` or, above
    ``CURVATURE_MIN_SPEED``, a curvature ``|yaw rate| / speed > CURVATURE_LIMIT``."""
    kin = kinematics(state)
    curvature = jnp.abs(kin["yaw_rate"]) / jnp.maximum(kin["speed"], CURVATURE_MIN_SPEED)
    bad = (kin["accel"] > ACCEL_LIMIT) | (
        (kin["speed"] >= CURVATURE_MIN_SPEED) & (curvature > CURVATURE_LIMIT))
    return jnp.any(bad & kin["valid"]).astype(jnp.float32)


def progress(state: SimState, params: SimParams | None = None):
    """Progress of the last simulated position along the logged SDC path (steps 10..90) over
    the path's length, in ``[0, 1]`` (1 when the log moves less than ``MIN_LOG_PROGRESS``)."""
    log = log_sdc_row(state)
    px, py, pv = (a[CURRENT_INDEX:] for a in (log.x, log.y, log.valid))
    seg_ok = pv[:-1] & pv[1:]
    sx, sy = jnp.diff(px), jnp.diff(py)
    seg_len = jnp.where(seg_ok, jnp.hypot(sx, sy), 0.0)
    start = jnp.concatenate([jnp.zeros(1), jnp.cumsum(seg_len)[:-1]])
    total = jnp.sum(seg_len)
    sdc = state.sdc
    last = jnp.max(jnp.where(sdc.valid, jnp.arange(sdc.valid.shape[-1]), 0))
    rx, ry = sdc.x[last] - px[:-1], sdc.y[last] - py[:-1]
    len2 = sx * sx + sy * sy
    u = jnp.clip((rx * sx + ry * sy) / jnp.maximum(len2, 1e-12), 0.0, 1.0)
    d2 = jnp.where(seg_ok, (rx - u * sx) ** 2 + (ry - u * sy) ** 2, jnp.inf)
    k = jnp.argmin(d2)
    arc = start[k] + u[k] * seg_len[k]
    ratio = jnp.clip(arc / jnp.maximum(total, 1e-6), 0.0, 1.0)
    return jnp.where(total < MIN_LOG_PROGRESS, 1.0, ratio).astype(jnp.float32)


def min_time_to_collision(state: SimState, params: SimParams | None = None):
    """Smallest time to collision (s) over the controlled steps, capped at ``TTC_HORIZON``:
    constant-velocity extrapolation of the SDC and the other objects, skipping steps where the
    SDC is invalid, stopped or already overlapping."""
    i = state.sdc_index
    times = jnp.arange(1, int(round(TTC_HORIZON / TTC_STEP)) + 1) * TTC_STEP  # [K]
    others = jnp.arange(state.log.x.shape[0]) != i

    def at(t):
        o = current_objects(state.replace(timestep=t))
        ex, ey, eyaw, el, ew, evx, evy = (a[i] for a in (o.x, o.y, o.yaw, o.length, o.width,
                                                         o.vel_x, o.vel_y))
        now = jnp.any(boxes_overlap(ex, ey, el, ew, eyaw, o.x, o.y, o.length, o.width, o.yaw)
                      & o.valid & others)
        tt = times[:, None]
        hit = boxes_overlap(ex + evx * tt, ey + evy * tt, el, ew, eyaw, o.x + o.vel_x * tt,
                            o.y + o.vel_y * tt, o.length, o.width, o.yaw) & o.valid & others
        first = jnp.min(jnp.where(jnp.any(hit, axis=-1), times, TTC_HORIZON))  # hit: [K, O]
        skip = ~o.valid[i] | now | (jnp.hypot(evx, evy) < STOPPED_SPEED)
        return jnp.where(skip, TTC_HORIZON, first)

    steps = jnp.arange(CURRENT_INDEX + 1, state.sdc.x.shape[-1])
    return jnp.min(jax.lax.map(at, steps)).astype(jnp.float32)


def ttc_compliant(state: SimState, params: SimParams | None = None):
    """1.0 when the time to collision is never below ``TTC_BOUND`` (nuPlan's 0.95 s)."""
    return (min_time_to_collision(state, params) >= TTC_BOUND).astype(jnp.float32)


def at_fault_overlap(state: SimState, params: SimParams | None = None):
    """1.0 when the SDC is at fault for an overlap at some controlled step
    (:func:`igdrivsim.simulator.metrics.at_fault_overlap`)."""
    steps = jnp.arange(CURRENT_INDEX + 1, state.sdc.x.shape[-1])
    at_fault = jax.lax.map(lambda t: step_rules.at_fault_overlap(state.replace(timestep=t)), steps)
    return jnp.any(at_fault).astype(jnp.float32)
