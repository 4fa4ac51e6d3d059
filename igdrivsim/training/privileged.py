"""The privileged teacher of DAgger and ADVISOR: a policy trained with the ``full`` setting.

The teacher is an earlier run (``training.teacher``) with the student's observation capacities;
its ``full`` parameters label the student's states, seed by seed (cycling over fewer seeds).
``igdrivsim teacher`` (:func:`choose_teacher`) picks the finished run that fails least
(overlap + offroad) on the validation subset of its learning curves at the last update.
"""

from __future__ import annotations

import argparse
import os

import jax
import jax.numpy as jnp
import numpy as np

from igdrivsim.errors import ConfigError
from igdrivsim.io import atomic_write_json
from igdrivsim.policy.network import PolicyConfig
from igdrivsim.training.config import RunConfig
from igdrivsim.training.run import Run, is_run

TEACHER_SETTING = "full"


def load_teacher(run_dir: str, student: RunConfig) -> tuple[PolicyConfig, object]:
    """The privileged teacher's network config and its ``full``-setting parameters stacked
    over the student's seeds ``[S]``, the run checked against the student's observation."""
    if not is_run(run_dir):
        raise ConfigError(f"training.teacher: {run_dir} holds no run (train the full setting "
                          "first)")
    teacher = Run.open(run_dir)
    config = teacher.config
    if TEACHER_SETTING not in config.settings:
        raise ConfigError(f"training.teacher: {run_dir} was not trained with the "
                          f"{TEACHER_SETTING!r} setting (it has {', '.join(config.settings)})")
    mine, theirs = ((o.num_objects, o.num_roadgraph_points, o.roadgraph_stride)
                    for o in (student.observation, config.observation))
    if mine != theirs:
        raise ConfigError(f"training.teacher: {run_dir} observes (objects, road points, "
                          f"stride) = {theirs}, the student {mine}; they must match")
    if not teacher.complete:
        raise ConfigError(f"training.teacher: {run_dir} has not finished training")
    g = config.settings.index(TEACHER_SETTING)
    pick = np.arange(student.training.seeds) % config.training.seeds
    return config.policy, jax.tree.map(lambda x: jnp.asarray(x[g])[pick], teacher.params())


def teacher_score(run_dir: str) -> dict | None:
    """A run's ``full`` setting's closed-loop validation metrics at its last learning-curve
    point, averaged over seeds (``None`` without one)."""
    if not is_run(run_dir):
        return None
    rows = [r for r in Run.open(run_dir).curves()
            if r.get("setting") == TEACHER_SETTING and "offroad" in r]
    if not rows:
        return None
    last = max(r["update"] for r in rows)
    rows = [r for r in rows if r["update"] == last]
    mean = {k: float(np.mean([r[k] for r in rows]))
            for k in ("log_divergence", "offroad", "overlap")}
    return {"run": os.fspath(run_dir), "update": last, "seeds": len(rows), **mean,
            "failure": mean["offroad"] + mean["overlap"]}


def choose_teacher(run_dirs: list[str]) -> dict:
    """The score of the run (among ``run_dirs``) whose ``full`` setting fails least (overlap +
    offroad, then log divergence), with every candidate's score under ``candidates``."""
    scores = [s for s in map(teacher_score, run_dirs) if s is not None]
    if not scores:
        raise ConfigError("no run with closed-loop validation curves of the full setting among "
                          + ", ".join(map(os.fspath, run_dirs)))
    best = min(scores, key=lambda s: (s["failure"], s["log_divergence"]))
    return {**best, "candidates": scores}


def teacher_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--runs", nargs="+", required=True, help="candidate run folders")
    parser.add_argument("--out", required=True, help="where to write the choice (JSON)")


def teacher_command(args: argparse.Namespace) -> int:
    """Pick the teacher among finished runs and record the choice."""
    choice = choose_teacher(args.runs)
    atomic_write_json(args.out, choice, indent=2)
    for s in choice["candidates"]:
        print(f"{s['run']}: full setting at update {s['update']}: offroad "
              f"{100 * s['offroad']:.2f}%, overlap {100 * s['overlap']:.2f}%, log "
              f"divergence {s['log_divergence']:.2f} m")
    print(f"teacher: {choice['run']}")
    return 0
