"""Fig. 3 (BC versus BC-RL), 4 (learning curves), 5 (supplementary metrics) and 6 (every learned
method). Bar panels: per setting a group of bars (mean over seeds, 95% t-interval clipped to the
metric's range), asterisks where significant after Holm (``fig.marked``: each panel's metric ->
its asterisked ``(setting, method)`` cells), the reference actors as horizontal lines."""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path

import matplotlib
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
import seaborn as sns
from matplotlib.container import BarContainer
from matplotlib.lines import Line2D

from igdrivsim.errors import DataError
from igdrivsim.evaluation.aggregate import ALPHA, t_interval
from igdrivsim.evaluation.schema import METRIC_BY_KEY
from igdrivsim.io import atomic_savefig
from igdrivsim.names import BC, BC_RL, CONSTANT_VELOCITY, EXPERT, METHOD_LABELS, setting_short
from igdrivsim.report import methods_table
from igdrivsim.report.results_tex import read_table
from igdrivsim.report.tables import _metric_name, present_settings
from igdrivsim.training.methods import METHODS as METHOD_REGISTRY
from igdrivsim.training.run import CURVES as CURVES_FILE

matplotlib.use("Agg")  # figures are files; never open a window

Cell = tuple[str, str]  # (setting, method)

# what each unit can take; other units (e.g. "ratio") are not clipped
FEASIBLE: dict[str, tuple[float, float]] = {
    "%": (0.0, 100.0), "score": (0.0, 1.0),
    **dict.fromkeys(("m", "s", "m/s", "m/s²", "m/s³", "rad/s"), (0.0, math.inf))}
REFERENCE_STYLE: dict[str, dict] = {  # distinct colour, dash and width, labelled in the legend
    CONSTANT_VELOCITY: dict(color="#b2182b", linestyle="-.", linewidth=1.2),
    EXPERT: dict(color="0.1", linestyle=":", linewidth=1.5),
}
SIGNIFICANT = "*"


def feasible_range(unit: str) -> tuple[float, float]:
    """``(low, high)`` a metric in ``unit`` can take (unbounded for an unknown unit)."""
    return FEASIBLE.get(unit, (-math.inf, math.inf))


def clip_interval(low: float, high: float, unit: str) -> tuple[float, float]:
    """A confidence interval clipped to :func:`feasible_range` (NaN bounds stay NaN)."""
    lo, hi = feasible_range(unit)
    return tuple(float(np.clip(v, lo, hi)) if math.isfinite(v) else v for v in (low, high))


def cell_stats(frame: pd.DataFrame, metric: str, unit: str) -> pd.DataFrame:
    """``setting, method, mean, low, high`` of ``metric``, clipped to the unit's range."""
    part = frame[frame.metric == metric]
    if "value" in part.columns:
        groups = part.groupby(["setting", "method"], sort=False)
        rows = [(setting, method, *t_interval(values))
                for (setting, method), cell in groups
                if (values := cell["value"].dropna().to_numpy(float)).size]
    else:
        rows = [(r.setting, r.method, float(r.mean), float(r.ci_low), float(r.ci_high))
                for r in part.itertuples()]
    out = []
    for setting, method, mean, low, high in rows:
        if not math.isfinite(low):  # one seed: no interval
            low = high = mean
        out.append((str(setting), str(method), mean, *clip_interval(low, high, unit)))
    return pd.DataFrame(out, columns=["setting", "method", "mean", "low", "high"])


def significant_cells(tests: pd.DataFrame | None, metric: str) -> set[Cell]:
    """``(setting, method)`` of the rows of ``tests`` significant after Holm."""
    if tests is None or len(tests) == 0:
        return set()
    rows = tests[(tests.metric == metric) & tests.significant.astype(bool)]
    return {(str(r.setting), str(r.method)) for r in rows.itertuples()}


