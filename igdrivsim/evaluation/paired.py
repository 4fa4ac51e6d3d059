"""Paired statistics of a driver against a reference ego by ego, that survive heavy tails (on
real logs a few egos diverge by 15 m or more, so a mean difference has little power):

- **Win share**: the share of (ego, seed) pairs where the driver's log divergence is below the
  reference's on the same ego (a tie counts one half).
- **Median paired difference** over egos of ``driver - reference`` (the driver's seed mean).
- **Mean ratio** of the driver's mean to the reference's and the mean difference ``diff``, with
  their minimum detectable effects.

95% percentile intervals come from a **hierarchical bootstrap**: source scenarios (every ego of
a drawn source), then the driver's seeds; the reference is its mean over seeds per ego. Where
the driver wins on every ego or on none, the win share's interval is Wilson's, one trial per
source. An ego's source is the ``source`` column, else :func:`source_of` its ``scenario_id``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pandas as pd
from scipy import stats

from igdrivsim.evaluation.aggregate import (
    CONFIDENCE,
    N_RESAMPLES,
    TEST_SEED,
    minimum_detectable_effect,
    resample_counts,
    statistic_seed,
)
from igdrivsim.evaluation.schema import REFERENCE_SETTING, SOURCE_COLUMN

_CHUNK = 500  # resamples per block: bounds memory at CHUNK x n_egos floats (a few arrays)
# the statistics, in the order of their columns (each with _lo, _hi; all but median with _mde)
STATISTICS = ("win", "median", "ratio", "diff")


def source_of(scenario_id: str) -> str:
    """The source scenario of an ego id ``<scenario id>#<object id>`` (itself without one)."""
    from igdrivsim.data.scenario import split_ego_id  # lazy: the tables import without JAX

    return split_ego_id(str(scenario_id))[0]


def sources(frame: pd.DataFrame) -> pd.Series:
    """Each row's source scenario: its ``source`` column, else :func:`source_of` its id."""
    ids = frame["scenario_id"].astype(str)
    given = frame.get(SOURCE_COLUMN, pd.Series(float("nan"), index=frame.index))
    missing = given.isna() | (given.astype(str) == "")
    if not missing.any():
        return given.astype(str)
    return given.astype(str).where(~missing, ids.map(source_of))


def source_map(frame: pd.DataFrame) -> dict[str, str]:
    """``{scenario_id: source scenario}`` of a frame's rows (see :func:`sources`)."""
    return dict(zip(frame["scenario_id"].astype(str), sources(frame), strict=True))


