"""Aggregate tidy evaluation CSVs across seeds: means, 95% confidence intervals, effects vs BC.

- **Mean and 95% CI**: each seed's mean over the scenarios, then a t interval (``n - 1``
  degrees of freedom) over the seed means: the paper's "mean over three seeds with 95% CI".
- **Effect vs BC, two-level bootstrap**: seeds resampled within each method, then scenarios with
  the *same* ids for both methods and every seed (scenario difficulty is the largest variance);
  the percentile interval of ``N_RESAMPLES`` replicates and the add-one smoothed p-value
  ``2 min(P*(d <= 0), P*(d >= 0))`` (3 seeds make the seed level coarse, slightly optimistic).
- **Holm over every cell** (settings x metrics x methods): significant (bold in Table I) when
  the adjusted p is below ``ALPHA``; minimum detectable effect ``(z_{1-a/2} + z_{0.8}) * SE``
  at ``ALPHA`` (``mde``) and at ``ALPHA / n_cells`` (``mde_holm``).

A fixed seed per setting makes the tables reproducible; Welch's t-test over the seed means
is kept in ``tests.csv`` as a check.
"""

from __future__ import annotations

import warnings
import zlib
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np
import pandas as pd
from scipy import stats

from igdrivsim.errors import DataError
from igdrivsim.evaluation.schema import (
    METRICS,
    PER_SCENARIO_COLUMNS,
    PER_SCENARIO_FILE,
    PER_STEP_COLUMNS,
    PER_STEP_FILE,
    Metric,
)
from igdrivsim.names import BC, REFERENCES

ALPHA = 0.05
CONFIDENCE = 0.95
POWER = 0.8
TEST_NAME = ("two-level bootstrap over seeds and paired scenarios, two-sided, "
             "Holm-corrected over all cells")
N_RESAMPLES = 10_000
TEST_SEED = 0
_CHUNK = 2_000  # resamples per block: bounds memory at CHUNK x n_scenarios counts


def read_csv_checked(path: str | Path, columns: Iterable[str],
                     complete: Iterable[str] = ()) -> pd.DataFrame:
    """Read a tidy CSV checked for ``columns``, a whole last row and values in every row for the
    ``complete`` columns (identifiers); a DataError names the file and row otherwise."""
    path = Path(path)
    try:  # pandas ends each row with a line end: a file without one was cut off
        cut_off = path.read_bytes()[-1:] not in (b"", b"\n")
    except OSError as err:
        raise DataError(f"cannot read CSV ({err})", file=str(path)) from err
    if cut_off:
        raise DataError("the last row is cut off (no line end); rerun what wrote it",
                        file=str(path))
    try:
        frame = pd.read_csv(path, dtype={"setting": str, "method": str, "scenario_id": str})
    except (OSError, pd.errors.ParserError, pd.errors.EmptyDataError) as err:
        raise DataError(f"cannot read CSV ({err})", file=str(path)) from err
    missing = [c for c in columns if c not in frame.columns]
    if missing:
        raise DataError(f"missing columns {missing}", file=str(path))
    complete = [c for c in complete if c in frame.columns]
    empty = frame[complete].isna()
    if empty.to_numpy().any():
        row = int(np.flatnonzero(empty.any(axis=1).to_numpy())[0])
        blank = [c for c in complete if empty[c].iloc[row]]
        raise DataError(f"row {row + 1} after the header has no value for {blank} "
                        "(file cut off or edited?)", file=str(path))
    return frame


def load_evaluations(paths: Iterable[str | Path]) -> tuple[pd.DataFrame, pd.DataFrame]:
    """``(per_step, per_scenario)``: every ``per_step.csv`` / ``per_scenario.csv`` under the
    folders (or their sub-folders) concatenated; a :class:`DataError` when none is found."""
    steps, scenarios = [], []
    for root in map(Path, paths):
        if not root.exists():
            raise DataError("evaluation folder does not exist", file=str(root))
        for csv in sorted(root.rglob(PER_STEP_FILE)):
            steps.append(read_csv_checked(csv, PER_STEP_COLUMNS))
        for csv in sorted(root.rglob(PER_SCENARIO_FILE)):
            scenarios.append(read_csv_checked(csv, PER_SCENARIO_COLUMNS,
                                              complete=PER_SCENARIO_COLUMNS[:4]))
    if not scenarios:
        raise DataError(f"no {PER_SCENARIO_FILE} found", file=", ".join(map(str, paths)))
    per_step = pd.concat(steps, ignore_index=True) if steps else pd.DataFrame(
        columns=PER_STEP_COLUMNS)
    per_scenario = pd.concat(scenarios, ignore_index=True)
    return (per_step.drop_duplicates(["setting", "method", "seed", "step"], keep="last"),
            per_scenario.drop_duplicates(["setting", "method", "seed", "scenario_id"], keep="last"))


