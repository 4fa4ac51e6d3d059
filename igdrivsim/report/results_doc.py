"""The report's markdown, ``results.md`` and the README's blocks, read from the report's own
files only (so ``igdrivsim report --from-tables`` rewrites them without the evaluations)."""

from __future__ import annotations

import math
import os
import re
from pathlib import Path

import pandas as pd

from igdrivsim.errors import ConfigError, DataError
from igdrivsim.evaluation.schema import COMPETENCE, PAPER_TABLE1, REFERENCE_SETTING, table_settings
from igdrivsim.io import atomic_write_csv, atomic_write_text, read_json
from igdrivsim.names import BC, BC_RL, EXPERT, METHOD_LABELS, setting_short
from igdrivsim.report import methods_table, tables
from igdrivsim.report.provenance import load as load_provenance
from igdrivsim.report.provenance import wall_text
from igdrivsim.report.real_logs import real_logs_section
from igdrivsim.report.results_tex import reactive_section, read_table, write_macros
from igdrivsim.report.tables import _fmt, _test_row, md_head, md_row, table1_markdown, wrap

BEGIN, END = "<!-- results:begin -->", "<!-- results:end -->"
# the README's block near the top: measured run times and the choice of profile (optional)
RUNTIME_BEGIN, RUNTIME_END = "<!-- runtime:begin -->", "<!-- runtime:end -->"
CURVES_SUMMARY = "curves_summary.csv"
RUN_TIMES = "run_times.csv"
_HEADLINE = (("log_divergence", "log div. (m)"), ("offroad", "offroad (%)"),
             ("overlap", "overlap (%)"))


def _bullet(text: str) -> list[str]:
    return wrap("- " + text, indent="  ")


def provenance(paper: Path) -> dict[str, str]:
    """The ``\\ProvX`` macros of ``generated/provenance.tex`` as ``{"Profile": ..., ...}``."""
    path = paper / "generated" / "provenance.tex"
    if not path.is_file():
        return {}
    found = re.findall(r"\\newcommand\{\\Prov(\w+)\}\{(.*)\}", path.read_text(encoding="utf-8"))
    return {key: value.replace("\\_", "_").replace("\\%", "%") for key, value in found}


def _command(entry: dict, quote: str = "") -> str:
    """The command and profile of a ``provenance.json`` entry (the profile within ``quote``)."""
    updates = f", {entry['updates']:,} updates" if entry.get("updates") else ""
    profile = f"{quote}{entry.get('profile', '?')}{quote}"
    return f"`{entry.get('command', '?')}` (profile {profile}{updates})"


def run_line(paper: Path, commit: bool = True) -> str:
    """How the run behind Table I was made (``paper/provenance.json``); empty without it."""
    files = load_provenance(Path(paper))
    entry = files.get("tables/table1.md") or files.get("tables/summary.csv")
    if not isinstance(entry, dict):
        return ""
    wall = entry.get("wall_s")
    parts = [_command(entry)]
    if commit:
        parts.append(f"commit {entry.get('commit', '?')}")
    parts += [str(entry.get("device", "device not recorded")),
              f"{wall_text(float(wall))} wall" if wall else "wall time not recorded",
              str(entry.get("date", ""))]
    note = f"; {entry['note']}" if entry.get("note") else ""
    if not commit:  # no commit hash at all (the README)
        note = re.sub(r"\s*(?:as of |at |commit )?\b[0-9a-f]{7,40}\b", "", note)
    return "Run: " + ", ".join(parts) + note + "."


def _signed(value: float) -> str:
    return tables._signed(value) if math.isfinite(value) else "--"


def _interval(row: pd.Series | None) -> str:
    if row is None:
        return "--"
    text = f"{_signed(row['diff'])} [{_signed(row.ci_low)}, {_signed(row.ci_high)}]"
    return f"**{text}**" if bool(row.significant) else text


def _scope(prov: dict[str, str], summary: pd.DataFrame) -> str:
    learned = summary[summary.method.isin([BC, BC_RL])]
    seeds = int(learned.n_seeds.max()) if len(learned) else 0
    scenarios = int(summary.n_scenarios.max()) if len(summary) else 0
    return (f"profile `{prov.get('Profile', 'unknown')}`, data: {prov.get('Data', 'unknown')}, "
            f"{seeds} seeds, {scenarios} validation scenarios, sampled actions")