def weighted_median(values: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Row-wise median of ``values`` ``(B, n)`` with integer ``weights`` (counts): the mean of
    the lower and upper weighted medians, as :func:`numpy.median` for unit weights."""
    order = np.argsort(values, axis=1, kind="stable")
    v = np.take_along_axis(values, order, axis=1)
    cum = np.cumsum(np.take_along_axis(weights, order, axis=1), axis=1)
    half = cum[:, -1:] / 2
    lower = np.argmax(cum >= half, axis=1)
    upper = np.argmax(cum > half, axis=1)
    rows = np.arange(values.shape[0])
    return (v[rows, lower] + v[rows, upper]) / 2


def _statistics(driver: np.ndarray, wins: np.ndarray, reference: np.ndarray,
                seed_counts: np.ndarray, ego_counts: np.ndarray) -> np.ndarray:
    """``(B, 4)``: win share, median difference, mean ratio and mean difference under ``B``
    weightings of the driver's seeds ``(B, S)`` and the egos ``(B, E)``."""
    n_seeds = seed_counts.sum(axis=1, keepdims=True)
    per_ego = seed_counts @ driver / n_seeds  # (B, E): the driver's seed mean on each ego
    win_ego = seed_counts @ wins / n_seeds
    total = ego_counts.sum(axis=1)
    win = (ego_counts * win_ego).sum(axis=1) / total
    median = weighted_median(per_ego - reference, ego_counts)
    driver_mean = (ego_counts * per_ego).sum(axis=1)
    reference_mean = ego_counts @ reference
    ratio = driver_mean / reference_mean
    return np.stack([win, median, ratio, (driver_mean - reference_mean) / total], axis=1)


def paired_ego_statistics(driver: np.ndarray, reference: np.ndarray, source: Sequence,
                          n_resamples: int = N_RESAMPLES, seed: int | Sequence[int] = TEST_SEED
                          ) -> dict[str, float]:
    """Win share, median paired difference, mean ratio and mean difference of ``driver``
    ``(seeds, egos)`` against ``reference`` ``(egos,)``, each with ``_lo``,
    ``_hi`` (and but the median ``_mde``), and ``n_egos``, ``n_sources``, ``n_seeds``; egos of
    one ``source`` are resampled together (see the module docstring)."""
    driver = np.atleast_2d(np.asarray(driver, float))
    reference = np.asarray(reference, float)
    codes, uniques = pd.factorize(pd.Series(list(source), dtype=object), sort=True)
    n_seeds, n_egos = driver.shape
    if reference.shape != (n_egos,) or codes.shape != (n_egos,):
        raise ValueError("driver (seeds, egos), reference (egos,) and source (egos,) must "
                         "agree on the egos")
    out: dict[str, float] = dict(n_egos=n_egos, n_sources=len(uniques), n_seeds=n_seeds)
    keys = [f"{s}{k}" for s in STATISTICS for k in ("", "_lo", "_hi")] + [
        "win_mde", "ratio_mde", "diff_mde"]
    if n_egos == 0 or n_seeds == 0:
        return out | dict.fromkeys(keys, float("nan"))
    wins = (driver < reference) + 0.5 * (driver == reference)
    point = _statistics(driver, wins, reference, np.ones((1, n_seeds)), np.ones((1, n_egos)))[0]
    rng = np.random.default_rng(seed)
    reps = np.empty((n_resamples, len(STATISTICS)))
    with np.errstate(invalid="ignore", divide="ignore"):  # a zero reference mean: inf ratio
        for start in range(0, n_resamples, _CHUNK):
            m = min(_CHUNK, n_resamples - start)
            ego_counts = resample_counts(rng, m, len(uniques))[:, codes]
            reps[start:start + m] = _statistics(driver, wins, reference,
                                                resample_counts(rng, m, n_seeds), ego_counts)
    q = [100 * (1 - CONFIDENCE) / 2, 100 * (1 + CONFIDENCE) / 2]
    lo, hi = np.nanpercentile(reps, q, axis=0)
    se = np.nanstd(np.where(np.isfinite(reps), reps, np.nan), axis=0, ddof=1)
    for i, name in enumerate(STATISTICS):
        out |= {name: float(point[i]), f"{name}_lo": float(lo[i]), f"{name}_hi": float(hi[i])}
    if point[0] in (0.0, 1.0):  # every resample agrees: the percentile interval is a point
        out["win_lo"], out["win_hi"] = wilson_interval(point[0], len(uniques))
    out |= {f"{name}_mde": float(minimum_detectable_effect(se[i]))
            for i, name in enumerate(STATISTICS) if name != "median"}
    return out


def wilson_interval(share: float, n: int) -> tuple[float, float]:
    """Wilson score interval of a binomial ``share`` observed on ``n`` trials."""
    z = stats.norm.ppf(0.5 + CONFIDENCE / 2)
    centre = (share + z * z / (2 * n)) / (1 + z * z / n)
    half = z / (1 + z * z / n) * np.sqrt(share * (1 - share) / n + z * z / (4 * n * n))
    lo = 0.0 if share <= 0 else max(0.0, centre - half)  # exact ends at a share of 0 or 1
    hi = 1.0 if share >= 1 else min(1.0, centre + half)
    return float(lo), float(hi)


def ego_arrays(per_scenario: pd.DataFrame, setting: str, method: str, reference: str,
               column: str = "log_divergence") -> tuple[np.ndarray, np.ndarray, list[str]]:
    """``(driver (seeds, egos), reference (egos,), sources)`` of one ``column``: ``method`` in
    ``setting`` against ``reference`` (in :data:`REFERENCE_SETTING` when not in ``setting``),
    on the egos every seed of both has a value for, in id order."""
    ours = per_scenario[(per_scenario.setting == setting) & (per_scenario.method == method)]
    ref = per_scenario[per_scenario.method == reference]
    if (ref.setting == setting).any():
        ref = ref[ref.setting == setting]
    elif (ref.setting == REFERENCE_SETTING).any():
        ref = ref[ref.setting == REFERENCE_SETTING]
    if ours.empty or ref.empty:
        return np.zeros((0, 0)), np.zeros(0), []
    a, b = (f.pivot_table(index="seed", columns="scenario_id", values=column, aggfunc="mean",
                          dropna=False) for f in (ours, ref))
    egos = sorted(set(a.columns[a.notna().all(axis=0)]) & set(b.columns[b.notna().all(axis=0)]))
    source = source_map(pd.concat([ours, ref]))
    return (a[egos].to_numpy(float).reshape(len(a), len(egos)),
            b[egos].to_numpy(float).mean(axis=0),
            [source[str(e)] for e in egos])


def compare_on_egos(per_scenario: pd.DataFrame, setting: str, method: str, reference: str,
                    column: str = "log_divergence", n_resamples: int = N_RESAMPLES
                    ) -> dict[str, float]:
    driver, ref, source = ego_arrays(per_scenario, setting, method, reference, column)
    return paired_ego_statistics(driver, ref, source, n_resamples,
                                 statistic_seed(setting, method, reference, column))
