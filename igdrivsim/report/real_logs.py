"""Synthetic-trained drivers on real logs: a small table beside the synthetic validation numbers.

Beyond the paper. Inputs are two evaluation folders of tidy CSVs (``igdrivsim evaluate``): the
policies and reference actors on real scenarios (the public WOMD samples of ``igdrivsim
samples``, or the user's WOMD / ScenarioNet data) and the same on the synthetic validation set.
Each cell is the mean over seeds of each seed's mean over scenarios (Table I's per-step metrics:
log divergence, offroad and overlap as percent of steps), with the number of scenarios beside
it. No confidence interval or test is given: on a handful of real scenarios none would mean much.

``python -m igdrivsim.report.real_logs --real DIR --synthetic DIR --out TABLES`` writes
``real_logs.md`` and ``real_logs.tex`` (the pipeline's ``real_logs`` stage).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import pandas as pd

from igdrivsim.errors import REPORTED, error_line
from igdrivsim.evaluation.aggregate import load_evaluations, seed_means
from igdrivsim.evaluation.schema import (
    METHOD_LABELS,
    METRIC_BY_KEY,
    REFERENCES,
    STEP_METRICS,
    setting_short,
    table_settings,
)
from igdrivsim.io import atomic_write_text

METRIC_KEYS = STEP_METRICS
SOURCES = ("validation", "real")  # the columns of each metric
HEADERS = {"log_divergence": "log divergence (m)", "offroad": "offroad (%)",
           "overlap": "overlap (%)"}


def real_log_table(real: pd.DataFrame, validation: pd.DataFrame | None = None) -> pd.DataFrame:
    """One row per ``(setting, method)`` evaluated on real logs: per source and metric the mean
    over seeds of the seed means, and per source the number of scenarios and seeds."""
    metrics = [METRIC_BY_KEY[k] for k in METRIC_KEYS]
    rows: dict[tuple[str, str], dict] = {}
    for source, frame in (("real", real), ("validation", validation)):
        if frame is None or frame.empty:
            continue
        means = seed_means(frame, metrics).groupby(["setting", "method", "metric"])["value"]
        counts = frame.groupby(["setting", "method"]).agg(
            n=("scenario_id", "nunique"), seeds=("seed", "nunique"))
        for (setting, method), c in counts.iterrows():
            if source == "validation" and (setting, method) not in rows:
                continue  # only what was also evaluated on real logs
            row = rows.setdefault((setting, method), dict(setting=setting, method=method))
            row[f"{source}_n"], row[f"{source}_seeds"] = int(c.n), int(c.seeds)
            for key in METRIC_KEYS:
                try:
                    row[f"{source}_{key}"] = float(means.mean().loc[(setting, method, key)])
                except KeyError:
                    row[f"{source}_{key}"] = float("nan")
    columns = ["setting", "method"] + [f"{s}_{x}" for s in SOURCES
                                        for x in ("n", "seeds", *METRIC_KEYS)]
    table = pd.DataFrame(list(rows.values()), columns=columns)
    methods = {m: i for i, m in enumerate(METHOD_LABELS)}
    settings = {s: i for i, s in enumerate(table_settings(table))}
    keys = pd.DataFrame({
        "ref": table.method.isin(REFERENCES),
        "s": table.setting.map(lambda s: settings.get(s, len(settings))),
        "m": table.method.map(lambda m: methods.get(m, len(methods)))})
    return table.loc[keys.sort_values(["ref", "s", "m"]).index].reset_index(drop=True)


def _cell(row: pd.Series, source: str, key: str) -> str:
    value, n = row.get(f"{source}_{key}"), row.get(f"{source}_n")
    if value is None or pd.isna(value) or n is None or pd.isna(n):
        return "--"
    digits = 2 if key == "log_divergence" else 1
    return f"{value:.{digits}f} (N={int(n)})"


def _label(row: pd.Series) -> tuple[str, str]:
    method = METHOD_LABELS.get(row.method, row.method)
    setting = "--" if row.method in REFERENCES else setting_short(row.setting)
    return setting, method


def real_logs_markdown(table: pd.DataFrame, real_label: str, validation_label: str) -> str:
    """The table as Markdown: per metric a validation and a real column, N beside each value."""
    head = ["setting", "method"] + [f"{HEADERS[k]}, {s}" for k in METRIC_KEYS
                                     for s in SOURCES]
    lines = ["# Synthetic-trained drivers on real logs (beyond the paper)", "",
             f"Real: {real_label}. Validation: {validation_label}. Each value is the mean "
             "over seeds of each seed's mean over scenarios; N is the number of scenarios. "
             "No significance is claimed: a few real scenarios cannot separate the methods.",
             "",
             "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for _, row in table.iterrows():
        cells = [*_label(row)] + [_cell(row, s, k) for k in METRIC_KEYS for s in SOURCES]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def _tex(text: str) -> str:
    return text.replace("\\", r"\textbackslash{}").replace("_", r"\_").replace("%", r"\%") \
        .replace("&", r"\&").replace("#", r"\#")


def real_logs_latex(table: pd.DataFrame, real_label: str, validation_label: str) -> str:
    """The table as a LaTeX ``table`` (booktabs)."""
    lines = [r"\begin{table}[t]", r"\centering", r"\small",
             r"\begin{tabular}{ll" + "rr" * len(METRIC_KEYS) + "}", r"\toprule",
             " & & " + " & ".join(rf"\multicolumn{{2}}{{c}}{{{_tex(HEADERS[k])}}}"
                                  for k in METRIC_KEYS) + r" \\",
             "setting & method & " + " & ".join("validation & real" for _ in METRIC_KEYS)
             + r" \\", r"\midrule"]
    for _, row in table.iterrows():
        cells = [_tex(c) for c in _label(row)] + [
            _cell(row, s, k) for k in METRIC_KEYS for s in SOURCES]
        lines.append(" & ".join(cells) + r" \\")
    lines += [r"\bottomrule", r"\end{tabular}",
              r"\caption{Synthetic-trained drivers on real logs (beyond the paper). Real: "
              + _tex(real_label) + ". Validation: " + _tex(validation_label) + ". Mean over seeds "
              r"of each seed's mean over scenarios; N: scenarios. No significance is claimed "
              r"on so few real scenarios.}", r"\label{tab:real-logs}", r"\end{table}"]
    return "\n".join(lines) + "\n"


def write_tables(real: str | Path, validation: str | Path | None, out: str | Path,
                 real_label: str, validation_label: str) -> list[Path]:
    """Read both evaluation folders, write ``out/real_logs.{md,tex}``; returns the paths."""
    real_frame = load_evaluations([real])[1]
    validation_frame = load_evaluations([validation])[1] if validation else None
    table = real_log_table(real_frame, validation_frame)
    out = Path(out)
    return [atomic_write_text(out / "real_logs.md",
                              real_logs_markdown(table, real_label, validation_label)),
            atomic_write_text(out / "real_logs.tex",
                              real_logs_latex(table, real_label, validation_label))]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m igdrivsim.report.real_logs",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("--real", required=True, help="evaluations on real logs (folder)")
    parser.add_argument("--synthetic", dest="validation", default=None,
                        help="evaluations on the (synthetic) validation set (folder)")
    parser.add_argument("--out", required=True, help="tables folder")
    parser.add_argument("--real-label", default="real scenarios", help="what the real data are")
    parser.add_argument("--synthetic-label", dest="validation_label",
                        default="synthetic validation scenarios",
                        help="what the validation data are")
    args = parser.parse_args(argv)
    try:
        paths = write_tables(args.real, args.validation, args.out, args.real_label,
                             args.validation_label)
    except REPORTED as err:
        print(f"real_logs: error: {error_line(err)}", file=sys.stderr)
        return 2
    print("wrote " + ", ".join(map(str, paths)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
