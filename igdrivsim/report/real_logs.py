"""Synthetic-trained drivers on real logs (``igdrivsim report real-logs``): per ``(setting,
method)`` the metrics on real logs and on validation, the comparison with the references ego by
ego (:mod:`igdrivsim.evaluation.paired`) and Full BC under each action read-out; then their
section of ``results.md`` and the README's sentence, from those tables."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from igdrivsim.evaluation.aggregate import load_evaluations, seed_means
from igdrivsim.evaluation.paired import compare_on_egos, sources
from igdrivsim.evaluation.schema import (
    EVAL_CONFIG,
    METRIC_BY_KEY,
    PER_SCENARIO_FILE,
    REAL_COMPETENCE,
    REFERENCE_SETTING,
    STEP_METRICS,
    table_settings,
)
from igdrivsim.io import atomic_write_text, read_json
from igdrivsim.names import BC, CONSTANT_VELOCITY, EXPERT, METHOD_LABELS, REFERENCES, setting_short
from igdrivsim.report.results_tex import read_table
from igdrivsim.report.tables import _tex, md_head, md_row, tex_row, wrap

SOURCES = ("validation", "real")  # the columns of each metric
# real log divergence minus constant velocity's: difference, interval, detectable effect
VS_CV = ["real_vs_cv_diff", "real_vs_cv_lo", "real_vs_cv_hi", "real_vs_cv_mde"]
VS_CV_HEADER = "log divergence - constant velocity (m), real [95% CI], MDE"
HEADERS = {"log_divergence": "log divergence (m)", "offroad": "offroad (%)",
           "overlap": "overlap (%)"}
# ego by ego against each reference (igdrivsim.evaluation.paired): column prefix -> reference
PAIRED_REFERENCES = {"cv": CONSTANT_VELOCITY, "expert": EXPERT}
PAIRED_STATS = ("egos", "sources", "win", "win_lo", "win_hi", "win_mde", "median", "median_lo",
                "median_hi", "ratio", "ratio_lo", "ratio_hi", "ratio_mde")
PAIRED = [f"real_vs_{ref}_{k}" for ref in PAIRED_REFERENCES for k in PAIRED_STATS]
PAIRED_HEAD = ["N egos (sources)", "closer to the log [95% CI]",
               "median difference (m) [95% CI]", "mean ratio [95% CI], MDE"]


def real_log_table(real: pd.DataFrame, validation: pd.DataFrame | None = None) -> pd.DataFrame:
    """One row per ``(setting, method)`` on real logs: means over seeds and counts."""
    metrics = [METRIC_BY_KEY[k] for k in STEP_METRICS]
    rows: dict[tuple[str, str], dict] = {}
    for source, frame in (("real", real), ("validation", validation)):
        if frame is None or frame.empty:
            continue
        means = seed_means(frame, metrics).groupby(["setting", "method", "metric"])["value"].mean()
        counts = frame.assign(source=sources(frame)).groupby(["setting", "method"]).agg(
            n=("scenario_id", "nunique"), seeds=("seed", "nunique"),
            sources=("source", "nunique"))
        for (setting, method), c in counts.iterrows():
            if source == "validation" and (setting, method) not in rows:
                continue  # only what was also evaluated on real logs
            row = rows.setdefault((setting, method), dict(setting=setting, method=method))
            row[f"{source}_n"], row[f"{source}_seeds"] = int(c.n), int(c.seeds)
            if source == "real":
                row["real_sources"] = int(c.sources)
            for key in STEP_METRICS:
                row[f"{source}_{key}"] = float(means.get((setting, method, key), float("nan")))
    for row in rows.values():
        row |= _ego_by_ego(real, row["setting"], row["method"])
    columns = ["setting", "method"] + [f"{s}_{x}" for s in SOURCES
                                        for x in ("n", "seeds", *STEP_METRICS)] + VS_CV + [
        "real_sources", *PAIRED]
    table = pd.DataFrame(list(rows.values()), columns=columns)
    methods = {m: i for i, m in enumerate(METHOD_LABELS)}
    settings = {s: i for i, s in enumerate(table_settings(table))}
    keys = pd.DataFrame({
        "ref": table.method.isin(REFERENCES),
        "s": table.setting.map(lambda s: settings.get(s, len(settings))),
        "m": table.method.map(lambda m: methods.get(m, len(methods)))})
    return table.loc[keys.sort_values(["ref", "s", "m"]).index].reset_index(drop=True)


def _ego_by_ego(real: pd.DataFrame, setting: str, method: str) -> dict:
    """A learned driver against each reference ego by ego; NaN for a reference."""
    out = dict.fromkeys(PAIRED + VS_CV, float("nan"))
    if method in REFERENCES:
        return out
    for prefix, reference in PAIRED_REFERENCES.items():
        c = compare_on_egos(real, setting, method, reference)
        if not c["n_egos"]:
            continue
        out |= _paired_stats(c, f"real_vs_{prefix}_")
        if reference == CONSTANT_VELOCITY:
            out |= dict(zip(VS_CV, (c["diff"], c["diff_lo"], c["diff_hi"], c["diff_mde"]),
                            strict=True))
    return out


def _paired_stats(c: dict, prefix: str) -> dict[str, float]:
    """:data:`PAIRED_STATS` of a :func:`~igdrivsim.evaluation.paired.compare_on_egos` result."""
    return {prefix + k: float(c[f"n_{k}" if k in ("egos", "sources") else k])
            for k in PAIRED_STATS}


def paired_cells(values: dict | pd.Series, prefix: str = "", mde: bool = True) -> list[str]:
    """The cells of :data:`PAIRED_HEAD` from :func:`~igdrivsim.evaluation.paired.compare_on_egos`'s
    numbers (keys ``prefix`` + ``egos``, ``sources``, ``win``...); ``--`` without egos."""
    def get(key: str) -> float:
        value = values.get(prefix + key)
        return float("nan") if value is None else float(value)

    if not get("egos") > 0:
        return ["--"] * len(PAIRED_HEAD)
    return [f"{int(get('egos'))} ({int(get('sources'))})",
            f"{100 * get('win'):.0f}% [{100 * get('win_lo'):.0f}, {100 * get('win_hi'):.0f}]",
            f"{get('median'):+.2f} [{get('median_lo'):+.2f}, {get('median_hi'):+.2f}]",
            f"{get('ratio'):.2f}x [{get('ratio_lo'):.2f}, {get('ratio_hi'):.2f}]"
            + (f", MDE {get('ratio_mde'):.2f}" if mde else "")]


PAIRED_NOTE = (
    "Ego by ego (heavy tails leave a mean weak): N egos compared (source scenarios: egos of "
    "one scene form one cluster); the share of egos where the driver stays closer to the log "
    "than the reference (over its seeds; a tie counts half); the median over egos of the "
    "driver's log divergence (mean over seeds) minus the reference's; the driver's mean log "
    "divergence over the reference's, with the smallest departure from 1 detectable at 80% "
    "power (MDE). 95% intervals: bootstrap resampling source scenarios, then seeds.")


def _paired_markdown(table: pd.DataFrame) -> list[str]:
    """The second table: each learned driver against each reference, ego by ego."""
    lines = []
    for _, row in table.iterrows():
        for prefix, reference in PAIRED_REFERENCES.items():
            cells = paired_cells(row, f"real_vs_{prefix}_")
            if cells[0] != "--":
                lines.append(md_row(*_label(row), METHOD_LABELS.get(reference, reference), *cells))
    if not lines:
        return []
    return ["", "## Ego by ego on the real logs", "", PAIRED_NOTE, "",
            *md_head("setting", "method", "against", *PAIRED_HEAD), *lines]


# Full BC under each action read-out (policy.act.ACTION_MODES), Table I's sampled one first
READOUT_SETTING = "full"
READOUT_LABELS = {"sample": "sampled (Table I's protocol)", "greedy": "greedy (most likely)",
                  "mean": "mean (expected level)"}
READOUT_COLUMNS = ["actions", *[f"real_vs_cv_{k}" for k in PAIRED_STATS]]


def readout_table(real: pd.DataFrame, readouts: str | Path | None) -> pd.DataFrame:
    """Full BC against constant velocity ego by ego under each action read-out."""
    frames = {"sample": real}
    cv = real[real.method == CONSTANT_VELOCITY]
    for config in sorted(Path(readouts).glob(f"*/{EVAL_CONFIG}")) if readouts else []:
        if (config.parent / PER_SCENARIO_FILE).is_file():
            frames[str(read_json(config, {}).get("actions", config.parent.name))] = pd.concat(
                [load_evaluations([config.parent])[1], cv], ignore_index=True)
    rows = []
    for actions in sorted(frames, key=lambda a: list(READOUT_LABELS).index(a)
                          if a in READOUT_LABELS else len(READOUT_LABELS)):
        c = compare_on_egos(frames[actions], READOUT_SETTING, BC, CONSTANT_VELOCITY)
        if c["n_egos"]:
            rows.append({"actions": actions, **_paired_stats(c, "real_vs_cv_")})
    return pd.DataFrame(rows, columns=READOUT_COLUMNS)


def readout_markdown(readouts: pd.DataFrame) -> list[str]:
    """The read-out table's lines (none with fewer than two read-outs)."""
    if len(readouts) < 2:
        return []
    return ["", "## Full BC's action read-outs on the real logs", "",
            "Table I's protocol samples each action from the policy; beside it, the most "
            "likely action (greedy) and the expected action under the policy's distribution "
            "(mean), each against constant velocity, ego by ego (as above).", "",
            *md_head("actions", *PAIRED_HEAD),
            *[md_row(READOUT_LABELS.get(row.actions, row.actions),
                     *paired_cells(row, "real_vs_cv_")) for _, row in readouts.iterrows()]]