def headline_markdown(paper: str | Path, results_link: str = "docs/results.md") -> str:
    """The README's short results table (BC and BC-RL per setting, the offroad effect)."""
    paper = Path(paper)
    summary = read_table(paper / "tables" / "summary.csv")
    if summary is None:
        return "No results yet: run the reproduction (`bash scripts/reproduce.sh`).\n"
    tests = read_table(paper / "tables" / "tests.csv")
    prov = provenance(paper)
    cv = tables.reference_means(summary, dict(_HEADLINE))
    out = [*wrap(f"Written by `igdrivsim report` from the run of "
                 f"{prov.get('Date', 'unknown date')} ({_scope(prov, summary)}). Mean over "
                 "seeds; BC-RL − BC with its 95% two-level bootstrap interval, in percentage "
                 "points of steps offroad, **bold** if significant after Holm."), "",
           *md_head("setting", *[f"BC {label}" for _, label in _HEADLINE],
                    "BC-RL − BC offroad", "paper's BC-RL − BC offroad")]
    for setting in tables.present_settings(summary):
        cells = [_fmt(tables.cell_mean(summary, m, setting, BC)) for m, _ in _HEADLINE]
        paper_effect = PAPER_TABLE1["offroad"].get(setting)
        paper_text = _signed(paper_effect[0] - paper_effect[1]) if paper_effect else "--"
        out.append(md_row(setting_short(setting), *cells,
                          _interval(_test_row(tests, "offroad", setting)), paper_text))
    out.append("| constant velocity | " + " | ".join(_fmt(cv[m]) for m, _ in _HEADLINE)
               + " | | |")
    cells = tables._cells(tests)  # BC-RL - BC
    k = int(cells.significant.astype(bool).sum()) if len(cells) else 0
    closing = f"BC-RL differs from BC in {k} of {len(cells)} cells of Table I after Holm."
    if line := run_line(paper, commit=False):
        closing += " " + line
    elif math.isfinite(wall := wall_seconds(read_table(paper / "tables" / RUN_TIMES))):
        closing += (f" The run took {wall_text(wall)} from its first stage's start to the "
                    "report (`tables/run_times.csv`).")
    closing += f" Full results: [{results_link}]({results_link})."
    real = real_logs_section(paper / "tables", headline=results_link)
    return "\n".join([*out, "", *wrap(closing), *(["", *real] if real else [])]) + "\n"


def _competence(summary: pd.DataFrame) -> list[str]:
    settings = tables.present_settings(summary)
    methods = [m for m in (BC, BC_RL) if m in set(summary.method)]
    cv = tables.reference_means(summary, COMPETENCE)
    if not settings or not methods or not all(math.isfinite(v) for v in cv.values()):
        return ["No constant-velocity reference in this run.", ""]
    bars = ", ".join(f"{label} at most {ratio:g}x constant velocity's"
                     for ratio, label, _ in COMPETENCE.values())
    out = [f"Targets (this project's, not the paper's): {bars}. Each cell: the value, its ratio "
           "to constant velocity, and whether the target is met.", "",
           *md_head("setting", "method", *[f"{label} ({unit})" for _, label, unit in
                                           COMPETENCE.values()], "targets met"),
           "| target | | " + " | ".join(f"<= {_fmt(ratio * cv[m])}" for m, (ratio, _, _) in
                                       COMPETENCE.items()) + " | |"]
    for setting in settings:
        for method in methods:
            cells, met = [], 0
            for metric, (ratio, _, _) in COMPETENCE.items():
                value = tables.cell_mean(summary, metric, setting, method)
                ok = math.isfinite(value) and value <= ratio * cv[metric]
                met += ok
                ratio_text = f" ({value / cv[metric]:.2f}x)" if cv[metric] > 0 else ""
                cells.append(f"{_fmt(value)}{ratio_text}{' ✓' if ok else ''}")
            out.append(md_row(setting_short(setting), METHOD_LABELS.get(method, method), *cells,
                              f"{met} of {len(COMPETENCE)}"))
    expert = [f"{label} {_fmt(tables.cell_mean(summary, m, REFERENCE_SETTING, EXPERT))} {unit}"
              for m, (_, label, unit) in COMPETENCE.items()]
    return out + ["", "The discretised expert's replay on the same scenarios: "
                  + ", ".join(expert) + ".", ""]