def draw_bars(ax, cells: pd.DataFrame, settings: Sequence[str], methods: Sequence[str],
              colours: Mapping[str, str], labels: Mapping[str, str]) -> dict[Cell, tuple]:
    """The bars of ``cells`` grouped by setting; ``(setting, method) -> (x, top)``."""
    width = 0.8 / max(1, len(methods))
    positions: dict[Cell, tuple] = {}
    labelled: set[str] = set()
    by_cell = {(r.setting, r.method): r for r in cells.itertuples()}
    for g, setting in enumerate(settings):
        present = [m for m in methods if (setting, m) in by_cell
                   and math.isfinite(by_cell[setting, m].mean)]
        for k, method in enumerate(present):
            r = by_cell[setting, method]
            x = g + (k - (len(present) - 1) / 2) * width
            ax.bar(x, r.mean, width * 0.95, color=colours[method],
                   label=None if method in labelled else labels[method])
            labelled.add(method)
            err = np.array([[max(r.mean - r.low, 0.0)], [max(r.high - r.mean, 0.0)]])
            ax.errorbar(x, r.mean, yerr=err, fmt="none", ecolor="0.2", elinewidth=1.0,
                        capsize=2.5)
            positions[setting, method] = (x, max(r.mean, r.high))
    ax.set_xticks(range(len(settings)))
    ax.set_xlim(-0.5, len(settings) - 0.5)
    return positions


def mark_significant(ax, positions: Mapping[Cell, tuple], significant: set[Cell]) -> list[Cell]:
    """An asterisk above each drawn bar in ``significant``; the marked cells."""
    marked = sorted(c for c in significant if c in positions)
    if not marked:
        return []
    low, high = ax.get_ylim()
    pad = 0.03 * (high - low)
    for cell in marked:
        x, top = positions[cell]
        ax.text(x, top + pad, SIGNIFICANT, ha="center", va="bottom", fontsize=12,
                fontweight="bold", color="0.1")
    ax.set_ylim(low, max(high, *(positions[c][1] + 5 * pad for c in marked)))
    return marked


def reference_lines(ax, frame: pd.DataFrame, metric: str) -> None:
    """A labelled horizontal line at each reference actor's mean of ``metric``."""
    column = "value" if "value" in frame.columns else "mean"
    for method in (CONSTANT_VELOCITY, EXPERT):
        value = frame[(frame.method == method) & (frame.metric == metric)][column].mean()
        if pd.notna(value):
            ax.axhline(float(value), label=METHOD_LABELS[method], zorder=3,
                       **REFERENCE_STYLE[method])


def figure_handles(fig) -> dict[str, object]:
    """Each distinct legend entry of the figure's axes, first occurrence first."""
    handles: dict[str, object] = {}
    for ax in fig.axes:
        for handle, name in zip(*ax.get_legend_handles_labels(), strict=True):
            handles.setdefault(name, handle)
    return handles


PANELS = ("log_divergence", "overlap", "offroad")
CLIPPED = "error bars: 95% t-interval over seeds, clipped to the metric's range"


def _bar_panel(ax, frame: pd.DataFrame, key: str, unit: str, settings: Sequence[str],
               methods: Sequence[str], tests: pd.DataFrame | None) -> list[Cell]:
    """One metric's bars, references and significance marks on ``ax``; the marked cells."""
    cells = cell_stats(frame, key, unit)
    cells = cells[cells.method.isin(methods) & cells.setting.isin(settings)]
    ax.set_xticks(range(len(settings)), [setting_short(s) for s in settings])
    if cells.empty:
        ax.text(0.5, 0.5, "not evaluated", ha="center", va="center", transform=ax.transAxes)
        return []
    positions = draw_bars(ax, cells, settings, methods, methods_table.method_colours(methods),
                          {m: methods_table.method_label(m) for m in methods})
    reference_lines(ax, frame, key)
    low, _ = feasible_range(unit)
    if math.isfinite(low):  # rates and distances start at 0
        ax.set_ylim(bottom=low)
    return mark_significant(ax, positions, significant_cells(tests, key))


def _rotate_settings(ax) -> None:
    ax.tick_params(axis="x", labelbottom=True, rotation=30)
    for label in ax.get_xticklabels():
        label.set_horizontalalignment("right")


def _legend(fig, tested: bool, ncols: int, top: bool = True) -> int:
    """The legend above (``top``) or below the panels; returns its number of rows."""
    handles = figure_handles(fig)  # the methods' bars first, then the lines
    handles = dict(sorted(handles.items(), key=lambda kv: not isinstance(kv[1], BarContainer)))
    if tested:  # an entry explaining the asterisk
        star = Line2D([], [], linestyle="", marker="$*$", markersize=7, color="0.1",
                      label=f"significant vs {METHOD_LABELS[BC]} (Holm, α={ALPHA})")
        handles[star.get_label()] = star
    if not handles:
        return 0
    fig.legend(list(handles.values()), list(handles), frameon=False, ncols=ncols,
               loc="upper center" if top else "lower center",
               bbox_to_anchor=(0.5, 1.0) if top else (0.5, 0.0), fontsize=7)
    return math.ceil(len(handles) / ncols)