def _full_bc(table: pd.DataFrame) -> pd.Series | None:
    """Full BC's row, when it was compared with constant velocity ego by ego."""
    full = table[(table.setting == READOUT_SETTING) & (table.method == BC)]
    return None if full.empty or pd.isna(full.iloc[0].get("real_vs_cv_win")) else full.iloc[0]


def _target_rows(table: pd.DataFrame) -> tuple[list[tuple[str, str, str]], pd.Series] | None:
    """Full BC against :data:`~igdrivsim.evaluation.schema.REAL_COMPETENCE` on the real egos:
    ``(target, Full BC, verdict)`` per target, and Full BC's row; None without them."""
    r, cv = _full_bc(table), table[table.method == CONSTANT_VELOCITY]
    if r is None or cv.empty:
        return None
    c, t = cv.iloc[0], REAL_COMPETENCE
    win, lo, hi = (100 * r[f"real_vs_cv_{k}"] for k in ("win", "win_lo", "win_hi"))
    offroad = r.real_offroad - t["offroad"] * c.real_offroad

    def verdict(gap: float, text: str) -> str:
        return "met" if gap <= 0 else f"missed by {text}"

    return [(f"closer to the log than CV on >= {100 * t['win']:.0f}% of the egos, the 95% "
             "interval's lower end above 50%", f"{win:.0f}% [{lo:.0f}, {hi:.0f}]",
             verdict(max(100 * t["win"] - win, 50 - lo),
                     f"{max(100 * t['win'] - win, 0):.0f} points (lower end by "
                     f"{max(50 - lo, 0):.0f})")),
            (f"mean log divergence <= {t['ratio']:.2f}x CV's",
             f"{r.real_vs_cv_ratio:.2f}x [{r.real_vs_cv_ratio_lo:.2f}, "
             f"{r.real_vs_cv_ratio_hi:.2f}]",
             verdict(r.real_vs_cv_ratio - t["ratio"], f"{r.real_vs_cv_ratio - t['ratio']:.2f}x")),
            (f"offroad <= {t['offroad']:g}x CV's",
             f"{r.real_offroad:.1f}% vs {c.real_offroad:.1f}%",
             verdict(offroad, f"{offroad:.1f} points"))], r