def curves_summary(curves: pd.DataFrame) -> pd.DataFrame:
    """Per (setting, method): the last two validation updates, mean over seeds."""
    cols = ["val_bc_loss", "log_divergence", "offroad", "overlap"]
    rows = []
    validated = curves.dropna(subset=["val_bc_loss"])
    for (setting, method), part in validated.groupby(["setting", "method"], sort=True):
        means = part.groupby("update")[cols].mean().sort_index()
        last = means.iloc[-1]
        prev = means.iloc[-2] if len(means) > 1 else last * math.nan
        rows.append(dict(setting=setting, method=method, update=int(means.index[-1]),
                         previous_update=int(means.index[-2]) if len(means) > 1 else -1,
                         **{c: float(last[c]) for c in cols},
                         **{f"{c}_previous": float(prev[c]) for c in cols}))
    return pd.DataFrame(rows, columns=["setting", "method", "update", "previous_update", *cols,
                                       *[f"{c}_previous" for c in cols]])


def _curves(curves: pd.DataFrame | None) -> list[str]:
    if curves is None or not len(curves):
        return ["Not in these tables (`tables/curves_summary.csv` is written when the report "
                "finds the runs' `curves.jsonl`).", ""]
    out = ["Mean over seeds on the fixed validation subset of the learning curves, at the last "
           "validation update and the one before it (Fig. 4).", "",
           *md_head("setting", "method", "updates", "validation BC loss (nats)",
                    "log divergence (m)", "offroad (% steps)", "overlap (% steps)")]

    def pair(row, col: str, scale: float = 1.0, digits: int = 2) -> str:
        a, b = getattr(row, f"{col}_previous") * scale, getattr(row, col) * scale
        return f"{a:.{digits}f} -> {b:.{digits}f}" if math.isfinite(a) else f"{b:.{digits}f}"

    order = {s: i for i, s in enumerate(table_settings(curves))}
    curves = curves.sort_values(["setting", "method"], key=lambda c: c.map(order).fillna(
        len(order)) if c.name == "setting" else c)
    for row in curves.itertuples():
        updates = f"{row.previous_update} -> {row.update}" if row.previous_update >= 0 else (
            str(row.update))
        out.append(md_row(setting_short(row.setting), METHOD_LABELS.get(row.method, row.method),
                          updates, pair(row, "val_bc_loss", digits=3),
                          pair(row, "log_divergence"), pair(row, "offroad", 100),
                          pair(row, "overlap", 100)))
    return out + [""]


def wall_seconds(times: pd.DataFrame | None) -> float:
    """From the first stage's start to the last stage's end (NaN without stage times)."""
    if times is None or not len(times):
        return math.nan
    end = pd.to_datetime(times.finished, errors="coerce")
    start = end - pd.to_timedelta(times.seconds, unit="s")
    return float((end.max() - start.min()).total_seconds())


HOUR = 3600.0  # the default run's time target (seconds)


def against_an_hour(times: pd.DataFrame) -> str:
    """Which stages hold the run above :data:`HOUR` and by how much: the training stages' share
    of the stages' summed time, and the factor they must shrink by at this run's overlap."""
    wall, total = wall_seconds(times), float(times.seconds.sum())
    if not math.isfinite(wall) or wall <= 0:
        return ""
    if wall <= HOUR:
        return f"Within an hour ({wall_text(wall)})."
    kinds = times.stage.str.split("_").str[0].replace({"evaluate": "evaluation"})
    by_kind = times.seconds.groupby(kinds).sum().sort_values(ascending=False)
    train = float(by_kind.get("train", 0.0))
    room = HOUR * total / wall - (total - train)  # training time that fits at this overlap
    shares = ", ".join(f"{k} {100 * v / total:.0f}%" for k, v in by_kind.items()
                       if v >= 0.01 * total)
    cut = (f"training must shrink {train / room:.1f}x for an hour" if room > 0 else
           "even without training the stages take more than an hour")
    return (f"Against an hour: the stages add up to {total:,.0f} s on the workers, run in "
            f"{wall:,.0f} s (on average {total / wall:.2f} stages at once): {shares}; at that "
            f"overlap {cut}.")


def _run_times(times: pd.DataFrame | None) -> list[str]:
    if times is None or not len(times):
        return ["Not in these tables (`tables/run_times.csv` is written when the report runs "
                "inside `scripts/reproduce.sh`).", ""]
    wall = wall_seconds(times)
    out = [f"{wall_text(wall)} from the first stage's start to the last stage's end. "
           + against_an_hour(times) if math.isfinite(wall) else "", "",
           "Seconds per stage (`WORK/stages/<stage>.json`; stages in two lanes overlap, so the "
           "wall time is below their sum).", "", *md_head("stage", "seconds", "finished")]
    out += [md_row(r.stage, f"{r.seconds:.0f}", str(r.finished)) for r in times.itertuples()]
    return out + [""]