def seed_means(per_scenario: pd.DataFrame, metrics: Sequence = METRICS) -> pd.DataFrame:
    """Long table ``setting, method, seed, metric, value``: each seed's mean over scenarios at
    Table I's scale (``metrics``: Table I's or the registry's; a missing column is skipped)."""
    grouped = per_scenario.groupby(["setting", "method", "seed"], sort=True)
    rows = [(grouped[m.column].mean() * m.scale).rename("value").reset_index().assign(metric=m.key)
            for m in metrics if m.column in per_scenario.columns]  # else evaluated before it
    columns = ["setting", "method", "seed", "metric", "value"]
    return pd.concat(rows, ignore_index=True)[columns] if rows else pd.DataFrame(columns=columns)


def t_interval(values: np.ndarray) -> tuple[float, float, float]:
    """Mean and two-sided :data:`CONFIDENCE` t-interval; NaN bounds for a single value."""
    values = np.asarray(values, dtype=float)
    mean = float(values.mean()) if values.size else float("nan")
    if values.size < 2:
        return mean, float("nan"), float("nan")
    half = stats.t.ppf(0.5 + CONFIDENCE / 2, values.size - 1) * values.std(ddof=1) / np.sqrt(
        values.size)
    return mean, mean - float(half), mean + float(half)


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


def summarize(per_scenario: pd.DataFrame, metrics: Sequence = METRICS) -> pd.DataFrame:
    """One row per ``(metric, setting, method)``: mean over seeds, CI bounds and counts."""
    means = seed_means(per_scenario, metrics)
    counts = per_scenario.groupby(["setting", "method"]).agg(
        n_seeds=("seed", "nunique"), n_scenarios=("scenario_id", "nunique"))
    rows = []
    for (metric, setting, method), part in means.groupby(["metric", "setting", "method"]):
        mean, low, high = t_interval(part["value"].to_numpy())
        n = counts.loc[(setting, method)]
        rows.append(dict(metric=metric, setting=setting, method=method, mean=mean, ci_low=low,
                         ci_high=high, n_seeds=int(n.n_seeds), n_scenarios=int(n.n_scenarios)))
    return pd.DataFrame(rows, columns=["metric", "setting", "method", "mean", "ci_low",
                                       "ci_high", "n_seeds", "n_scenarios"])


def resample_counts(rng: np.random.Generator, n_resamples: int, n: int) -> np.ndarray:
    """``(n_resamples, n)`` integer counts of each of ``n`` items in a resample of size ``n``."""
    idx = rng.integers(0, n, size=(n_resamples, n)) + n * np.arange(n_resamples)[:, None]
    return np.bincount(idx.ravel(), minlength=n_resamples * n).reshape(n_resamples, n)