def real_targets(table: pd.DataFrame) -> list[str]:
    """The targets section of ``real_logs.md``: each met or missed and by how much, and what
    these egos can detect at all (a miss below that is not a measured shortfall)."""
    if (found := _target_rows(table)) is None:
        return []
    rows, r = found
    win, lo, hi = (100 * r[f"real_vs_cv_{k}"] for k in ("win", "win_lo", "win_hi"))
    return ["", "## Full BC against the real-log targets", "",
            f"This project's targets for Full BC on the real egos, Table I's protocol (sampled "
            f"actions), against constant velocity (CV) on the same {int(r.real_vs_cv_egos)} "
            f"egos from {int(r.real_vs_cv_sources)} source scenarios. At 80% power these egos "
            f"detect a share closer to the log only beyond 50% +/- "
            f"{100 * r.real_vs_cv_win_mde:.0f} points and a mean ratio only beyond 1 +/- "
            f"{r.real_vs_cv_ratio_mde:.2f}; the share's 95% interval spans {hi - lo:.0f} points, "
            f"so its lower end clears 50% only for a share of about {50 + win - lo:.0f}% or "
            "more.", "", *md_head("target", "Full BC", "verdict"),
            *[md_row(*row) for row in rows]]


def _targets_line(table: pd.DataFrame) -> str | None:
    """The results page's sentence on the real-log targets."""
    if (found := _target_rows(table)) is None:
        return None
    return ("Against this project's real-log targets: " + "; ".join(
        f"{target} ({value}): {verdict}" for target, value, verdict in found[0])
        + " ([real_logs.md](PAPER/tables/real_logs.md#full-bc-against-the-real-log-targets)).")


