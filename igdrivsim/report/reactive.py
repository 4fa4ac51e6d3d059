"""Table I's companion under reactive traffic (``igdrivsim report reactive``): every driver's
per-scenario rates with log-replay and with IDM agents, and log - idm with Table I's two-level
bootstrap, Holm over the table; ``tables/reactive.{md,csv}`` and Fig. 7."""

from __future__ import annotations

import zlib
from pathlib import Path

import numpy as np
import pandas as pd

from igdrivsim.errors import DataError
from igdrivsim.evaluation import registry
from igdrivsim.evaluation.aggregate import (
    ALPHA,
    TEST_NAME,
    TEST_SEED,
    complete_scenarios,
    holm_adjust,
    load_evaluations,
    paired_difference,
    scenario_cube,
    summarize,
)
from igdrivsim.evaluation.schema import METRIC_BY_KEY, REFERENCE_SETTING, table_settings
from igdrivsim.io import atomic_write_csv, atomic_write_text
from igdrivsim.names import BC, BC_RL, METHOD_LABELS, REFERENCES, setting_short
from igdrivsim.report.tables import _fmt, _lookup, md_bold, md_head, md_row
from igdrivsim.simulator import episode_metrics as em

AT_FAULT = next(m for m in registry.REGISTRY if m.episode is em.at_fault_overlap)
METRICS = (METRIC_BY_KEY["overlap_rate"], AT_FAULT, METRIC_BY_KEY["offroad_rate"],
           METRIC_BY_KEY["max_log_divergence"])
HEADERS = {"overlap_rate": "overlap rate (%)", AT_FAULT.key: f"{AT_FAULT.label} rate (%)",
           "offroad_rate": "offroad rate (%)", "max_log_divergence": "max log divergence (m)"}
FIGURE = "fig7_reactive"
# the table's column -> its key in paired_difference's result
DIFF_COLUMNS = {"diff": "diff", "diff_low": "lo", "diff_high": "hi", "p_value": "p", "mde": "mde"}


def drivers(log: pd.DataFrame, idm: pd.DataFrame) -> list[tuple[str, str]]:
    """The ``(setting, method)`` pairs evaluated under both, in Table I's order."""
    both = set(zip(log.setting, log.method, strict=True)) & set(
        zip(idm.setting, idm.method, strict=True))
    out = [(s, m) for s in table_settings(log, idm) for m in (BC, BC_RL) if (s, m) in both]
    return out + [(REFERENCE_SETTING, m) for m in REFERENCES if (REFERENCE_SETTING, m) in both]


def reactive_table(log: pd.DataFrame, idm: pd.DataFrame, n_resamples: int = 10_000
                   ) -> pd.DataFrame:
    """One row per (driver, metric): under log, under idm, and log - idm."""
    pairs = drivers(log, idm)
    if not pairs:
        raise DataError("no driver was evaluated under both log and idm agents")
    summaries = {c: summarize(f, metrics=METRICS) for c, f in (("log", log), ("idm", idm))}
    rows = []
    for setting, method in pairs:
        a = log[(log.setting == setting) & (log.method == method)]
        b = idm[(idm.setting == setting) & (idm.method == method)]
        scenarios = pd.Index(sorted(set(complete_scenarios(a, [method], METRICS))
                                    & set(complete_scenarios(b, [method], METRICS))),
                             name="scenario_id")
        seed = [TEST_SEED, zlib.crc32(f"{setting}/{method}".encode())]
        if scenarios.size:
            c = paired_difference(scenario_cube(a, method, scenarios, METRICS),
                                  scenario_cube(b, method, scenarios, METRICS), n_resamples, seed)
        else:
            c = {k: np.full(len(METRICS), np.nan) for k in DIFF_COLUMNS.values()}
        for i, metric in enumerate(METRICS):
            row = dict(setting=setting, method=method, metric=metric.key)
            for cond, summary in summaries.items():
                s = _lookup(summary, metric.key, setting, method)
                row |= {f"{cond}_{k}": np.nan if s is None else float(s[k])
                        for k in ("mean", "ci_low", "ci_high")}
                row[f"{cond}_seeds"] = 0 if s is None else int(s.n_seeds)
            row |= {name: float(c[k][i]) for name, k in DIFF_COLUMNS.items()}
            rows.append(row | dict(n_pairs=int(scenarios.size)))
    out = pd.DataFrame(rows)
    out["p_holm"] = holm_adjust(out.p_value.to_numpy())
    out["significant"] = out.p_holm < ALPHA
    return out


def _cell(row: pd.Series, cond: str, digits: int) -> str:
    mean = _fmt(row[f"{cond}_mean"], digits)
    if not np.isfinite(row[f"{cond}_ci_low"]):
        return mean
    return f"{mean} [{_fmt(row[f'{cond}_ci_low'], digits)}, {_fmt(row[f'{cond}_ci_high'], digits)}]"


