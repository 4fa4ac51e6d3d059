"""Aggregate tidy evaluation CSVs across seeds: means, 95% confidence intervals, BC-RL vs BC tests.

Statistics used, and why:

- **Mean and 95% CI over seeds.** Each seed (one independently trained policy) gives one
  number per metric: its mean over the validation scenarios. The table reports the mean of the
  seed means and a t-distribution interval over them (``n - 1`` degrees of freedom), which is
  what "mean over three seeds with 95% CI" means in the paper.
- **Significance: paired sign-flip permutation test over scenarios** (two-sided, alpha 0.05).
  BC and BC-RL are evaluated on the *same* validation scenarios, and scenario difficulty is by
  far the largest source of variance, so pairing by scenario is the powerful comparison. Each
  scenario's value is first averaged over the seeds (one independent pair per scenario), then
  the mean paired difference is compared with its distribution under random sign flips, which
  is exact under the null "the two methods are exchangeable on each scenario" and needs no
  normality: the metrics are binary (overlap/offroad rates) or heavy-tailed (max divergence).
  It conditions on the trained seeds, i.e. it asks whether *these* policies differ; as a check
  on training-seed variance, Welch's t-test over the seed means (about 4 degrees of freedom
  with 3 seeds, so low power) is reported alongside in ``summary.csv``.

The permutation test uses a fixed random seed so that running the pipeline twice produces the
same tables.
"""

from __future__ import annotations

import warnings
from collections.abc import Iterable
from pathlib import Path

import numpy as np
import pandas as pd
from scipy import stats

from igdrivsim.errors import DataError
from igdrivsim.evaluation.schema import (
    BC,
    BC_RL,
    METRICS,
    PER_SCENARIO_COLUMNS,
    PER_STEP_COLUMNS,
)

ALPHA = 0.05
CONFIDENCE = 0.95
TEST_NAME = "paired sign-flip permutation test over scenarios (seed-averaged), two-sided"
TEST_SHORT = "paired permutation test"
N_RESAMPLES = 10_000
TEST_SEED = 0


def read_csv_checked(path: str | Path, columns: Iterable[str]) -> pd.DataFrame:
    """Read a tidy CSV and check that it has ``columns``; DataError names the file otherwise."""
    path = Path(path)
    try:
        frame = pd.read_csv(path, dtype={"setting": str, "method": str, "scenario_id": str})
    except (OSError, pd.errors.ParserError, pd.errors.EmptyDataError) as err:
        raise DataError(f"cannot read CSV ({err})", file=str(path)) from err
    missing = [c for c in columns if c not in frame.columns]
    if missing:
        raise DataError(f"missing columns {missing}", file=str(path))
    return frame


def load_evaluations(paths: Iterable[str | Path]) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Concatenate every ``per_step.csv`` / ``per_scenario.csv`` under the given folders.

    A folder may hold the CSVs itself or in sub-folders (one per evaluated run). Returns
    ``(per_step, per_scenario)``; raises :class:`DataError` when nothing is found.
    """
    steps, scenarios = [], []
    for root in map(Path, paths):
        if not root.exists():
            raise DataError("evaluation folder does not exist", file=str(root))
        for csv in sorted(root.rglob("per_step.csv")):
            steps.append(read_csv_checked(csv, PER_STEP_COLUMNS))
        for csv in sorted(root.rglob("per_scenario.csv")):
            scenarios.append(read_csv_checked(csv, PER_SCENARIO_COLUMNS))
    if not scenarios:
        raise DataError("no per_scenario.csv found", file=", ".join(map(str, paths)))
    per_step = pd.concat(steps, ignore_index=True) if steps else pd.DataFrame(
        columns=PER_STEP_COLUMNS)
    per_scenario = pd.concat(scenarios, ignore_index=True)
    key = ["setting", "method", "seed", "scenario_id"]
    per_scenario = per_scenario.drop_duplicates(key, keep="last")
    per_step = per_step.drop_duplicates(["setting", "method", "seed", "step"], keep="last")
    return per_step, per_scenario


def seed_means(per_scenario: pd.DataFrame) -> pd.DataFrame:
    """Long table ``setting, method, seed, metric, value``: each seed's mean over scenarios,
    scaled as in Table I (percent for the rates)."""
    rows = []
    grouped = per_scenario.groupby(["setting", "method", "seed"], sort=True)
    for metric in METRICS:
        values = grouped[metric.column].mean() * metric.scale
        part = values.rename("value").reset_index()
        part["metric"] = metric.key
        rows.append(part)
    out = pd.concat(rows, ignore_index=True)
    return out[["setting", "method", "seed", "metric", "value"]]


def t_interval(values: np.ndarray, confidence: float = CONFIDENCE) -> tuple[float, float, float]:
    """Mean and two-sided t-distribution confidence interval; NaN bounds for a single value."""
    values = np.asarray(values, dtype=float)
    mean = float(values.mean()) if values.size else float("nan")
    if values.size < 2:
        return mean, float("nan"), float("nan")
    half = stats.t.ppf(0.5 + confidence / 2, values.size - 1) * values.std(ddof=1) / np.sqrt(
        values.size)
    return mean, mean - float(half), mean + float(half)


def paired_permutation_test(x: np.ndarray, y: np.ndarray, n_resamples: int = N_RESAMPLES,
                            seed: int = TEST_SEED) -> float:
    """Two-sided p-value of the paired sign-flip permutation test of ``mean(x - y) == 0``.

    Exact (all sign patterns) when there are few pairs, Monte Carlo with a fixed seed otherwise.
    """
    x, y = np.asarray(x, float), np.asarray(y, float)
    if x.shape != y.shape or x.ndim != 1:
        raise ValueError("paired test needs two 1-D arrays of equal length")
    if x.size == 0:
        return float("nan")
    if np.allclose(x, y):
        return 1.0
    result = stats.permutation_test(
        (x, y), lambda a, b, axis: np.mean(a - b, axis=axis), permutation_type="samples",
        vectorized=True, n_resamples=n_resamples, alternative="two-sided",
        rng=np.random.default_rng(seed),
    )
    return float(result.pvalue)


def welch_test(x: np.ndarray, y: np.ndarray) -> float:
    """Two-sided p-value of Welch's t-test (NaN with fewer than two values a side)."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    if x.size < 2 or y.size < 2:
        return float("nan")
    if np.allclose(x, x.mean()) and np.allclose(y, y.mean()):
        return 1.0 if np.isclose(x.mean(), y.mean()) else 0.0
    with warnings.catch_warnings():  # near-identical seeds: scipy warns about precision
        warnings.simplefilter("ignore", RuntimeWarning)
        return float(stats.ttest_ind(x, y, equal_var=False).pvalue)