def _vs_cv_cell(row: pd.Series) -> str:
    if pd.isna(row.get("real_vs_cv_diff")):
        return "--"
    return (f"{row.real_vs_cv_diff:+.2f} [{row.real_vs_cv_lo:+.2f}, {row.real_vs_cv_hi:+.2f}], "
            f"MDE {row.real_vs_cv_mde:.2f}")


def _cell(row: pd.Series, source: str, key: str) -> str:
    value, n = row.get(f"{source}_{key}"), row.get(f"{source}_n")
    if pd.isna(value) or pd.isna(n):
        return "--"
    digits = 2 if key == "log_divergence" else 1
    return f"{value:.{digits}f} (N={int(n)})"


def _label(row: pd.Series) -> tuple[str, str]:
    return ("--" if row.method in REFERENCES else setting_short(row.setting),
            METHOD_LABELS.get(row.method, row.method))


def _egos_text(table: pd.DataFrame) -> str:
    """`` (N egos from M source scenarios)``: the real logs' constant-velocity row's counts."""
    cv = table[table.method == CONSTANT_VELOCITY]
    if cv.empty or cv[["real_n", "real_sources"]].iloc[0].isna().any():
        return ""
    return f" ({int(cv.real_n.iloc[0])} egos from {int(cv.real_sources.iloc[0])} source scenarios)"


def real_logs_markdown(table: pd.DataFrame, real_label: str, validation_label: str,
                       readouts: pd.DataFrame | None = None) -> str:
    """The tables as Markdown: the metrics, ego by ego, the read-outs."""
    head = ["setting", "method"] + [f"{HEADERS[k]}, {s}" for k in STEP_METRICS
                                     for s in SOURCES] + [VS_CV_HEADER]
    lines = ["# Synthetic-trained drivers on real logs (beyond the paper)", "",
             f"Real: {real_label}{_egos_text(table)}. Validation: {validation_label}. "
             "Each value is the mean "
             "over seeds of each seed's mean over scenarios; N is the number of scenarios "
             "(egos, when every vehicle is the ego in turn). "
             "The last column: a learned driver's real log divergence minus constant "
             "velocity's on the same scenarios, its 95% interval (bootstrap resampling source "
             "scenarios, then seeds) and the smallest difference these scenarios detect "
             "at 80% power (MDE); a few real scenarios cannot separate the methods.",
             "", *md_head(*head)]
    lines += [md_row(*_label(row), *[_cell(row, s, k) for k in STEP_METRICS for s in SOURCES],
                     _vs_cv_cell(row)) for _, row in table.iterrows()]
    extra = [] if readouts is None else readout_markdown(readouts)
    return "\n".join(lines + real_targets(table) + _paired_markdown(table) + extra) + "\n"