def hierarchical_bootstrap(xa: np.ndarray, xb: np.ndarray, n_resamples: int = N_RESAMPLES,
                           seed: int | Sequence[int] = TEST_SEED,
                           clusters: Sequence | None = None) -> np.ndarray:
    """``(n_resamples, k)`` bootstrap replicates of ``mean(xa) - mean(xb)``, ``xa``/``xb``
    ``(seeds, scenarios, k)`` over the same scenarios: seeds resampled within each method, one
    scenario resample shared by both (whole ``clusters`` of scenarios from one scene, when
    given). A resample's grand mean is ``w_seed @ X @ w_scenario``."""
    xa, xb = np.asarray(xa, float), np.asarray(xb, float)
    if xa.ndim == 2:
        xa, xb = xa[..., None], xb[..., None]
    if xa.shape[1:] != xb.shape[1:]:
        raise ValueError("xa and xb need the same scenarios and metrics")
    (sa, n, k), sb = xa.shape, xb.shape[0]
    codes, n_clusters = None, n
    if clusters is not None:
        codes, uniques = pd.factorize(pd.Series(list(clusters), dtype=object), sort=True)
        if codes.shape != (n,):
            raise ValueError("clusters needs one entry per scenario")
        codes, n_clusters = (None, n) if len(uniques) == n else (codes, len(uniques))
    rng = np.random.default_rng(seed)
    flat_a = xa.transpose(1, 0, 2).reshape(n, sa * k)  # scenario x (seed, metric)
    flat_b = xb.transpose(1, 0, 2).reshape(n, sb * k)
    out = np.empty((n_resamples, k))
    for start in range(0, n_resamples, _CHUNK):
        m = min(_CHUNK, n_resamples - start)
        w_scen = resample_counts(rng, m, n_clusters) / n_clusters
        if codes is not None:  # every scenario of a drawn cluster, weights summing to one
            w_scen = w_scen[:, codes]
            w_scen /= w_scen.sum(axis=1, keepdims=True)
        w_a, w_b = resample_counts(rng, m, sa) / sa, resample_counts(rng, m, sb) / sb
        ya = (w_scen @ flat_a).reshape(m, sa, k)  # each seed's mean over resampled scenarios
        yb = (w_scen @ flat_b).reshape(m, sb, k)
        out[start:start + m] = (np.einsum("ms,msk->mk", w_a, ya)
                                - np.einsum("ms,msk->mk", w_b, yb))
    return out


def bootstrap_p_value(replicates: np.ndarray) -> np.ndarray:
    """Two-sided bootstrap p-value of "difference = 0" per column:
    ``2 min(P(d <= 0), P(d >= 0))`` with add-one smoothing, capped at 1."""
    replicates = np.asarray(replicates, float)
    b = replicates.shape[0]
    low = ((replicates <= 0).sum(axis=0) + 1) / (b + 1)
    high = ((replicates >= 0).sum(axis=0) + 1) / (b + 1)
    return np.minimum(1.0, 2 * np.minimum(low, high))


def paired_difference(a: np.ndarray, b: np.ndarray, n_resamples: int = N_RESAMPLES,
                      seed: int | Sequence[int] = TEST_SEED, clusters: Sequence | None = None
                      ) -> dict[str, np.ndarray]:
    """``a - b`` over the same scenarios per metric: the means, the difference, its
    :func:`hierarchical_bootstrap` interval, standard error, p-value and minimum detectable
    effect."""
    reps = hierarchical_bootstrap(a, b, n_resamples, seed, clusters)
    lo, hi = np.percentile(reps, [100 * (1 - CONFIDENCE) / 2, 100 * (1 + CONFIDENCE) / 2], axis=0)
    se = reps.std(axis=0, ddof=1)
    return dict(a=a.mean((0, 1)), b=b.mean((0, 1)), diff=a.mean((0, 1)) - b.mean((0, 1)),
                lo=lo, hi=hi, se=se, p=bootstrap_p_value(reps),
                mde=minimum_detectable_effect(se))


def holm_adjust(p_values: Sequence[float] | np.ndarray) -> np.ndarray:
    """Holm step-down adjusted p-values (NaN entries stay NaN and are not counted)."""
    p = np.asarray(p_values, float)
    out = np.full_like(p, np.nan)
    ok = np.flatnonzero(np.isfinite(p))
    order = ok[np.argsort(p[ok], kind="stable")]
    m = order.size
    adjusted = np.maximum.accumulate((m - np.arange(m)) * p[order])
    out[order] = np.minimum(1.0, adjusted)
    return out


def minimum_detectable_effect(se: float | np.ndarray, alpha: float = ALPHA) -> float | np.ndarray:
    """Smallest true difference a two-sided level-``alpha`` test detects with ``POWER``,
    for an estimate with standard error ``se`` (normal approximation)."""
    return (stats.norm.ppf(1 - alpha / 2) + stats.norm.ppf(POWER)) * np.asarray(se, float)


def statistic_seed(*names: str) -> list[int]:
    """A fixed bootstrap seed per comparison (independent of which others were made)."""
    return [TEST_SEED, zlib.crc32("/".join(names).encode())]


