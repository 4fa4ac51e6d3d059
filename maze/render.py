"""A strip of maze frames (minigrid rendering, imitator's 3x3 view highlighted): ``python -m
maze.render [--out DIR]`` writes ``DIR/figures/maze_frames.png``.

The agent follows the exploring planner of :mod:`maze.oracles` (walk to the nearest unseen cell
until the goal is in view, then take the shortest path), the behaviour an imitator with a 3x3
view needs and that a full-observation expert never demonstrates.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from igdrivsim.cli_args import DefaultsFormatter
from igdrivsim.io import atomic_savefig
from maze.env import MOVES
from maze.gym_env import MazeGymEnv
from maze.oracles import _step_towards


def planner_actions(env: MazeGymEnv, seed: int) -> list[int]:
    """Actions of one exploring-planner episode from ``env.reset(seed=seed)``."""
    obs, info = env.reset(seed=seed)
    walls, r = env.maze.walls, env.maze.receptive_field // 2
    cells = {tuple(int(v) for v in c) for c in env.maze.goal_cells}
    seen: set = set()
    actions, done = [], False
    while not done:
        pos = info["position"]
        seen.update((pos[0] + i, pos[1] + j) for i in range(-r, r + 1) for j in range(-r, r + 1))
        targets = {info["goal"]} if info["goal"] in seen else cells - seen
        nxt = _step_towards(walls, pos, targets)
        actions.append(int(np.flatnonzero((MOVES == np.subtract(nxt, pos)).all(axis=1))[0]))
        obs, _, terminated, truncated, info = env.step(actions[-1])
        done = terminated or truncated
    return actions


def save_frames(path: Path, seed: int | None = None, num_frames: int = 6) -> Path:
    """Evenly spaced frames of a planner episode side by side (by default the first seed whose
    episode takes more than 25 steps, so the exploration shows)."""
    import matplotlib  # heavy: only when drawing

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # heavy: only when drawing

    env = MazeGymEnv(render_mode="rgb_array", tile_size=16)
    if seed is None:
        seed = 0
        while len(actions := planner_actions(env, seed)) <= 25:
            seed += 1
    else:
        actions = planner_actions(env, seed)
    picks = set(np.linspace(0, len(actions), num_frames).round().astype(int).tolist())
    obs, _ = env.reset(seed=seed)
    frames = []
    for t in range(len(actions) + 1):
        if t in picks:
            frames.append((env.render(), t, bool(obs[-1] >= 0)))
        if t < len(actions):
            obs, *_ = env.step(actions[t])
    fig, axes = plt.subplots(1, len(frames), figsize=(2.0 * len(frames), 2.3))
    for ax, (img, t, visible) in zip(np.atleast_1d(axes), frames, strict=True):
        ax.imshow(img)
        ax.set_title(f"t = {t}" + (", goal in view" if visible else ""), fontsize=8)
        ax.axis("off")
    fig.suptitle("Imitator's 3x3 view (highlighted) while it explores for the goal (green)",
                 fontsize=9)
    fig.tight_layout()
    atomic_savefig(fig, path, format="png", dpi=150)
    plt.close(fig)
    return path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m maze.render", description=__doc__.split(
        "\n\n")[0].replace("\n", " "), formatter_class=DefaultsFormatter)
    parser.add_argument("--out", type=Path, default=Path("outputs/maze"),
                        help="output folder (the figure goes to OUT/figures/)")
    parser.add_argument("--seed", type=int, default=None,
                        help="maze layout seed (default: the study's)")
    args = parser.parse_args(argv)
    print(save_frames(args.out / "figures" / "maze_frames.png", args.seed))
    return 0


if __name__ == "__main__":
    sys.exit(main())