def _maze(maze: pd.DataFrame | None) -> list[str]:
    if maze is None or not len(maze):
        return ["Not in these tables.", ""]
    out = ["Final return, mean ± 95% CI over seeds ([tables/maze_summary.md]"
           "(PAPER/tables/maze_summary.md)).", "",
           *md_head("curve", "return", "episode length", "seeds")]
    out += [md_row(r.curve, f"{r.final_return_mean:.2f} ± {r.final_return_ci95:.2f}",
                   f"{r.final_length_mean:.1f}", str(int(r.seeds))) for r in maze.itertuples()]
    return out + [""]


def _demote(markdown: str) -> list[str]:
    return [("#" + line if line.startswith("#") else line) for line in markdown.splitlines()]


def _table2(tables: Path, summary: pd.DataFrame, header: str) -> list[str]:
    """Table II of the run that owns it, else rebuilt from ``tests_all.csv``."""
    tests_all = read_table(tables / "tests_all.csv")
    if tests_all is None:
        return []
    own = tables / "table2.md"
    if own.is_file():
        return _demote(own.read_text(encoding="utf-8").rstrip()) + [""]
    missing = tests_all[~tests_all.method.isin(set(summary.method))]
    extra = pd.DataFrame(dict(metric=missing.metric, setting=missing.setting,
                              method=missing.method, mean=missing.mean_a, ci_low=math.nan,
                              ci_high=math.nan, n_seeds=missing.n_seeds_a))
    full = pd.concat([summary, extra], ignore_index=True) if len(extra) else summary
    return _demote(methods_table.table2_markdown(full, tests_all, header)) + [""]


def results_markdown(paper: str | Path, paper_link: str = ".") -> str:
    """The whole run as one markdown page (``paper_link``: the paper folder)."""
    paper = Path(paper)
    tables = paper / "tables"
    summary = read_table(tables / "summary.csv")
    if summary is None:
        raise ConfigError(f"{tables / 'summary.csv'}: no report tables here (run `igdrivsim "
                          "report --evals ...` first)")
    tests = read_table(tables / "tests.csv")
    prov = provenance(paper)
    header = f"Profile `{prov.get('Profile', 'unknown')}`, data `{prov.get('Data', 'unknown')}`."
    out = ["# Results", "",
           "<!-- Generated by `igdrivsim report`; do not edit: rerun the report instead. -->", "",
           f"Run of {prov.get('Date', 'unknown date')}, commit {prov.get('Commit', 'unknown')}: "
           f"{_scope(prov, summary)}.", "", "## Run time", "",
           *([run_line(paper), ""] if run_line(paper) else []),
           *_run_times(read_table(tables / RUN_TIMES)),
           *real_logs_section(tables),
           "## Competence against the reference actors", "", *_competence(summary),
           *_demote(table1_markdown(summary, tests if tests is not None else
                                    pd.DataFrame(columns=["method"]), header)), "",
           "Cell by cell next to the paper: [vs_paper.md](PAPER/tables/vs_paper.md); the power "
           "table alone: [power.md](PAPER/tables/power.md); metrics beyond Table I: "
           "[supplementary_metrics.md](PAPER/tables/supplementary_metrics.md).", "",
           *reactive_section(read_table(tables / "reactive.csv")),
           "## Learning curves", "", *_curves(read_table(tables / CURVES_SUMMARY))]
    out += _table2(tables, summary, header)
    out += ["## Maze (paper Fig. 2)", "", *_maze(read_table(tables / "maze_summary.csv"))]
    return ("\n".join(out).rstrip() + "\n").replace("](PAPER/", f"]({paper_link.rstrip('/')}/")


def fill_block(text: str, content: str, source: str = "README", begin: str = BEGIN,
               end: str = END) -> str:
    """``text`` with what lies between ``begin`` and ``end`` replaced by ``content``."""
    start, stop = text.find(begin), text.find(end)
    if start < 0 or stop < start:
        raise ConfigError(f"{source}: no {begin} ... {end} block to fill")
    return text[:start + len(begin)] + "\n" + content.rstrip() + "\n" + text[stop:]


