"""Names shared by the evaluation outputs (the tidy CSVs written by :mod:`.rollout` and read by
:mod:`.aggregate`): files, columns, metrics and the paper's Table I. Imports no JAX; the
settings' and methods' names are :mod:`igdrivsim.names`'.
"""

from __future__ import annotations

from dataclasses import dataclass

from igdrivsim.names import SETTINGS

# Competence targets of a learned driver against constant velocity on the same scenarios (the
# project's own bar; the paper's BC is about 0.8x on real logs): metric -> (largest ratio
# allowed, label, unit).
COMPETENCE: dict[str, tuple[float, str, str]] = {
    "log_divergence": (0.7, "log divergence", "m"),
    "offroad": (0.25, "offroad", "% steps"),
    "overlap": (1.0, "overlap", "% steps"),
}


# Targets of Full BC against constant velocity on real logs, every ego, sampled actions: the
# share of egos where it stays closer to the log (at least WIN, the 95% interval's lower end
# above one half), and its mean log divergence and offroad over constant velocity's (at most
# RATIO and OFFROAD).
REAL_COMPETENCE = {"win": 0.6, "ratio": 0.9, "offroad": 1.0}


def table_settings(*frames) -> tuple[str, ...]:
    """The columns of a table over ``frames`` (DataFrames with a ``setting`` column, or None):
    the paper's six in Table I order, then any other registered setting present, by name."""
    present: set[str] = set()
    for frame in frames:
        if frame is not None and len(frame) and "setting" in frame:
            present |= set(frame["setting"].astype(str))
    extra = sorted(present - set(SETTINGS) - {REFERENCE_SETTING})
    return SETTINGS + tuple(extra)


# Reference rows do not depend on the observation: their CSV `setting` is this value.
REFERENCE_SETTING = "none"

# An evaluation folder's files: the tidy CSVs and the record of what was evaluated.
PER_STEP_FILE, PER_SCENARIO_FILE = "per_step.csv", "per_scenario.csv"
EVAL_CONFIG = "eval_config.json"

# Tidy CSV columns. per_step: one row per (setting, method, seed, step), the mean over scenarios
# of the metric after the step-th policy action (step 1..80; overlap/offroad as fractions).
PER_STEP_COLUMNS = ("setting", "method", "seed", "step", "log_divergence", "overlap", "offroad")
PER_SCENARIO_COLUMNS = (
    "setting", "method", "seed", "scenario_id",
    "max_log_divergence", "overlap", "offroad",  # per-scenario: max, any overlap, any offroad
    "log_divergence", "overlap_steps", "offroad_steps",  # per-step values averaged over steps
)
# Where each per-scenario row's scenario comes from, written after the metrics' columns:
# ``source``, the source log (windows of one long log and the egos of one scene share it: the
# paired statistics' clusters), and ``logged_sdc``, whether the ego is the log's SDC.
SOURCE_COLUMN, LOGGED_SDC_COLUMN = "source", "logged_sdc"
ORIGIN_COLUMNS = (SOURCE_COLUMN, LOGGED_SDC_COLUMN)


@dataclass(frozen=True)
class Metric:
    """One row group of Table I: which per-scenario column, how to scale it, how to name it."""

    key: str  # name in tables and summary.csv
    column: str  # per_scenario.csv column averaged over scenarios
    label: tuple[str, str]  # two lines, as in the paper's table
    scale: float  # 100 for percentages
    unit: str
    per_step: bool  # True: a per-step metric (Fig. 3); False: a per-scenario one


METRICS: tuple[Metric, ...] = (
    Metric("log_divergence", "log_divergence", ("log", "divergence"), 1.0, "m", True),
    Metric("max_log_divergence", "max_log_divergence", ("max log", "divergence"), 1.0, "m", False),
    Metric("overlap", "overlap_steps", ("overlap", r"(\%)"), 100.0, "%", True),
    Metric("overlap_rate", "overlap", ("overlap", r"rate (\%)"), 100.0, "%", False),
    Metric("offroad", "offroad_steps", ("offroad", r"(\%)"), 100.0, "%", True),
    Metric("offroad_rate", "offroad", ("offroad", r"rate (\%)"), 100.0, "%", False),
)
METRIC_BY_KEY: dict[str, Metric] = {m.key: m for m in METRICS}
# Table I's per-step metrics, the ones its side tables (real logs, run comparisons) report
STEP_METRICS: tuple[str, ...] = ("log_divergence", "offroad", "overlap")


def _row(*cells: tuple[float, float]) -> dict[str, tuple[float, float]]:
    return dict(zip(SETTINGS, cells, strict=True))


# The paper's Table I (BC-RL, BC), mean of 3 seeds on the WOMD validation set.
PAPER_TABLE1: dict[str, dict[str, tuple[float, float]]] = {
    "log_divergence": _row(
        (3.67, 3.79), (3.69, 3.85), (4.18, 4.12), (3.87, 3.94), (4.60, 4.19), (3.68, 3.81)),
    "max_log_divergence": _row(
        (10.56, 11.00), (10.72, 11.23), (12.54, 12.28), (11.51, 11.74), (14.08, 12.39),
        (10.68, 11.16)),
    "overlap": _row(
        (4.80, 5.06), (4.66, 5.02), (5.28, 5.45), (5.09, 5.31), (3.70, 5.73), (4.95, 5.30)),
    "overlap_rate": _row(
        (21.17, 22.24), (20.94, 22.26), (24.25, 24.30), (22.73, 23.47), (24.65, 25.16),
        (21.70, 23.00)),
    "offroad": _row(
        (2.13, 2.54), (2.39, 2.96), (0.77, 2.15), (1.13, 1.68), (1.10, 2.39), (2.20, 2.71)),
    "offroad_rate": _row(
        (6.69, 7.78), (7.25, 8.73), (4.28, 7.18), (4.49, 5.73), (7.00, 8.34), (6.85, 7.96)),
}