def scenario_cube(sub: pd.DataFrame, method: str, scenarios: pd.Index,
                  metrics: Sequence[Metric] = METRICS) -> np.ndarray:
    """``(seeds, scenarios, metrics)`` array of one method's values at the metrics' scale, NaN
    where a seed lacks a scenario."""
    cols = [m.column for m in metrics]
    scale = np.array([m.scale for m in metrics])
    part = sub[sub.method == method].set_index(["seed", "scenario_id"])[cols]
    seeds = sorted(part.index.get_level_values(0).unique())
    full = pd.MultiIndex.from_product([seeds, scenarios], names=["seed", "scenario_id"])
    return part.reindex(full).to_numpy(float).reshape(len(seeds), len(scenarios), -1) * scale


def complete_scenarios(sub: pd.DataFrame, methods: Sequence[str],
                       metrics: Sequence[Metric] = METRICS) -> pd.Index:
    """Scenarios with every metric for every seed of every method in ``methods``."""
    cols = [m.column for m in metrics]
    keep = None
    for method in methods:
        part = sub[sub.method == method]
        n_seeds = part.seed.nunique()
        ok = part.dropna(subset=cols).groupby("scenario_id").seed.nunique()
        ids = set(ok.index[ok == n_seeds])
        keep = ids if keep is None else keep & ids
    return pd.Index(sorted(keep or ()), name="scenario_id")


def compare_methods(per_scenario: pd.DataFrame, baseline: str = BC,
                    methods: Sequence[str] | None = None, n_resamples: int = N_RESAMPLES
                    ) -> pd.DataFrame:
    """Each method (default: every learned one) against ``baseline`` per setting and metric, one
    row each (see the module docstring): means, ``diff`` on the scenarios all seeds share, its
    interval, ``p_value``, Holm ``p_holm``, ``significant``, ``better`` (the lower, when
    significant), ``mde``/``mde_holm``, ``p_welch`` and the counts."""
    if methods is None:
        present = per_scenario.method.unique()
        methods = sorted(m for m in present if m != baseline and m not in REFERENCES)
    means = seed_means(per_scenario)
    rows = []
    for method in methods:
        settings = sorted(set(per_scenario.loc[per_scenario.method == method, "setting"])
                          & set(per_scenario.loc[per_scenario.method == baseline, "setting"]))
        for setting in settings:
            sub = per_scenario[per_scenario.setting == setting]
            scenarios = complete_scenarios(sub, (method, baseline))
            xa = scenario_cube(sub, method, scenarios)
            xb = scenario_cube(sub, baseline, scenarios)
            nan = np.full(len(METRICS), np.nan)
            c = (paired_difference(xa, xb, n_resamples, statistic_seed(setting)) if scenarios.size
                 else dict(diff=nan, lo=nan, hi=nan, se=nan, p=nan))
            for i, metric in enumerate(METRICS):
                cell = means[(means.setting == setting) & (means.metric == metric.key)]
                sa, sb = cell[cell.method == method], cell[cell.method == baseline]
                rows.append(dict(
                    method=method, baseline=baseline, metric=metric.key, setting=setting,
                    mean_a=float(sa.value.mean()), mean_b=float(sb.value.mean()),
                    diff=float(c["diff"][i]), ci_low=float(c["lo"][i]), ci_high=float(c["hi"][i]),
                    se=float(c["se"][i]), p_value=float(c["p"][i]),
                    p_welch=welch_test(sa.value.to_numpy(), sb.value.to_numpy()),
                    n_seeds_a=int(xa.shape[0]), n_seeds_b=int(xb.shape[0]),
                    n_pairs=int(scenarios.size)))
    columns = ["method", "baseline", "metric", "setting", "mean_a", "mean_b", "diff", "ci_low",
               "ci_high", "se", "p_value", "p_holm", "significant", "better", "mde", "mde_holm",
               "p_welch", "n_seeds_a", "n_seeds_b", "n_pairs"]
    out = pd.DataFrame(rows)
    if out.empty:
        return pd.DataFrame(columns=columns)
    out["p_holm"] = holm_adjust(out.p_value.to_numpy())
    out["significant"] = out.p_holm < ALPHA
    out["better"] = [(m if d < 0 else b) if sig else ""
                     for m, b, d, sig in zip(out.method, out.baseline, out["diff"],
                                             out.significant, strict=True)]
    n_cells = int(np.isfinite(out.p_value).sum()) or 1
    out["mde"] = minimum_detectable_effect(out.se.to_numpy())
    out["mde_holm"] = minimum_detectable_effect(out.se.to_numpy(), ALPHA / n_cells)
    return out[columns]
