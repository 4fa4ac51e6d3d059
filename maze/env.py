"""Pure-JAX maze of paper Fig. 2 (gymnax style: ``reset(key, p)`` / ``step(state, action, p)``).

Layout (MetaMaze grid): a ``(size + 2)``-square array whose outer ring is wall; inside, odd array
rows are open corridors and even rows have a wall at every even column (pillars). The agent starts
at the centre; the goal is drawn uniformly among the open cells other than the start. Four moves
(0 up, 1 down, 2 left, 3 right; walking into a wall stays put). Reaching the goal at step ``t``
(1-based) pays ``10 - 9 t / max_steps`` and ends the episode; otherwise it ends after
``max_steps`` steps with return 0.

Two observation functions, both ``float32[rf * rf + 4]``: the centred ``rf x rf`` wall patch
(1 = wall), the agent's (row, col), and the goal's (row, col). The imitator (``partial``) sees the
goal only while it lies inside the patch, else (-1, -1); the expert (``full``) always sees it.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from igdrivsim.errors import ConfigError

ACTION_NAMES = ("up", "down", "left", "right")
MOVES = np.array([[-1, 0], [1, 0], [0, -1], [0, 1]], dtype=np.int32)
OBS_KINDS = ("full", "partial")


def wall_grid(size: int) -> np.ndarray:
    """Boolean ``(size + 2, size + 2)`` wall array of the MetaMaze layout (True = wall)."""
    n = size + 2
    walls = np.zeros((n, n), dtype=bool)
    walls[0, :] = walls[-1, :] = walls[:, 0] = walls[:, -1] = True
    walls[2:-1:2, 2:-1:2] = True
    return walls


@struct.dataclass
class MazeParams:
    """Static maze configuration (hashable, so it can be a ``jit`` static argument)."""

    size: int = struct.field(pytree_node=False, default=13)
    receptive_field: int = struct.field(pytree_node=False, default=3)
    max_steps: int = struct.field(pytree_node=False, default=200)

    @property
    def start(self) -> tuple[int, int]:
        c = (self.size + 2) // 2
        return (c, c)

    @property
    def walls(self) -> np.ndarray:
        return wall_grid(self.size)

    @property
    def goal_cells(self) -> np.ndarray:
        """``int32[G, 2]`` open cells a goal can be drawn from (every open cell but the start)."""
        cells = np.argwhere(~self.walls).astype(np.int32)
        return cells[~np.all(cells == np.array(self.start), axis=1)]

    @property
    def obs_dim(self) -> int:
        return self.receptive_field**2 + 4


def make_params(size: int = 13, receptive_field: int = 3, max_steps: int = 200) -> MazeParams:
    """Validated :class:`MazeParams` (raises :class:`ConfigError` on a bad value)."""
    if size < 3 or size % 2 == 0:
        raise ConfigError(f"maze size must be odd and >= 3, got {size}")
    if receptive_field < 1 or receptive_field % 2 == 0:
        raise ConfigError(f"receptive field must be odd and >= 1, got {receptive_field}")
    if receptive_field > size:
        raise ConfigError(f"receptive field {receptive_field} is larger than the maze ({size})")
    if max_steps < 1:
        raise ConfigError(f"max steps must be >= 1, got {max_steps}")
    return MazeParams(size=size, receptive_field=receptive_field, max_steps=max_steps)


@struct.dataclass
class MazeState:
    pos: jax.Array  # int32[2] (row, col)
    goal: jax.Array  # int32[2]
    time: jax.Array  # int32, steps taken in this episode
    key: jax.Array  # PRNG key for the next automatic reset


def sample_goal(key: jax.Array, params: MazeParams) -> jax.Array:
    """Goal cell drawn uniformly among the open cells other than the start."""
    cells = jnp.asarray(params.goal_cells)
    return cells[jax.random.randint(key, (), 0, cells.shape[0])]


def reset(key: jax.Array, params: MazeParams) -> MazeState:
    """New episode: agent at the centre, goal drawn with ``key``."""
    key_goal, key_next = jax.random.split(key)
    return MazeState(pos=jnp.asarray(params.start, jnp.int32), goal=sample_goal(key_goal, params),
                     time=jnp.zeros((), jnp.int32), key=key_next)


def step(state: MazeState, action: jax.Array, params: MazeParams
         ) -> tuple[MazeState, jax.Array, jax.Array]:
    """One move; returns ``(state, reward, done)`` (no reset: see :func:`auto_step`)."""
    walls = jnp.asarray(params.walls)
    target = state.pos + jnp.asarray(MOVES)[action]
    pos = jnp.where(walls[target[0], target[1]], state.pos, target)
    time = state.time + 1
    reached = jnp.all(pos == state.goal)
    reward = jnp.where(reached, 10.0 - 9.0 * time / params.max_steps, 0.0).astype(jnp.float32)
    done = reached | (time >= params.max_steps)
    return state.replace(pos=pos, time=time), reward, done


def auto_step(state: MazeState, action: jax.Array, params: MazeParams
              ) -> tuple[MazeState, jax.Array, jax.Array]:
    """:func:`step`, then a fresh episode (from ``state.key``) where the episode ended."""
    nxt, reward, done = step(state, action, params)
    fresh = reset(state.key, params)
    nxt = jax.tree.map(lambda a, b: jnp.where(done, a, b), fresh, nxt)
    return nxt, reward, done


def wall_patch(pos: jax.Array, params: MazeParams) -> jax.Array:
    """``float32[rf * rf]`` walls of the centred receptive field (outside the array = wall)."""
    r = params.receptive_field // 2
    padded = jnp.pad(jnp.asarray(params.walls), r, constant_values=True)
    patch = jax.lax.dynamic_slice(padded, (pos[0], pos[1]), (2 * r + 1, 2 * r + 1))
    return patch.reshape(-1).astype(jnp.float32)


def goal_in_view(state: MazeState, params: MazeParams) -> jax.Array:
    """Whether the goal lies inside the agent's centred receptive field."""
    return jnp.all(jnp.abs(state.goal - state.pos) <= params.receptive_field // 2)


def observe(state: MazeState, params: MazeParams, kind: str | jax.Array) -> jax.Array:
    """Observation ``"full"`` (expert) or ``"partial"`` (imitator).

    ``kind`` may also be a boolean array (True = partial), so one compiled function serves both
    observation kinds (the study ``vmap``s over curves that differ only in this flag).
    """
    if isinstance(kind, str):
        if kind not in OBS_KINDS:
            raise ConfigError(f"observation kind must be one of {OBS_KINDS}, got {kind!r}")
        kind = kind == "partial"
    hidden = jnp.asarray(kind) & ~goal_in_view(state, params)
    goal = jnp.where(hidden, -1, state.goal)
    return jnp.concatenate([wall_patch(state.pos, params), state.pos.astype(jnp.float32),
                            goal.astype(jnp.float32)])
