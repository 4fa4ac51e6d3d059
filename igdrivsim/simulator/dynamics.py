"""SDC dynamics: delta-local / delta-global actions, their inverses, and the action discretiser.

An action is ``float[..., 3] = (dx, dy, dyaw)`` over one step (0.1 s), ``(dx, dy)`` in the SDC
frame (delta-local) or the world's (delta-global), clipped to ``+-6 m, +-6 m, +-pi``; a
non-finite action becomes the zero action (host code rejects it with :func:`validate_actions`).
Each dimension has 257 levels from min to max (level 128 is zero).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from igdrivsim.data.scenario import DT
from igdrivsim.errors import DataError

ACTION_LOW = (-6.0, -6.0, -np.pi)
ACTION_HIGH = (6.0, 6.0, np.pi)
NUM_BINS = 256  # bins per dimension; NUM_BINS + 1 levels
NUM_LEVELS = NUM_BINS + 1
DX_LEVEL = (ACTION_HIGH[0] - ACTION_LOW[0]) / NUM_BINS  # metres between two dx levels
DYAW_LEVEL = (ACTION_HIGH[2] - ACTION_LOW[2]) / NUM_BINS  # radians between two dyaw levels


def constant_speed_offset(speed):
    """Levels above the zero level of the dx that keeps ``speed`` (m/s) over one step."""
    return jnp.round(jnp.asarray(speed) * DT / DX_LEVEL).astype(jnp.int32)


def wrap_angle(a):
    return (a + jnp.pi) % (2 * jnp.pi) - jnp.pi


def clip_action(action):
    action = jnp.asarray(action)
    low, high = jnp.asarray(ACTION_LOW, action.dtype), jnp.asarray(ACTION_HIGH, action.dtype)
    finite = jnp.all(jnp.isfinite(action), axis=-1, keepdims=True)
    return jnp.where(finite, jnp.clip(action, low, high), 0.0)


def validate_actions(action) -> None:
    """Host-side check: a :class:`DataError` for a non-finite action."""
    a = np.asarray(action)
    if a.shape[-1:] != (3,):
        raise DataError("actions must have a trailing dimension of 3 (dx, dy, dyaw), "
                        f"got {a.shape}")
    bad = ~np.isfinite(a)
    if bad.any():
        where = tuple(int(i) for i in np.argwhere(bad)[0])
        raise DataError(f"non-finite action value {a[where]} at index {where}")


def delta_local(x, y, yaw, action):
    """Apply a delta-local action to poses ``[...]``: returns ``(x, y, yaw, vel_x, vel_y)``."""
    a = clip_action(action)
    c, s = jnp.cos(yaw), jnp.sin(yaw)
    gx = c * a[..., 0] - s * a[..., 1]
    gy = s * a[..., 0] + c * a[..., 1]
    return x + gx, y + gy, wrap_angle(yaw + a[..., 2]), gx / DT, gy / DT


def delta_global(x, y, yaw, action):
    """Apply a delta-global (world-frame) action: returns ``(x, y, yaw, vel_x, vel_y)``."""
    a = clip_action(action)
    return x + a[..., 0], y + a[..., 1], wrap_angle(yaw + a[..., 2]), a[..., 0] / DT, a[..., 1] / DT


def inverse_delta_local(x, y, yaw, x1, y1, yaw1):
    """The delta-local action that moves pose ``(x, y, yaw)`` to ``(x1, y1, yaw1)``, clipped."""
    gx, gy = x1 - x, y1 - y
    c, s = jnp.cos(yaw), jnp.sin(yaw)
    return clip_action(jnp.stack([c * gx + s * gy, -s * gx + c * gy, wrap_angle(yaw1 - yaw)], -1))


def inverse_delta_global(x, y, yaw, x1, y1, yaw1):
    """The delta-global action that moves pose ``(x, y, yaw)`` to ``(x1, y1, yaw1)``, clipped."""
    return clip_action(jnp.stack([x1 - x, y1 - y, wrap_angle(yaw1 - yaw)], axis=-1))


DYNAMICS = {"delta_local": (delta_local, inverse_delta_local),
            "delta_global": (delta_global, inverse_delta_global)}


def discretize(action):
    """Nearest of the 257 levels per dimension: ``float[..., 3] -> int32[..., 3]`` in 0..256."""
    a = clip_action(action)
    low, high = jnp.asarray(ACTION_LOW, a.dtype), jnp.asarray(ACTION_HIGH, a.dtype)
    idx = jnp.round((a - low) / (high - low) * NUM_BINS)
    return jnp.clip(idx, 0, NUM_BINS).astype(jnp.int32)


def undiscretize(idx):
    """Level index ``int[..., 3]`` (clipped to 0..256) back to the action ``float32[..., 3]``."""
    i = jnp.clip(jnp.asarray(idx), 0, NUM_BINS).astype(jnp.float32)
    low, high = jnp.asarray(ACTION_LOW, jnp.float32), jnp.asarray(ACTION_HIGH, jnp.float32)
    return low + i * ((high - low) / NUM_BINS)