def _metric_column(frame: pd.DataFrame, settings: Sequence[str], methods: Sequence[str],
                   tests: pd.DataFrame | None, figsize: tuple[float, float], ncols: int):
    """Fig. 3 or 6: a panel per metric of :data:`PANELS` down one column, ``fig.marked``; the
    figure and its legend's rows."""
    sns.set_theme(style="whitegrid", context="paper")
    fig, axes = plt.subplots(len(PANELS), 1, figsize=figsize, sharex=True, squeeze=False)
    marked = {}
    for ax, key in zip(axes[:, 0], PANELS, strict=True):
        unit = METRIC_BY_KEY[key].unit
        marked[key] = _bar_panel(ax, frame, key, unit, settings, methods, tests)
        ax.set_ylabel(f"{_metric_name(METRIC_BY_KEY[key])} ({unit})")
    _rotate_settings(axes[-1, 0])
    fig.marked = marked
    return fig, _legend(fig, tests is not None and len(tests) > 0, ncols=ncols)


def fig3_metrics(seed_level: pd.DataFrame, tests: pd.DataFrame | None = None):
    """Fig. 3 from the seed means (or the summary) and BC-RL vs BC's ``tests``."""
    fig, rows = _metric_column(seed_level, present_settings(seed_level), (BC, BC_RL), tests,
                               (4.6, 7.0), 2)
    fig.text(0.01, 0.005, CLIPPED, fontsize=6, color="0.35")
    fig.tight_layout(rect=(0, 0.015, 1, 1 - 0.027 * rows))
    return fig


def save_figure(fig, out_dir: str | Path, stem: str) -> list[Path]:
    """Write ``stem.pdf`` and ``stem.png`` (reproducible PDF: no creation date)."""
    out_dir = Path(out_dir)
    paths = [atomic_savefig(fig, out_dir / f"{stem}.pdf", metadata={"CreationDate": None}),
             atomic_savefig(fig, out_dir / f"{stem}.png", dpi=200)]
    plt.close(fig)
    return paths


# Fig. 4 rows: (curves.jsonl key, y label, scale, per_scenario.csv column of the references).
CURVE_ROWS: tuple[tuple[str, str, float, str | None], ...] = (
    ("val_bc_loss", "validation BC loss (nats)", 1.0, None),
    ("log_divergence", "log divergence (m)", 1.0, "log_divergence"),
    ("offroad", "offroad (% steps)", 100.0, "offroad_steps"),
    ("overlap", "overlap (% steps)", 100.0, "overlap_steps"),
)


def load_curves(run_dirs: Iterable[str | Path]) -> pd.DataFrame:
    """Every ``curves.jsonl`` record, one row per (setting, method, seed, update)."""
    found: set[Path] = set()  # each run folder, or folder of runs, searched below
    for root in map(Path, run_dirs):
        if root.is_dir():
            found.update(root.rglob(CURVES_FILE))
        elif root.name == CURVES_FILE and root.is_file():
            found.add(root)
    records = []
    for path in sorted(found):
        for number, line in enumerate(path.read_text().splitlines(), 1):
            if not line.strip():
                continue
            try:
                record = json.loads(line)
                for key in ("update", "setting", "method", "seed"):
                    record[key]  # noqa: B018 - presence check
            except (json.JSONDecodeError, KeyError, TypeError) as err:
                raise DataError(f"bad curves record on line {number} ({err!r})",
                                file=str(path)) from err
            records.append(record)
    columns = ["setting", "method", "seed", "update", "bc_loss"] + [r[0] for r in CURVE_ROWS]
    frame = pd.DataFrame(records)
    frame = frame.assign(**{c: pd.Series(dtype=float) for c in columns if c not in frame.columns})
    key = ["setting", "method", "seed", "update"]
    # one row per key: the training line (bc_loss) and the validation line (closed-loop
    # metrics) of the same update merge; a value logged twice (a resumed run) keeps the last
    return frame.groupby(key, as_index=False, sort=True).last()


def _reference_levels(references: pd.DataFrame | None) -> dict[str, dict[str, float]]:
    """Mean per reference method of each Fig. 4 row's per_scenario column, in row units."""
    levels: dict[str, dict[str, float]] = {}
    for method in (CONSTANT_VELOCITY, EXPERT):
        part = [] if references is None else references[references.method == method]
        if len(part):
            levels[method] = {key: float(part[column].mean()) * scale
                              for key, _, scale, column in CURVE_ROWS
                              if column is not None and column in part.columns}
    return levels