_RUNS = (("tables/table1.md", "Table I", "the default run"),
         ("tables/table2.md", "Table II", "the methods run"))
COMPETENCE_ANCHOR = "#competence-against-the-reference-actors"


def runtime_markdown(paper: str | Path, results_link: str = "docs/results.md") -> str:
    """Each published run's wall time and machine, then the profiles."""
    # lazy: the training profiles pull in JAX; the rest of this module does not need it
    from igdrivsim.training.config import get_profile

    files = load_provenance(Path(paper))
    runs, gpu = [], False
    for rel, table, label in _RUNS:
        entry = files.get(rel)
        if not isinstance(entry, dict) or not entry.get("wall_s"):
            continue
        device = str(entry.get("device") or "")
        where = (f"on {device}" if device and "not recorded" not in device
                 else "(device not recorded)")
        runs += _bullet(f"{table}, {label}: {_command(entry, '`')} took "
                        f"{wall_text(float(entry['wall_s']))} {where}, {entry.get('date', '')}.")
        gpu |= entry.get("profile") == "gpu"
    out = ["Measured run times (the report writes them from `paper/provenance.json`"
           + ("):" if gpu else "; no GPU run is recorded):"), "",
           *(runs or ["- no run with a recorded wall time."]), ""]
    n = {name: get_profile(name).training.num_updates for name in ("laptop", "quick", "gpu")}
    targets = f"[competence targets]({results_link}{COMPETENCE_ANCHOR})"
    out += [*wrap("Profiles (`--profile`; their sizes: `igdrivsim/training/config.py` and "
                  "`igdrivsim/pipeline/profiles.py`; the plan printed first estimates the time "
                  "on your machine):"), "",
            *_bullet(f"`laptop`: the default, {n['laptop']:,} updates;"),
            *_bullet(f"`quick`: {n['quick']:,} updates, a first look below the {targets};"),
            *_bullet(f"`gpu`: {n['gpu']:,} updates, more seeds and validation scenarios, "
                     "one GPU;"),
            *_bullet("`paper`: the paper's network and batch, for GPUs and real WOMD;"),
            *_bullet("`smoke`: minutes; everything runs, the numbers mean nothing.")]
    return "\n".join(out) + "\n"


def write_curves_summary(curves: pd.DataFrame, tables: Path) -> list[Path]:
    """``tables/curves_summary.csv`` (nothing when there are no curves)."""
    if curves.empty:
        (tables / CURVES_SUMMARY).unlink(missing_ok=True)
        return []
    return [atomic_write_csv(tables / CURVES_SUMMARY, curves_summary(curves).round(6))]


def write_run_times(work: str | Path, tables: Path) -> list[Path]:
    """``tables/run_times.csv`` from the pipeline's ``WORK/stages/*.json``."""
    rows = []
    for path in sorted(Path(work).glob("stages/*.json")):
        info = read_json(path)
        try:
            rows.append(dict(stage=info["stage"], seconds=float(info["seconds"]),
                             finished=str(info.get("finished", ""))))
        except (ValueError, KeyError, TypeError) as err:
            raise DataError(f"not a stage record ({err!r})", file=str(path)) from err
    if not rows:
        return []
    frame = pd.DataFrame(rows).sort_values(["finished", "stage"])
    return [atomic_write_csv(tables / RUN_TIMES, frame)]


def write_markdown(paper: str | Path, results: str | Path | None,
                   readme: str | Path | None = None) -> list[Path]:
    """Write ``results``, fill ``readme``'s blocks and rewrite the PDF's macros."""
    paper = Path(paper)
    results = Path(results) if results else paper / "results.md"
    link = os.path.relpath(paper.resolve(), results.resolve().parent)
    written = [atomic_write_text(results, results_markdown(paper, link))]
    if readme:
        readme = Path(readme)
        if not readme.is_file():
            raise ConfigError(f"--readme {readme}: no such file")
        res_link = os.path.relpath(results.resolve(), readme.resolve().parent)
        text = readme.read_text(encoding="utf-8")
        text = fill_block(text, headline_markdown(paper, res_link), str(readme))
        if RUNTIME_BEGIN in text:
            text = fill_block(text, runtime_markdown(paper, res_link), str(readme),
                              RUNTIME_BEGIN, RUNTIME_END)
        written.append(atomic_write_text(readme, text))
    return written + write_macros(paper)
