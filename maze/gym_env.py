"""The maze as a gymnasium environment built on minigrid (id ``IGDrivSim/Maze-v0``).

Same layout, rules, rewards and observations as :mod:`maze.env`, for rendering and for other RL
libraries. Actions are absolute moves (0 up, 1 down, 2 left, 3 right), not minigrid's turn/forward;
the arrow drawn for the agent points along its last move. Goals are drawn with the JAX
environment's own key chain (``reset(seed=s)`` starts it at ``PRNGKey(s)``; later resets continue
it, as the JAX auto-reset does), so both implementations produce identical episodes for the same
seed and actions. The observation is the JAX environment's vector (``obs_kind`` ``"partial"``,
the imitator's, or ``"full"``); the rendering highlights the imitator's centred view.
"""

from __future__ import annotations

import gymnasium as gym
import jax
import numpy as np
from gymnasium import spaces
from minigrid.core.grid import Grid
from minigrid.core.mission import MissionSpace
from minigrid.core.world_object import Goal, Wall
from minigrid.minigrid_env import MiniGridEnv

from igdrivsim.errors import ConfigError
from maze import env as maze_env
from maze.env import MOVES, make_params

ENV_ID = "IGDrivSim/Maze-v0"
_jax_reset = jax.jit(maze_env.reset, static_argnums=1)
MINIGRID_DIR = (3, 1, 2, 0)  # our action -> minigrid direction (0 right, 1 down, 2 left, 3 up)


class MazeGymEnv(MiniGridEnv):
    """Minigrid rendition of the paper's maze; positions are (row, col) as in :mod:`maze.env`."""

    metadata = {"render_modes": ["rgb_array", "human"], "render_fps": 10}

    def __init__(self, size: int = 13, receptive_field: int = 3, max_steps: int = 200,
                 obs_kind: str = "partial", render_mode: str | None = None, tile_size: int = 32):
        self.maze = make_params(size, receptive_field, max_steps)
        if obs_kind not in maze_env.OBS_KINDS:
            raise ConfigError(f"obs_kind must be one of {maze_env.OBS_KINDS}, got {obs_kind!r}")
        self.obs_kind = obs_kind
        side = size + 2
        super().__init__(mission_space=MissionSpace(mission_func=lambda: "reach the goal"),
                         width=side, height=side, max_steps=max_steps, see_through_walls=True,
                         agent_view_size=max(3, receptive_field), render_mode=render_mode,
                         tile_size=tile_size)
        self.action_space = spaces.Discrete(4)
        self.observation_space = spaces.Box(-1.0, float(side), (self.maze.obs_dim,), np.float32)
        self._key = jax.random.PRNGKey(0)
        self.goal = (0, 0)

    # --- minigrid hooks -------------------------------------------------------------------
    def _gen_grid(self, width: int, height: int) -> None:
        self.grid = Grid(width, height)
        walls = self.maze.walls
        for r, c in np.argwhere(walls):
            self.grid.set(int(c), int(r), Wall())
        self.grid.set(self.goal[1], self.goal[0], Goal())
        self.agent_pos = (self.maze.start[1], self.maze.start[0])  # minigrid is (x=col, y=row)
        self.agent_dir = 3

    def get_full_render(self, highlight: bool, tile_size: int) -> np.ndarray:
        """Whole maze with the imitator's centred receptive field highlighted."""
        mask = np.zeros((self.width, self.height), dtype=bool)
        if highlight:
            r = self.maze.receptive_field // 2
            col, row = self.agent_pos
            mask[max(col - r, 0):col + r + 1, max(row - r, 0):row + r + 1] = True
        return self.grid.render(tile_size, self.agent_pos, self.agent_dir, highlight_mask=mask)

    # --- gymnasium API ---------------------------------------------------------------------
    @property
    def position(self) -> tuple[int, int]:
        return (int(self.agent_pos[1]), int(self.agent_pos[0]))

    def _obs(self) -> np.ndarray:
        """The observation vector, computed with numpy (an independent check of the JAX one)."""
        r = self.maze.receptive_field // 2
        row, col = self.position
        padded = np.pad(self.maze.walls, r, constant_values=True)
        patch = padded[row:row + 2 * r + 1, col:col + 2 * r + 1].reshape(-1)
        goal = np.array(self.goal, np.float32)
        visible = max(abs(self.goal[0] - row), abs(self.goal[1] - col)) <= r
        if self.obs_kind == "partial" and not visible:
            goal[:] = -1.0
        return np.concatenate([patch.astype(np.float32), np.array([row, col], np.float32), goal])

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        if seed is not None:
            self._key = jax.random.PRNGKey(seed)
        state = _jax_reset(self._key, self.maze)  # the JAX env's goal draw and key chain
        self.goal = tuple(int(v) for v in np.asarray(state.goal))
        self._key = state.key
        super().reset(seed=seed, options=options)
        return self._obs(), {"position": self.position, "goal": self.goal}

    def step(self, action):
        action = int(action)
        if not 0 <= action < 4:
            raise ValueError(f"action must be in 0..3, got {action}")
        self.step_count += 1
        row, col = self.position
        target = (row + int(MOVES[action][0]), col + int(MOVES[action][1]))
        self.agent_dir = MINIGRID_DIR[action]
        if not self.maze.walls[target]:
            self.agent_pos = (target[1], target[0])
        terminated = self.position == self.goal
        reward = 10.0 - 9.0 * self.step_count / self.max_steps if terminated else 0.0
        truncated = not terminated and self.step_count >= self.max_steps
        if self.render_mode == "human":
            self.render()
        return self._obs(), float(reward), terminated, truncated, {
            "position": self.position, "goal": self.goal}


def register() -> None:
    """Register ``IGDrivSim/Maze-v0`` with gymnasium (idempotent)."""
    if ENV_ID not in gym.registry:
        gym.register(id=ENV_ID, entry_point="maze.gym_env:MazeGymEnv")


register()