def real_logs_latex(table: pd.DataFrame, real_label: str, validation_label: str) -> str:
    """The table as a LaTeX ``table`` (booktabs)."""
    lines = [r"\begin{table}[t]", r"\centering", r"\small",
             r"\begin{tabular}{ll" + "rr" * len(STEP_METRICS) + "}", r"\toprule",
             " & & " + tex_row(*[rf"\multicolumn{{2}}{{c}}{{{_tex(HEADERS[k])}}}"
                                 for k in STEP_METRICS]),
             tex_row("setting", "method", *["validation & real"] * len(STEP_METRICS)), r"\midrule"]
    lines += [tex_row(*[_tex(c) for c in _label(row)], *[_cell(row, s, k) for k in STEP_METRICS
                                                         for s in SOURCES])
              for _, row in table.iterrows()]
    lines += [r"\bottomrule", r"\end{tabular}",
              r"\caption{Synthetic-trained drivers on real logs (beyond the paper). Real: "
              + _tex(real_label) + ". Validation: " + _tex(validation_label) + ". Mean over seeds "
              r"of each seed's mean over scenarios; N: scenarios. Differences from constant "
              r"velocity with their intervals and detectable effects: "
              r"\texttt{tables/real\_logs.md}.}", r"\label{tab:real-logs}", r"\end{table}"]
    return "\n".join(lines) + "\n"


def _span(values: pd.Series, digits: int) -> str:
    """``lo-hi``, or one value when they agree at ``digits``."""
    lo, hi = f"{values.min():.{digits}f}", f"{values.max():.{digits}f}"
    return lo if lo == hi else f"{lo}-{hi}"


def real_logs_summary(table: pd.DataFrame, metre: str = " m") -> str | None:
    """The abstract's sentence; None without constant velocity."""
    cv = table[table.method == CONSTANT_VELOCITY]
    learned = table[~table.method.isin(REFERENCES)].dropna(subset=["real_log_divergence"])
    if cv.empty or learned.empty or pd.isna(cv.real_log_divergence.iloc[0]):
        return None
    ref, n = float(cv.real_log_divergence.iloc[0]), int(cv.real_n.iloc[0])
    farther = int((learned.real_log_divergence > ref).sum())
    ranges = "; ".join(
        f"{METHOD_LABELS.get(m, m)} {_span(g.real_log_divergence, 2)}{metre}"
        for m, g in learned.groupby("method", sort=False))
    verdict = ("every learned driver drifts farther from the log than constant velocity"
               if farther == len(learned) else
               f"{farther} of {len(learned)} learned (setting, method) drivers drift farther "
               "from the log than constant velocity")
    power = ""
    if "real_vs_cv_mde" in learned and learned.real_vs_cv_mde.notna().any():
        power = (f"; at 80% power these scenarios detect only differences of "
                 f"{_span(learned.real_vs_cv_mde.dropna(), 1)}{metre} or more")
    closer = ""
    if "real_vs_cv_win" in learned and learned.real_vs_cv_win.notna().any():
        closer = (f"; ego by ego, they stay closer to the log than constant velocity on "
                  f"{_span(100 * learned.real_vs_cv_win.dropna(), 0)}% of the egos")
        if (r := _full_bc(learned)) is not None:
            closer += (f", Full BC on {100 * r.real_vs_cv_win:.0f}% (95% CI "
                       f"{100 * r.real_vs_cv_win_lo:.0f}-{100 * r.real_vs_cv_win_hi:.0f}%)")
    where = f"{n} real scenarios"
    if "real_sources" in cv and pd.notna(cv.real_sources.iloc[0]) \
            and int(cv.real_sources.iloc[0]) != n:
        where = f"{n} real egos from {int(cv.real_sources.iloc[0])} source scenarios"
    return (f"On {where}, {verdict}: {ref:.2f}{metre} for constant velocity "
            f"against {ranges} over the settings{power}{closer}.")


def _summary_tex(table: pd.DataFrame) -> str:
    sentence = real_logs_summary(table, metre="~m")
    body = "" if sentence is None else (
        _tex(sentence[:-1]) + r" (mean log divergence; Table~\ref{tab:real-logs}).")
    return "% Generated by igdrivsim.report.real_logs; do not edit.\n" + body + "\n"


def write_tables(real: str | Path, validation: str | Path | None, out: str | Path,
                 real_label: str, validation_label: str,
                 readouts: str | Path | None = None) -> list[Path]:
    """Write ``out/real_logs*`` from the evaluation folders; the paths."""
    real_frame = load_evaluations([real])[1]
    table = real_log_table(real_frame, load_evaluations([validation])[1] if validation else None)
    modes = readout_table(real_frame, readouts)
    out = Path(out)
    return [atomic_write_text(out / "real_logs.md",
                              real_logs_markdown(table, real_label, validation_label, modes)),
            atomic_write_text(out / "real_logs_readouts.csv", modes.to_csv(index=False)),
            atomic_write_text(out / "real_logs.tex",
                              real_logs_latex(table, real_label, validation_label)),
            *write_numbers(table, out)]


