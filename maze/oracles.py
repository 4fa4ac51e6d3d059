"""Exact reference returns: a shortest-path oracle (full observation) and an exploring planner.

Both are deterministic, so their expected return is an exact average over the goal cells (the
goal is uniform): no sampling noise. The planner, which only sees the goal inside its receptive
field, walks to the nearest cell it has not yet seen until the goal is in view, then takes the
shortest path: a reference (not a proof of optimality) for the partial-observation optimum.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from maze.env import MOVES, MazeParams


def bfs_distances(walls: np.ndarray, source: tuple[int, int]) -> np.ndarray:
    """Shortest-path step counts from ``source`` to every cell (-1 for walls / unreachable)."""
    dist = np.full(walls.shape, -1, dtype=np.int64)
    dist[source] = 0
    queue = deque([source])
    while queue:
        r, c = queue.popleft()
        for dr, dc in MOVES:
            nr, nc = r + dr, c + dc
            if not walls[nr, nc] and dist[nr, nc] < 0:
                dist[nr, nc] = dist[r, c] + 1
                queue.append((nr, nc))
    return dist


def episode_return(steps: int, params: MazeParams) -> float:
    """Return of an episode that reaches the goal after ``steps`` moves (0 past the limit)."""
    return 10.0 - 9.0 * steps / params.max_steps if steps <= params.max_steps else 0.0


def oracle_lengths(params: MazeParams) -> np.ndarray:
    """Shortest-path episode length to each goal cell (order of ``params.goal_cells``)."""
    dist = bfs_distances(params.walls, params.start)
    return np.array([dist[r, c] for r, c in params.goal_cells])


def _step_towards(walls: np.ndarray, pos: tuple[int, int], targets: set) -> tuple[int, int]:
    """First move of a shortest path from ``pos`` to the nearest cell of ``targets``."""
    parent = {pos: None}
    queue = deque([pos])
    while queue:
        cell = queue.popleft()
        if cell in targets:
            while parent[cell] != pos and parent[cell] is not None:
                cell = parent[cell]
            return cell
        for dr, dc in MOVES:
            nxt = (cell[0] + dr, cell[1] + dc)
            if not walls[nxt] and nxt not in parent:
                parent[nxt] = cell
                queue.append(nxt)
    raise RuntimeError("no reachable target")  # cannot happen in a connected maze


def planner_lengths(params: MazeParams) -> np.ndarray:
    """Episode length of the exploring planner for each goal cell (``max_steps + 1`` = failed)."""
    walls, r = params.walls, params.receptive_field // 2
    cells = [tuple(int(v) for v in cell) for cell in params.goal_cells]
    lengths = []
    for goal in cells:
        pos, seen, t = params.start, set(), 0
        while pos != goal and t <= params.max_steps:
            seen.update((pos[0] + i, pos[1] + j) for i in range(-r, r + 1)
                        for j in range(-r, r + 1))
            targets = {goal} if goal in seen else set(cells) - seen
            pos, t = _step_towards(walls, pos, targets), t + 1
        lengths.append(t)
    return np.array(lengths)


def reference_returns(params: MazeParams) -> dict[str, tuple[float, float]]:
    """``{"oracle_full": (mean return, mean length), "planner_partial": (...)}`` (exact)."""
    out = {}
    for name, lengths in (("oracle_full", oracle_lengths(params)),
                          ("planner_partial", planner_lengths(params))):
        returns = [episode_return(int(n), params) for n in lengths]
        out[name] = (float(np.mean(returns)), float(np.mean(lengths)))
    return out