def _band(part: pd.DataFrame, key: str, scale: float) -> pd.DataFrame:
    """Mean, min and max over seeds of one metric per update (updates where it was logged)."""
    values = part[["update", "seed", key]].dropna()
    values = values.assign(value=values[key].astype(float) * scale)
    return values.groupby("update").value.agg(["mean", "min", "max"]).reset_index()


def _zoom_past_start(ax, first: list[float], later: list[float]) -> None:
    """Scale a learning-curve panel to the trained part when the untrained policy's value
    would flatten it; that value is then written in the panel instead."""
    first = [v for v in first if math.isfinite(v)]
    later = [v for v in later if math.isfinite(v)]
    if not first or not later:
        return
    low, high = min(later), max(later)
    span = max(high - low, 1e-9)
    if max(first) <= high + span:  # the start fits without squashing the rest
        return
    ax.set_ylim(low - 0.1 * span, high + 0.25 * span)
    ax.text(0.97, 0.95, f"update 0: {max(first):.3g} (off scale)", ha="right", va="top",
            transform=ax.transAxes, fontsize=6, color="0.35")


def learning_curves_figure(curves: pd.DataFrame, out_dir: str | Path,
                           references: pd.DataFrame | None = None) -> list[Path]:
    """Fig. 4 from the runs' curves (:func:`load_curves`), the references (per_scenario rows)
    as lines; the paths."""
    if curves.empty:
        return []
    settings = present_settings(curves)
    methods = [m for m in (BC, BC_RL) if m in set(curves.method)] + sorted(
        set(curves.method) - {BC, BC_RL})
    extra = sns.color_palette("tab10")
    colours = {m: METHOD_REGISTRY[m].colour if m in METHOD_REGISTRY else extra[i % 10]
               for i, m in enumerate(methods)}
    levels = _reference_levels(references)
    sns.set_theme(style="whitegrid", context="paper")
    fig, axes = plt.subplots(len(CURVE_ROWS), len(settings), squeeze=False, sharex="col",
                             figsize=(1.2 + 2.3 * len(settings), 1.2 + 1.8 * len(CURVE_ROWS)))
    for col, setting in enumerate(settings):
        axes[0, col].set_title(setting_short(setting))
        axes[-1, col].set_xlabel("training update (count)")
        for row, (key, label, scale, _) in enumerate(CURVE_ROWS):
            ax = axes[row, col]
            first: list[float] = []  # the untrained policy (first evaluated update)
            later: list[float] = []  # everything else drawn in the panel
            for method in methods:
                part = curves[(curves.setting == setting) & (curves.method == method)]
                name = METHOD_LABELS.get(method, method)
                band = _band(part, key, scale)
                if not band.empty:
                    start = band["update"] == band["update"].min()
                    first += band.loc[start, "mean"].tolist()
                    later += band.loc[~start, ["min", "max"]].to_numpy().ravel().tolist()
                    ax.plot(band["update"], band["mean"], color=colours[method], label=name,
                            linewidth=1.4)
                    ax.fill_between(band["update"], band["min"], band["max"],
                                    color=colours[method], alpha=0.2, linewidth=0)
                if key == "val_bc_loss":
                    train = _band(part, "bc_loss", 1.0)
                    if not train.empty:
                        later += train["mean"].tolist()
                        ax.plot(train["update"], train["mean"], color=colours[method],
                                linestyle="--", linewidth=0.9, alpha=0.7,
                                label=f"{name} (training loss)")
            if not ax.lines:  # nothing logged (the references' lines come next)
                ax.text(0.5, 0.5, "not logged", ha="center", va="center",
                        transform=ax.transAxes, color="0.5")
            for method, values in levels.items():
                if key in values and math.isfinite(values[key]):
                    later.append(values[key])
                    ax.axhline(values[key], label=METHOD_LABELS[method],
                               **REFERENCE_STYLE[method])
            _zoom_past_start(ax, first, later)
            if col == 0:
                ax.set_ylabel(label)
    handles = figure_handles(fig)
    fig.legend(list(handles.values()), list(handles), loc="lower center", frameon=False,
               ncols=min(len(handles), 4), bbox_to_anchor=(0.5, 0.0))
    fig.tight_layout(rect=(0, 0.04 + 0.02 * math.ceil(len(handles) / 4), 1, 1))
    return save_figure(fig, out_dir, "fig4_learning_curves")