def write_numbers(table: pd.DataFrame, out: Path) -> list[Path]:
    """``out/real_logs.csv`` (the table's numbers) and ``out/real_logs_summary.tex``."""
    return [atomic_write_text(out / "real_logs.csv", table.to_csv(index=False)),
            atomic_write_text(out / "real_logs_summary.tex", _summary_tex(table))]


# ------------------------------------------------------------------ the results page
READOUTS = {"sample": "sampled (Table I)"}  # a read-out's name in the table, when not its own
VS_CV_HEAD = ("N egos (sources)", "closer than CV [95% CI]", "mean / CV [95% CI]")


def _vs_cv(row: pd.Series) -> list[str]:
    """:data:`VS_CV_HEAD`'s cells: N egos, the share closer to the log than CV, the ratio."""
    n, win, _, ratio = paired_cells(row, "real_vs_cv_", mde=False)
    return [n, win, ratio]


def _full_bc_line(table: pd.DataFrame) -> str | None:
    """The headline sentence on Full BC; None without that comparison."""
    if (r := _full_bc(table)) is None:
        return None
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
    return ["", "Full BC's action read-outs (Table I samples its actions):", "",
            *md_head("actions", *VS_CV_HEAD, "median - CV (m)"),
            *[md_row(READOUTS.get(r.actions, r.actions), *_vs_cv(r), f"{r.real_vs_cv_median:+.2f}")
              for _, r in modes.iterrows()]]


def real_logs_section(tables: Path, headline: str | None = None) -> list[str]:
    """The real-log section of ``results.md`` (``headline``: the README's)."""
    table = read_table(tables / "real_logs.csv")
    if table is None or (sentence := real_logs_summary(table)) is None:
        return []
    full = _full_bc_line(table)
    if headline:
        text = full or sentence.rstrip(".")
        return wrap(text + f"; every setting: [{headline}]({headline}#on-real-logs).")
    learned = [m for m in dict.fromkeys(table.method) if m not in REFERENCES]
    settings = [s for s in dict.fromkeys(table.setting) if s != REFERENCE_SETTING]
    rows = {(r.setting, r.method): r for _, r in table.iterrows()}
    ego_table = []
    if "real_vs_cv_win" in table and table.real_vs_cv_win.notna().any():
        ego_table = [*wrap("Against constant velocity, ego by ego: the share of egos where the "
                           "driver stays closer to the log (a tie counts half) and its mean log "
                           "divergence over constant velocity's, with 95% intervals (bootstrap "
                           "over source scenarios, then seeds); N egos (source scenarios). All "
                           "statistics: [real_logs.md](PAPER/tables/real_logs.md)."), "",
                     *md_head("setting", "method", *VS_CV_HEAD)]
        ego_table += [md_row(setting_short(s), METHOD_LABELS.get(m, m), *_vs_cv(rows[s, m]))
                      for s in settings for m in learned
                      if (s, m) in rows and pd.notna(rows[s, m].real_vs_cv_egos)]
        ego_table += [*_readouts(tables), ""]

    def cell(key: tuple[str, str], source: str) -> str:
        return _cell(rows[key], source, "log_divergence") if key in rows else "--"

    head = [f"{METHOD_LABELS.get(m, m)}, {src}" for src in ("real", "validation")
            for m in learned]
    targets = _targets_line(table)
    out = ["## On real logs", "", *(wrap(full + ".") + [""] if full else []),
           *(wrap(targets) + [""] if targets else []), *ego_table,
           *wrap(sentence), "",
           "Log divergence (m), mean over seeds of each seed's mean over scenarios; N: "
           "scenarios. Every metric: [real_logs.md](PAPER/tables/real_logs.md).", "",
           *md_head("setting", *head)]
    cv = [(REFERENCE_SETTING, CONSTANT_VELOCITY)] * len(learned)
    for name, keys in [*[(setting_short(s), [(s, m) for m in learned]) for s in settings],
                       ("constant velocity", cv)]:
        out.append(md_row(name, *[cell(k, src) for src in ("real", "validation") for k in keys]))
    return [*out, ""]
