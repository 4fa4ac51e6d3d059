"""The real-log section of ``docs/results.md`` and the README's real-log sentence, read from
the ``real_logs`` stage's ``tables/real_logs.csv`` and ``tables/real_logs_readouts.csv``
(:mod:`igdrivsim.report.real_logs`): every setting's BC and BC-RL against constant velocity ego
by ego (share of egos closer to the log, mean ratio, 95% intervals, N egos and source
scenarios), Full BC's action read-outs, and the log divergence per setting on real logs and on
validation. No number is typed by hand."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from igdrivsim.evaluation.schema import REFERENCE_SETTING
from igdrivsim.names import BC, CONSTANT_VELOCITY, EXPERT, METHOD_LABELS, setting_short
from igdrivsim.report.real_logs import real_logs_summary
from igdrivsim.report.results_tex import read_table
from igdrivsim.report.text import wrap

READOUTS = {"sample": "sampled (Table I)"}  # a read-out's name in the table, when not its own


def _vs_cv(row: pd.Series) -> str:
    """``x% [lo, hi]; r.rrx [lo, hi]``: a driver's share of egos closer to the log than constant
    velocity and its mean log divergence over constant velocity's (real_logs.csv's columns)."""
    if pd.isna(row.get("real_vs_cv_win")):
        return "-- | --"
    return (f"{100 * row.real_vs_cv_win:.0f}% [{100 * row.real_vs_cv_win_lo:.0f}, "
            f"{100 * row.real_vs_cv_win_hi:.0f}] | {row.real_vs_cv_ratio:.2f}x "
            f"[{row.real_vs_cv_ratio_lo:.2f}, {row.real_vs_cv_ratio_hi:.2f}]")


def _full_bc_line(table: pd.DataFrame) -> str | None:
    """The headline sentence: Full BC against constant velocity ego by ego, with N egos and N
    source scenarios; None without that comparison."""
    full = table[(table.setting == "full") & (table.method == BC)]
    if full.empty or "real_vs_cv_win" not in full or pd.isna(full.real_vs_cv_win.iloc[0]):
        return None
    r = full.iloc[0]
    return (f"On real logs ({int(r.real_vs_cv_egos)} egos from {int(r.real_vs_cv_sources)} "
            "source scenarios, every vehicle that passes the scenario filter as the ego), "
            f"Full BC stays closer to the log than constant velocity on "
            f"{100 * r.real_vs_cv_win:.0f}% of the egos (95% CI {100 * r.real_vs_cv_win_lo:.0f}-"
            f"{100 * r.real_vs_cv_win_hi:.0f}%), with a mean log divergence "
            f"{r.real_vs_cv_ratio:.2f}x constant velocity's (95% CI "
            f"{r.real_vs_cv_ratio_lo:.2f}-{r.real_vs_cv_ratio_hi:.2f})")


def _readouts(tables: Path) -> list[str]:
    """Full BC's action read-outs against constant velocity (``real_logs_readouts.csv``)."""
    modes = read_table(tables / "real_logs_readouts.csv")
    if modes is None or len(modes) < 2:
        return []
    out = ["", "Full BC's action read-outs (Table I samples its actions):", "",
           "| actions | N egos (sources) | closer than CV [95% CI] | mean / CV [95% CI] "
           "| median - CV (m) |", "|---|---|---|---|---|"]
    for _, r in modes.iterrows():
        name = READOUTS.get(r.actions, r.actions)
        out.append(f"| {name} | {int(r.real_vs_cv_egos)} ({int(r.real_vs_cv_sources)}) | "
                   f"{_vs_cv(r)} | {r.real_vs_cv_median:+.2f} |")
    return out


def real_logs_section(tables: Path, headline: str | None = None) -> list[str]:
    """The drivers on real logs (``tables/real_logs.csv``, the ``real_logs`` stage): every
    setting's BC and BC-RL against constant velocity ego by ego (share of egos closer to the
    log, mean ratio, with 95% intervals and N), Full BC's action read-outs, the summary
    sentence, and each learned method's log divergence per setting on the real scenarios and on
    validation; nothing without real logs. ``headline``: the link to the full results (the
    README's block: one sentence, Full BC's)."""
    table = read_table(tables / "real_logs.csv")
    if table is None or table.empty:
        return []
    sentence = real_logs_summary(table)
    if sentence is None:
        return []
    full = _full_bc_line(table)
    if headline:
        text = full or sentence.rstrip(".")
        return wrap(text + f"; every setting: [{headline}]({headline}#on-real-logs).")
    learned = [m for m in dict.fromkeys(table.method) if m not in (EXPERT, CONSTANT_VELOCITY)]
    settings = [s for s in dict.fromkeys(table.setting) if s != REFERENCE_SETTING]
    ego_table = []
    if "real_vs_cv_win" in table and table.real_vs_cv_win.notna().any():
        ego_table = [*wrap("Against constant velocity, ego by ego: the share of egos where the "
                           "driver stays closer to the log (a tie counts half) and its mean log "
                           "divergence over constant velocity's, with 95% intervals (bootstrap "
                           "over source scenarios, then seeds); N egos (source scenarios). All "
                           "statistics: [real_logs.md](PAPER/tables/real_logs.md)."), "",
                     "| setting | method | N egos (sources) | closer than CV [95% CI] "
                     "| mean / CV [95% CI] |", "|---|---|---|---|---|"]
        for setting in settings:
            for m in learned:
                row = table[(table.setting == setting) & (table.method == m)]
                if row.empty or pd.isna(row.real_vs_cv_egos.iloc[0]):
                    continue
                r = row.iloc[0]
                ego_table.append(f"| {setting_short(setting)} | {METHOD_LABELS.get(m, m)} | "
                                 f"{int(r.real_vs_cv_egos)} ({int(r.real_vs_cv_sources)}) | "
                                 f"{_vs_cv(r)} |")
        ego_table += [*_readouts(tables), ""]

    def cell(row: pd.DataFrame, source: str) -> str:
        if row.empty or pd.isna(row[f"{source}_log_divergence"].iloc[0]):
            return "--"
        value = row[f"{source}_log_divergence"].iloc[0]
        return f"{value:.2f} (N={int(row[f'{source}_n'].iloc[0])})"

    head = [f"{METHOD_LABELS.get(m, m)}, {src}" for src in ("real", "validation")
            for m in learned]
    out = ["## On real logs", "", *(wrap(full + ".") + [""] if full else []), *ego_table,
           *wrap(sentence), "",
           "Log divergence (m), mean over seeds of each seed's mean over scenarios; N: "
           "scenarios. Every metric: [real_logs.md](PAPER/tables/real_logs.md).", "",
           "| setting | " + " | ".join(head) + " |", "|---|" + "---|" * len(head)]
    for setting in settings:
        rows = [table[(table.setting == setting) & (table.method == m)] for m in learned]
        out.append(f"| {setting_short(setting)} | " + " | ".join(
            cell(r, src) for src in ("real", "validation") for r in rows) + " |")
    cv = table[table.method == CONSTANT_VELOCITY]
    out.append("| constant velocity | " + " | ".join(
        cell(cv, src) for src in ("real", "validation") for _ in learned) + " |")
    return [*out, ""]
