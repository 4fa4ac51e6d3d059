"""Closed-loop evaluation rollouts -> tidy per-step and per-scenario metrics.

A learned policy is evaluated as in the paper: after the 10 warm-up steps replayed from the log
(``reset``; the GRU sees their observations, as in training), it drives the SDC for 80 steps
under its own observation setting, sampling its action from the three categoricals
(``actions="greedy"`` takes the most likely level, ``"mean"`` the expected one; see
:data:`igdrivsim.policy.act.ACTION_MODES`). Every episode, learned or reference, is the
simulator's one runner (:func:`igdrivsim.simulator.rollout.run_episode`, a ``lax.scan`` over
steps) with an actor, ``vmap``-ped over a batch of scenarios and over the seeds of a run
(stacked parameters), so one compiled function evaluates every seed at once.

Two reference actors need no training and no observation: the discretised expert replay (the
inverse dynamics to the next logged pose, quantised to the 257 levels: the floor of the metrics)
and constant velocity (the SDC keeps its last logged velocity and heading: a naive baseline).

Metric semantics (per step, after each of the 80 actions): ``overlap`` / ``offroad`` are 0/1,
``log_divergence`` is the distance to the logged SDC position. Steps where the logged SDC is
invalid are masked out. Per scenario: ``max_log_divergence`` (max over steps), ``overlap`` /
``offroad`` (any step), and the per-step means ``log_divergence``, ``overlap_steps``,
``offroad_steps``. With ``episode_metrics=True`` the final state of each episode also gives
the registry's trajectory-level metrics (:mod:`igdrivsim.evaluation.registry`: progress,
comfort, kinematic infeasibility, time to collision), ``StepOutputs.scenario``; their columns,
and the registry's derived ones, follow Table I's in the per-scenario frame.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import pandas as pd

from igdrivsim.data.scenario import decode_scenario_id, split_ego_id
from igdrivsim.evaluation import registry
from igdrivsim.evaluation.schema import (
    LOGGED_SDC_COLUMN,
    PER_SCENARIO_COLUMNS,
    PER_STEP_COLUMNS,
    REFERENCE_SETTING,
    SOURCE_COLUMN,
)
from igdrivsim.policy import closed_loop
from igdrivsim.policy.closed_loop import (
    DEFAULT_SIM_PARAMS,
    EVAL_SEED,
    REFERENCE_ACTORS,
    StepOutputs,
)
from igdrivsim.simulator import SimParams


# The engine (batches, devices, keys, the jitted episodes) is the policy layer's
# :mod:`igdrivsim.policy.closed_loop`; evaluation adds the registry's per-episode metrics.
def evaluate_reference(scenarios, actor_name: str, params: SimParams = DEFAULT_SIM_PARAMS,
                       batch_size: int = 32, metrics_fn: Callable | None = None,
                       progress: Callable[[int], Any] | None = None,
                       episode_metrics: bool = True) -> StepOutputs:
    """Roll a reference actor out on stacked scenarios ``[N]``; outputs ``[N, steps]`` (and the
    registry's episode metrics ``[N]`` unless ``episode_metrics=False``)."""
    return closed_loop.evaluate_reference(
        scenarios, actor_name, params, batch_size, metrics_fn, progress,
        episode_metrics=registry.episode_values if episode_metrics else None)


def evaluate_policy(policy_params, scenarios, *, episode_metrics: bool = False,
                    **options: Any) -> StepOutputs:
    """Evaluate every seed of stacked ``policy_params`` on scenarios ``[N]``.

    One setting name: ``policy_params [S]``, metrics ``[S, N, steps]``. A list of ``G``
    names: ``policy_params [G, S]``, metrics ``[G, S, N, steps]``, every setting in one
    compiled program (settings as data) when the settings allow it. The key of scenario ``i``
    and seed ``s`` is derived from ``seed``, ``i`` and ``s`` only (the same for every
    setting), so results do not depend on the batch size or on which settings run together.
    ``episode_metrics=True`` adds the registry's per-episode metrics (``scenario``, ``[S, N]``
    or ``[G, S, N]``); off by default (the training curves need only the per-step ones).
    The other keyword ``options`` are :func:`igdrivsim.policy.closed_loop.evaluate_policy`'s
    (``policy_config``, ``setting``, ``obs_config``, ``params``, ``actions``, ``batch_size``,
    ``seed``, ``metrics_fn``, ``progress``).
    """
    return closed_loop.evaluate_policy(
        policy_params, scenarios,
        episode_metrics=registry.episode_values if episode_metrics else None, **options)


# ----------------------------------------------------------------------------- tidy frames
def _masked_mean(x: np.ndarray, valid: np.ndarray, axis: int) -> np.ndarray:
    count = valid.sum(axis=axis)
    total = np.where(valid, x, 0.0).sum(axis=axis)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, total / np.maximum(count, 1), np.nan)