def _diff_cell(row: pd.Series, digits: int) -> str:
    if not np.isfinite(row["diff"]):
        return "--"
    text = (f"{row['diff']:+.{digits}f} [{row.diff_low:+.{digits}f}, "
            f"{row.diff_high:+.{digits}f}]")
    return md_bold(text) if row.significant else text


def driver_label(setting: str, method: str) -> tuple[str, str]:
    """The table's setting and driver cells."""
    if setting == REFERENCE_SETTING:
        return "--", "Expert (its own log)" if method == "expert" else METHOD_LABELS[method]
    return setting_short(setting), METHOD_LABELS.get(method, method)


def reactive_markdown(table: pd.DataFrame) -> str:
    """``tables/reactive.md``: per driver and metric, log, idm and log - idm."""
    n = int(table.n_pairs.max()) if len(table) else 0
    lines = [
        "# Every driver under log-replay and IDM sim agents (beyond the paper)", "",
        "Each cell: the mean over seeds of each seed's mean over the validation scenarios, with "
        "its 95% t-interval over seeds (none for the references: one deterministic run). "
        "*log*: the other objects replay their log (Table I); *idm*: the vehicles follow their "
        "logged paths with IDM speed (Waymax's defaults: desired speed 30 m/s, minimum gap 2 m, "
        "headway 2 s; docs/reactive.md). *log - idm*: the difference on the same scenarios "
        f"({n} at most), its 95% interval ({TEST_NAME}, over the {len(table)} cells of this "
        f"table); bold where the Holm-adjusted p is below {ALPHA}.", ""]
    for metric in METRICS:
        digits = 2 if metric.key == "max_log_divergence" else 1
        lines += [f"## {HEADERS[metric.key]}", "",
                  *md_head("setting", "driver", "log", "idm", "log - idm [95% CI]")]
        lines += [md_row(*driver_label(row.setting, row.method), _cell(row, "log", digits),
                         _cell(row, "idm", digits), _diff_cell(row, digits))
                  for _, row in table[table.metric == metric.key].iterrows()]
        lines.append("")
    return "\n".join(lines)


def reactive_figure(table: pd.DataFrame, out_dir: str | Path) -> list[Path]:
    """Fig. 7: per metric, each driver's mean under log and idm with its interval."""
    from igdrivsim.report.figures import plt, save_figure  # lazy: matplotlib

    keys = [m.key for m in METRICS]
    fig, axes = plt.subplots(1, len(keys), figsize=(4.2 * len(keys), 4.6), squeeze=False)
    for ax, key in zip(axes[0], keys, strict=True):
        part = table[table.metric == key].reset_index(drop=True)
        y = np.arange(len(part))
        for k, (cond, colour) in enumerate((("log", "#4C4C4C"), ("idm", "#E15759"))):
            mean = part[f"{cond}_mean"].to_numpy(float)
            lo = np.nan_to_num(mean - part[f"{cond}_ci_low"].to_numpy(float))
            hi = np.nan_to_num(part[f"{cond}_ci_high"].to_numpy(float) - mean)
            ax.errorbar(mean, y + (k - 0.5) * 0.3, xerr=[np.maximum(lo, 0), np.maximum(hi, 0)],
                        fmt="o", color=colour, label=cond, ms=4, capsize=2)
        ax.set_yticks(y, [" ".join(driver_label(s, m)).strip("- ")
                          for s, m in zip(part.setting, part.method, strict=True)], fontsize=7)
        ax.invert_yaxis()
        ax.set_xlabel(HEADERS[key])
        if "%" in HEADERS[key]:  # a rate: its axis is 0-100 (wide t-intervals are cut)
            ax.set_xlim(-5, 105)
        ax.grid(axis="x", alpha=0.3)
    axes[0][0].legend(title="sim agents", fontsize=8)
    fig.suptitle("Every driver under log-replay and IDM sim agents (mean, 95% CI over seeds)")
    fig.tight_layout()
    return save_figure(fig, out_dir, FIGURE)


def build(log_dirs: list[str], idm_dirs: list[str], out: str | Path) -> list[Path]:
    """Read both evaluations and write the table, its numbers and the figure under ``out``."""
    table = reactive_table(load_evaluations(log_dirs)[1], load_evaluations(idm_dirs)[1])
    out = Path(out)
    written = [atomic_write_csv(out / "tables" / "reactive.csv", table.round(6)),
               atomic_write_text(out / "tables" / "reactive.md", reactive_markdown(table))]
    return written + reactive_figure(table, out / "figures")
