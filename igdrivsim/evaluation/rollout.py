"""Closed-loop evaluation rollouts (:mod:`igdrivsim.policy.closed_loop`, with the registry's
episode metrics) -> tidy per-step and per-scenario frames in the columns of
:mod:`igdrivsim.evaluation.schema` and :mod:`igdrivsim.evaluation.registry`."""

from __future__ import annotations

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
from igdrivsim.policy.closed_loop import DEFAULT_SIM_PARAMS, REFERENCE_ACTORS, StepOutputs
from igdrivsim.simulator import SimParams


def _masked_mean(x: np.ndarray, valid: np.ndarray, axis: int) -> np.ndarray:
    count = valid.sum(axis=axis)
    total = np.where(valid, x, 0.0).sum(axis=axis)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, total / np.maximum(count, 1), np.nan)


def tidy_frames(outputs: StepOutputs, scenario_ids: list[str], setting: str, method: str,
                seeds: list[int]) -> tuple[pd.DataFrame, pd.DataFrame]:
    """``(per_step, per_scenario)`` frames in the schema's column order from ``outputs``
    ``[S, N, steps]``; per-step rows average the valid steps over scenarios, step ``k`` being
    the state after the ``k``-th action."""
    arrays = {f: np.asarray(getattr(outputs, f)) for f in StepOutputs.FIELDS}
    episode = {k: np.asarray(v, float) for k, v in (outputs.scenario or {}).items()}
    valid = arrays["valid"]
    num_seeds, num_scenarios, num_steps = valid.shape
    if len(seeds) != num_seeds or len(scenario_ids) != num_scenarios:
        raise ValueError("seeds / scenario_ids do not match the outputs' shape")
    step_rows, scen_rows = [], []
    for si, seed in enumerate(seeds):
        v = valid[si]
        ld, ov, off = (arrays[k][si] for k in ("log_divergence", "overlap", "offroad"))
        step_ld, step_ov, step_off = (_masked_mean(a, v, axis=0) for a in (ld, ov, off))
        step_rows += [(setting, method, seed, k + 1, step_ld[k], step_ov[k], step_off[k])
                      for k in range(num_steps)]
        max_ld = np.where(v, ld, -np.inf).max(axis=1)
        any_ov, any_off = ((np.where(v, a, 0.0) > 0).any(axis=1) for a in (ov, off))
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
    """``per_scenario`` with each row's source log and whether its ego is the logged SDC last,
    from the reader's ``origins`` (without them: the id's scenario part, and unknown)."""
    by_id = {o["scenario_id"]: o for o in origins or ()}
    ids = per_scenario["scenario_id"].astype(str)
    source = ids.map(lambda s: by_id[s]["source"] if s in by_id else split_ego_id(s)[0])
    logged = ids.map(lambda s: float(by_id[s]["logged_sdc"]) if s in by_id else float("nan"))
    return per_scenario.assign(**{SOURCE_COLUMN: source, LOGGED_SDC_COLUMN: logged})


def scenario_ids_of(scenarios) -> list[str]:
    """Decoded scenario ids of stacked scenarios ``[N]``."""
    return [decode_scenario_id(row) for row in np.asarray(scenarios.scenario_id)]


def reference_frames(scenarios, params: SimParams = DEFAULT_SIM_PARAMS, batch_size: int = 32,
                     progress=None) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Tidy frames of both reference actors (setting ``none``, seed 0)."""
    ids = scenario_ids_of(scenarios)
    frames = []
    for name in REFERENCE_ACTORS:
        outs = closed_loop.evaluate_reference(scenarios, name, params, batch_size,
                                              progress=progress,
                                              episode_metrics=registry.episode_values)
        frames.append(tidy_frames(outs.map(lambda a: a[None]), ids, REFERENCE_SETTING, name,
                                  [0]))
    steps, scens = zip(*frames, strict=True)
    return pd.concat(steps, ignore_index=True), pd.concat(scens, ignore_index=True)