def tidy_frames(outputs: StepOutputs, scenario_ids: list[str], setting: str, method: str,
                seeds: list[int]) -> tuple[pd.DataFrame, pd.DataFrame]:
    """``(per_step, per_scenario)`` frames in the schema's column order.

    ``outputs`` holds ``[S, N, steps]`` (or ``[N, steps]`` for one seed); ``seeds`` names the
    seed axis. Per-step rows average over scenarios (valid steps only); step ``k`` is the state
    after the ``k``-th action (1..80). The per-scenario frame has Table I's columns, then the
    registry's (NaN where ``outputs.scenario`` lacks them).
    """
    arrays = {f: np.asarray(getattr(outputs, f)) for f in StepOutputs.FIELDS}
    episode = {k: np.asarray(v, float) for k, v in (outputs.scenario or {}).items()}
    if arrays["valid"].ndim == 2:
        arrays = {k: v[None] for k, v in arrays.items()}
        episode = {k: v[None] for k, v in episode.items()}
    valid = arrays["valid"]
    num_seeds, num_scenarios, num_steps = valid.shape
    if len(seeds) != num_seeds or len(scenario_ids) != num_scenarios:
        raise ValueError("seeds / scenario_ids do not match the outputs' shape")
    step_rows, scen_rows = [], []
    for si, seed in enumerate(seeds):
        v = valid[si]
        ld, ov, off = (arrays[k][si] for k in ("log_divergence", "overlap", "offroad"))
        per_step = {k: _masked_mean(a, v, axis=0) for k, a in
                    (("log_divergence", ld), ("overlap", ov), ("offroad", off))}
        for k in range(num_steps):
            step_rows.append((setting, method, seed, k + 1, per_step["log_divergence"][k],
                              per_step["overlap"][k], per_step["offroad"][k]))
        max_ld = np.where(v, ld, -np.inf).max(axis=1)
        any_ov = (np.where(v, ov, 0.0) > 0).any(axis=1)
        any_off = (np.where(v, off, 0.0) > 0).any(axis=1)
        mean_ld, frac_ov, frac_off = (_masked_mean(a, v, axis=1) for a in (ld, ov, off))
        for i, sid in enumerate(scenario_ids):
            if not v[i].any():
                continue  # the logged SDC is never valid: nothing to score
            row = dict(zip(PER_SCENARIO_COLUMNS, (
                setting, method, seed, sid, float(max_ld[i]), float(any_ov[i]),
                float(any_off[i]), float(mean_ld[i]), float(frac_ov[i]), float(frac_off[i])),
                strict=True))
            row.update({k: float(episode[k][si, i]) if k in episode else float("nan")
                        for k in registry.episode_keys()})
            scen_rows.append(registry.derive_row(row))
    return (pd.DataFrame(step_rows, columns=list(PER_STEP_COLUMNS)),
            pd.DataFrame(scen_rows, columns=list(registry.scenario_columns())))


def with_origins(per_scenario: pd.DataFrame, origins: list[dict] | None) -> pd.DataFrame:
    """``per_scenario`` with the :data:`~igdrivsim.evaluation.schema.ORIGIN_COLUMNS` last: each
    row's source log and whether its ego is the logged SDC, from the reader's ``origins``
    (:func:`igdrivsim.data.validation.origin_of`, one per scenario id); without them (scenarios
    given stacked) the source is the id's scenario part and ``logged_sdc`` unknown (empty)."""
    by_id = {o["scenario_id"]: o for o in origins or ()}
    ids = per_scenario["scenario_id"].astype(str)
    source = ids.map(lambda s: by_id[s]["source"] if s in by_id else split_ego_id(s)[0])
    logged = ids.map(lambda s: float(by_id[s]["logged_sdc"]) if s in by_id else float("nan"))
    return per_scenario.assign(**{SOURCE_COLUMN: source, LOGGED_SDC_COLUMN: logged})


def scenario_ids_of(scenarios) -> list[str]:
    """Decoded scenario ids of stacked scenarios ``[N]``."""
    ids = np.asarray(scenarios.scenario_id)
    return [decode_scenario_id(row) for row in ids]


def reference_frames(scenarios, params: SimParams = DEFAULT_SIM_PARAMS, batch_size: int = 32,
                     metrics_fn: Callable | None = None, progress=None
                     ) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Tidy frames of both reference actors (setting ``none``, seed 0)."""
    ids = scenario_ids_of(scenarios)
    steps, scens = [], []
    for name in REFERENCE_ACTORS:
        outs = evaluate_reference(scenarios, name, params, batch_size, metrics_fn, progress)
        a, b = tidy_frames(outs, ids, REFERENCE_SETTING, name, [0])
        steps.append(a)
        scens.append(b)
    return pd.concat(steps, ignore_index=True), pd.concat(scens, ignore_index=True)


__all__ = [
    "EVAL_SEED", "REFERENCE_ACTORS", "StepOutputs", "evaluate_policy", "evaluate_reference",
    "reference_frames",
    "scenario_ids_of", "tidy_frames", "with_origins",
]