def supplementary_figure(seed_level: pd.DataFrame, metrics: Sequence):
    """Fig. 5: a panel per registry metric with ``figure=True`` (descriptive: no tests)."""
    panels = [m for m in metrics if m.figure]
    order = present_settings(seed_level)
    learned = [m for m in METHOD_REGISTRY if m in set(seed_level.method)] or [BC, BC_RL]
    sns.set_theme(style="whitegrid", context="paper")
    ncols = 2 if len(panels) > 1 else 1
    nrows = max(1, math.ceil(len(panels) / ncols))
    fig, axes = plt.subplots(nrows, ncols, figsize=(4.0 * ncols, 2.2 * nrows + 0.6),
                             squeeze=False, sharex=True)
    marked = {}
    for ax, metric in zip(axes.ravel(), panels, strict=False):
        marked[metric.key] = _bar_panel(ax, seed_level, metric.key, metric.unit, order,
                                        learned, None)
        arrow = "↑" if metric.higher_is_better else "↓"
        ax.set_title(f"{metric.label} {arrow}", fontsize=9)
        ax.set_ylabel(metric.unit)
    for ax in axes.ravel()[len(panels):]:
        ax.set_visible(False)
    for col in range(ncols):  # setting names under the lowest drawn panel of each column
        drawn = [r for r in range(nrows) if r * ncols + col < len(panels)]
        if drawn:
            _rotate_settings(axes[drawn[-1], col])
    fig.marked = marked
    rows = _legend(fig, False, ncols=4, top=False)
    note = CLIPPED + "; no significance tests on these metrics (descriptive)"
    fig.text(0.01, 0.995, note, fontsize=7, color="0.35", va="top")
    fig.tight_layout(rect=(0, 0.03 * rows + 0.01, 1, 0.985))
    return fig


def _missing_note(frame: pd.DataFrame, methods: Sequence[str], settings: Sequence[str]) -> str:
    """Which methods each setting lacks, and why when known."""
    notes = []
    for setting in settings:
        here = set(frame[frame.setting == setting].method)
        absent = [m for m in methods if m not in here]
        if not absent:
            continue
        names = ", ".join(methods_table.method_label(m) for m in absent)
        why = ("not trained there: their teacher is the Full-setting policy"
               if setting == "full" and all(getattr(METHOD_REGISTRY.get(m), "teacher", False)
                                            for m in absent) else "not evaluated")
        notes.append(f"{setting_short(setting)}: no {names} ({why})")
    return "; ".join(notes)


def fig6_methods(seed_level: pd.DataFrame, tests: pd.DataFrame | None = None):
    """Fig. 6: a panel per Table I metric of :data:`PANELS`, a bar per learned method."""
    methods = methods_table.learned_methods(seed_level)
    learned = seed_level[seed_level.method.isin(methods)]
    settings = present_settings(learned)
    width = max(5.0, 1.2 + 0.3 * len(settings) * max(len(methods), 2))
    fig, rows = _metric_column(seed_level, settings, methods, tests,
                               (width, 2.1 * len(PANELS) + 0.9), 4 if width >= 6.5 else 2)
    note = "; ".join(n for n in (_missing_note(learned, methods, settings), CLIPPED) if n)
    fig.text(0.01, 0.005, note, fontsize=7, color="0.35")
    fig.tight_layout(rect=(0, 0.02, 1, 1 - 0.035 * rows))
    return fig


def redraw_from_tables(paper: str | Path) -> list[Path]:
    """Fig. 3, 5 (and 6) from the tables under ``paper``; the paths."""
    from igdrivsim.evaluation import registry  # the supplementary metrics

    tables, figures = Path(paper) / "tables", Path(paper) / "figures"
    seeds = read_table(tables / "seed_means.csv")
    summary = read_table(tables / "summary.csv")
    main = seeds if seeds is not None else summary
    if main is None:
        raise DataError("no seed_means.csv or summary.csv: run `igdrivsim report` first",
                        file=str(tables))
    written = save_figure(fig3_metrics(main, read_table(tables / "tests.csv")), figures,
                          "fig3_metrics")
    supplementary = read_table(tables / "supplementary_summary.csv")
    if supplementary is not None:
        written += save_figure(supplementary_figure(supplementary, registry.metrics()),
                               figures, "fig5_supplementary")
    tests_all = read_table(tables / "tests_all.csv")
    if tests_all is not None and methods_table.extended_methods(main):
        written += save_figure(fig6_methods(main, tests=tests_all), figures, "fig6_methods")
    return written