def summarize(per_scenario: pd.DataFrame, confidence: float = CONFIDENCE) -> pd.DataFrame:
    """One row per ``(metric, setting, method)``: mean over seeds, CI bounds, counts."""
    means = seed_means(per_scenario)
    counts = per_scenario.groupby(["setting", "method"]).agg(
        n_seeds=("seed", "nunique"), n_scenarios=("scenario_id", "nunique"))
    rows = []
    for (metric, setting, method), part in means.groupby(["metric", "setting", "method"]):
        mean, low, high = t_interval(part["value"].to_numpy(), confidence)
        n = counts.loc[(setting, method)]
        rows.append(dict(metric=metric, setting=setting, method=method, mean=mean, ci_low=low,
                         ci_high=high, n_seeds=int(n.n_seeds), n_scenarios=int(n.n_scenarios)))
    return pd.DataFrame(rows)


def compare_methods(per_scenario: pd.DataFrame, a: str = BC_RL, b: str = BC,
                    alpha: float = ALPHA, n_resamples: int = N_RESAMPLES) -> pd.DataFrame:
    """Test ``a`` against ``b`` per setting and metric (see the module docstring).

    Returns ``metric, setting, mean_a, mean_b, diff, p_value, p_welch, significant, better``
    where ``better`` is the method with the lower value when the difference is significant
    (every Table I metric is lower-is-better), else ``""``.
    """
    means = seed_means(per_scenario)
    rows = []
    settings = sorted(set(per_scenario.loc[per_scenario.method == a, "setting"])
                      & set(per_scenario.loc[per_scenario.method == b, "setting"]))
    for setting in settings:
        sub = per_scenario[per_scenario.setting == setting]
        for metric in METRICS:
            by_scenario = sub.groupby(["method", "scenario_id"])[metric.column].mean()
            xa, xb = by_scenario.loc[a], by_scenario.loc[b]
            common = xa.index.intersection(xb.index)
            x = xa.loc[common].to_numpy() * metric.scale
            y = xb.loc[common].to_numpy() * metric.scale
            p = paired_permutation_test(x, y, n_resamples=n_resamples)
            cell = means[(means.setting == setting) & (means.metric == metric.key)]
            sa, sb = cell[cell.method == a], cell[cell.method == b]
            mean_a, mean_b = float(sa.value.mean()), float(sb.value.mean())
            significant = bool(p < alpha)
            better = "" if not significant else (a if mean_a < mean_b else b)
            rows.append(dict(metric=metric.key, setting=setting, mean_a=mean_a, mean_b=mean_b,
                             diff=mean_a - mean_b, p_value=p,
                             p_welch=welch_test(sa.value.to_numpy(), sb.value.to_numpy()),
                             n_pairs=int(common.size), significant=significant, better=better))
    return pd.DataFrame(rows)
