"""Two runs' Table I conclusions beside each other (``igdrivsim report compare OLD NEW``): per
metric, constant velocity's level, BC's setting order, the gap to Full and BC-RL - BC."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from igdrivsim.errors import ConfigError
from igdrivsim.evaluation.schema import METRIC_BY_KEY, STEP_METRICS, table_settings
from igdrivsim.names import BC_RL, CONSTANT_VELOCITY, setting_short
from igdrivsim.report.results_tex import bc_means, read_table

FULL = "full"


def _tables(folder: Path) -> tuple[pd.DataFrame, pd.DataFrame]:
    summary, tests = read_table(folder / "summary.csv"), read_table(folder / "tests.csv")
    if summary is None or tests is None:
        raise ConfigError(f"{folder}: expected summary.csv and tests.csv (igdrivsim report's "
                          "tables)")
    return summary, tests


def run_lines(summary: pd.DataFrame, tests: pd.DataFrame, metric: str) -> dict[str, str]:
    """One run's cells for ``metric``: reference, BC's order, the gap and BC-RL - BC."""
    bc = pd.Series(bc_means(summary, metric), dtype=float)
    cv = summary[(summary.metric == metric) & (summary.method == CONSTANT_VELOCITY)]["mean"]
    order = table_settings(summary)
    partial = [s for s in order if s != FULL and s in bc.index]
    rl = tests[(tests.metric == metric) & (tests.method == BC_RL)].set_index("setting")
    return {
        "constant velocity": f"{cv.iloc[0]:.2f}" if len(cv) else "--",
        "BC, best to worst": " < ".join(setting_short(s) for s in bc.sort_values().index),
        "BC gap to Full": ", ".join(f"{setting_short(s)} {bc[s] - bc[FULL]:+.2f}"
                                    for s in partial if FULL in bc),
        "BC-RL - BC (MDE)": ", ".join(
            f"{setting_short(s)} {r['diff']:+.2f}{'*' if bool(r.significant) else ''} "
            f"({r.mde:.2f})" for s, r in rl.loc[[s for s in order if s in rl.index]].iterrows()),
    }


def compare_markdown(old: Path, new: Path, labels: tuple[str, str] = ("old", "new")) -> str:
    """The markdown comparison of two report folders."""
    runs = [(label, *_tables(Path(folder))) for label, folder in zip(labels, (old, new),
                                                                       strict=True)]
    lines = [f"# Table I: {labels[0]} vs {labels[1]}", "",
             "Written by `igdrivsim report compare`. `*`: significant after Holm; "
             "in brackets the minimum detectable effect (80% power).", ""]
    for metric in STEP_METRICS:
        name = " ".join(p for p in METRIC_BY_KEY[metric].label if not p.startswith("("))
        lines += [f"## {name} ({METRIC_BY_KEY[metric].unit})", "", "| | " + " | ".join(
            label for label, *_ in runs) + " |", "|---|" + "---|" * len(runs)]
        cells = [run_lines(summary, tests, metric) for _, summary, tests in runs]
        lines += [f"| {row} | " + " | ".join(c[row] for c in cells) + " |" for row in cells[0]]
        lines.append("")
    return "\n".join(lines)
