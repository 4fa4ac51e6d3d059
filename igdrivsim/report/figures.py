"""Fig. 3 (per-step metrics of BC versus BC-RL) and Fig. 4 (learning curves).

Fig. 3: three panels (log divergence, overlap %, offroad %), one group of bars per setting, BC
in blue and BC-RL in orange as in the paper; bars are the mean over seeds and error bars the 95%
t-interval over the seed means (the same numbers as Table I).

Fig. 4: what each training run logged in its ``curves.jsonl`` (teacher-forced validation BC
loss, closed-loop validation metrics every K updates) against the update, one column per
setting, so a reader sees whether training converged; constant velocity and the expert replay
are drawn as horizontal references when their evaluation is available.

Fig. 6 (only with methods beyond BC and BC-RL): Fig. 3's panels with one bar per learned
method in its registry colour, the constant-velocity and expert levels as dashed lines.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # figures are files; never open a window

import matplotlib.pyplot as plt  # noqa: E402
import pandas as pd  # noqa: E402
import seaborn as sns  # noqa: E402

from igdrivsim.errors import DataError  # noqa: E402
from igdrivsim.evaluation.aggregate import CONFIDENCE, t_interval  # noqa: E402
from igdrivsim.evaluation.schema import (  # noqa: E402
    BC,
    BC_RL,
    CONSTANT_VELOCITY,
    EXPERT,
    METHOD_LABELS,
    METRIC_BY_KEY,
    setting_short,
    table_settings,
)
from igdrivsim.io import atomic_savefig  # noqa: E402
from igdrivsim.report.methods_table import (  # noqa: E402
    learned_methods,
    method_colours,
    method_label,
)
from igdrivsim.training.methods import METHODS as METHOD_REGISTRY  # noqa: E402

PALETTE = {m.label: m.colour for m in METHOD_REGISTRY.values()}  # BC blue, BC-RL orange
PANELS = ("log_divergence", "overlap", "offroad")


def _t_errorbar(values) -> tuple[float, float]:
    """seaborn error-bar callable: the t-interval over seed means (no bar for one seed)."""
    mean, low, high = t_interval(values.to_numpy(), CONFIDENCE)
    return (low, high) if pd.notna(low) else (mean, mean)


def fig3_metrics(seed_level: pd.DataFrame):
    """Build the figure from the long ``setting, method, seed, metric, value`` frame
    (:func:`igdrivsim.evaluation.aggregate.seed_means`)."""
    settings = table_settings(seed_level)
    data = seed_level[seed_level.method.isin((BC, BC_RL)) & seed_level.metric.isin(PANELS)
                      & seed_level.setting.isin(settings)].copy()
    data["Method"] = data.method.map(METHOD_LABELS)
    data["Setting"] = data.setting.map(setting_short)
    order = [setting_short(s) for s in settings if s in set(data.setting)]
    hue_order = [METHOD_LABELS[m] for m in (BC, BC_RL)]
    sns.set_theme(style="whitegrid", context="paper")
    fig, axes = plt.subplots(len(PANELS), 1, figsize=(4.2, 6.4), sharex=True)
    for ax, key in zip(axes, PANELS, strict=True):
        metric = METRIC_BY_KEY[key]
        panel = data[data.metric == key]
        if panel.empty:
            ax.text(0.5, 0.5, "not evaluated", ha="center", va="center", transform=ax.transAxes)
        else:
            sns.barplot(data=panel, x="Setting", y="value", hue="Method", order=order,
                        hue_order=hue_order, palette=PALETTE, errorbar=_t_errorbar,
                        capsize=0.15, err_kws={"linewidth": 1.0}, ax=ax)
        name = " ".join(metric.label).replace("\\", "").replace(" (%)", "")
        ax.set_ylabel(f"{name} ({metric.unit})")
        ax.set_xlabel("")
        legend = ax.get_legend()
        if legend is not None and ax is not axes[0]:
            legend.remove()
    if axes[0].get_legend() is not None:
        axes[0].legend(title=None, frameon=False, ncols=2, loc="lower center",
                       bbox_to_anchor=(0.5, 1.0))
    axes[-1].tick_params(axis="x", rotation=30)
    for label in axes[-1].get_xticklabels():
        label.set_horizontalalignment("right")
    fig.tight_layout()
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
    ("val_bc_loss", "validation BC loss", 1.0, None),
    ("log_divergence", "log divergence (m)", 1.0, "log_divergence"),
    ("offroad", "offroad (% steps)", 100.0, "offroad_steps"),
    ("overlap", "overlap (% steps)", 100.0, "overlap_steps"),
)
CURVES_FILE = "curves.jsonl"
_REFERENCE_STYLE = {CONSTANT_VELOCITY: dict(color="0.45", linestyle="-.", linewidth=1.0),
                    EXPERT: dict(color="0.1", linestyle=":", linewidth=1.2)}


def find_curves(run_dirs: Iterable[str | Path]) -> list[Path]:
    """Every ``curves.jsonl`` in or below the given folders (a run folder or a folder of runs)."""
    found: set[Path] = set()
    for root in map(Path, run_dirs):
        if root.is_file() and root.name == CURVES_FILE:
            found.add(root)
        elif root.is_dir():
            found.update(root.rglob(CURVES_FILE))
    return sorted(found)


def load_curves(run_dirs: Iterable[str | Path]) -> pd.DataFrame:
    """All ``curves.jsonl`` records as one frame (one row per logged line; missing keys NaN).

    A repeated ``(setting, method, seed, update)`` (a resumed run) keeps its last record; a
    malformed line raises :class:`DataError` naming the file.
    """
    records = []
    for path in find_curves(run_dirs):
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
    for column in columns:
        if column not in frame.columns:
            frame[column] = pd.Series(dtype=float)
    key = ["setting", "method", "seed", "update"]
    # one row per key: the training line (bc_loss) and the validation line (closed-loop
    # metrics) of the same update merge; a value logged twice (a resumed run) keeps the last
    return frame.groupby(key, as_index=False, sort=True).last()


def _reference_levels(references: str | Path | pd.DataFrame | None) -> dict[str, dict[str, float]]:
    """Mean per reference method of each Fig. 4 row's per_scenario column, in row units."""
    if references is None:
        return {}
    if not isinstance(references, pd.DataFrame):
        if not Path(references).is_file():
            return {}
        references = pd.read_csv(references, dtype={"method": str})
    levels: dict[str, dict[str, float]] = {}
    for method in (CONSTANT_VELOCITY, EXPERT):
        part = references[references.method == method] if "method" in references else []
        if len(part) == 0:
            continue
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


def learning_curves_figure(run_dirs: Sequence[str | Path], out_dir: str | Path,
                           references_csv: str | Path | pd.DataFrame | None = None,
                           stem: str = "fig4_learning_curves") -> list[Path]:
    """Write ``stem.{pdf,png}`` under ``out_dir`` from the runs' ``curves.jsonl``.

    Rows: validation BC loss (training BC loss dashed), log divergence, offroad % and overlap %;
    columns: settings; one line per method, the mean over seeds with the min-max band shaded;
    constant velocity and the expert as horizontal lines when ``references_csv`` (a
    per_scenario.csv path or frame) has them. Returns the written paths ([] without curves).
    """
    curves = load_curves(run_dirs)
    if curves.empty:
        return []
    present = list(dict.fromkeys(curves.setting.astype(str)))
    settings = [s for s in table_settings(curves) if s in present]
    methods = [m for m in (BC, BC_RL) if m in set(curves.method)] + sorted(
        set(curves.method) - {BC, BC_RL})
    extra = sns.color_palette("tab10")
    colours = {m: METHOD_REGISTRY[m].colour if m in METHOD_REGISTRY else extra[i % 10]
               for i, m in enumerate(methods)}
    levels = _reference_levels(references_csv)
    sns.set_theme(style="whitegrid", context="paper")
    fig, axes = plt.subplots(len(CURVE_ROWS), len(settings), squeeze=False, sharex="col",
                             figsize=(1.2 + 2.3 * len(settings), 1.2 + 1.8 * len(CURVE_ROWS)))
    for col, setting in enumerate(settings):
        axes[0, col].set_title(setting_short(setting))
        axes[-1, col].set_xlabel("update")
        for row, (key, label, scale, _) in enumerate(CURVE_ROWS):
            ax = axes[row, col]
            drawn = False
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
                    drawn = True
                if key == "val_bc_loss":
                    train = _band(part, "bc_loss", 1.0)
                    if not train.empty:
                        later += train["mean"].tolist()
                        ax.plot(train["update"], train["mean"], color=colours[method],
                                linestyle="--", linewidth=0.9, alpha=0.7,
                                label=f"{name} (training loss)")
                        drawn = True
            for method, values in levels.items():
                if key in values and math.isfinite(values[key]):
                    later.append(values[key])
                    ax.axhline(values[key], label=METHOD_LABELS[method],
                               **_REFERENCE_STYLE[method])
            _zoom_past_start(ax, first, later)
            if not drawn:
                ax.text(0.5, 0.5, "not logged", ha="center", va="center",
                        transform=ax.transAxes, color="0.5")
            if col == 0:
                ax.set_ylabel(label)
    handles: dict[str, object] = {}
    for ax in axes.ravel():
        for handle, name in zip(*ax.get_legend_handles_labels(), strict=True):
            handles.setdefault(name, handle)
    fig.legend(list(handles.values()), list(handles), loc="lower center", frameon=False,
               ncols=min(len(handles), 4), bbox_to_anchor=(0.5, 0.0))
    fig.tight_layout(rect=(0, 0.04 + 0.02 * math.ceil(len(handles) / 4), 1, 1))
    return save_figure(fig, out_dir, stem)


def supplementary_figure(seed_level: pd.DataFrame, metrics: Sequence):
    """Fig. 5: one panel per registry metric with ``figure=True`` (``metrics``), bars per
    setting for every learned method present (mean over seeds, 95% t-interval), the expert
    and constant velocity as horizontal lines when evaluated. ``seed_level``:
    :func:`seed_means` over the registry's metrics."""
    panels = [m for m in metrics if m.figure]
    order = list(table_settings(seed_level))
    learned = [m for m in METHOD_REGISTRY if m in set(seed_level.method)] or [BC, BC_RL]
    data = seed_level[seed_level.method.isin(learned) & seed_level.setting.isin(order)]
    data = data.assign(Method=data.method.map(METHOD_LABELS), Setting=data.setting)
    refs = seed_level[seed_level.method.isin((EXPERT, CONSTANT_VELOCITY))]
    sns.set_theme(style="whitegrid", context="paper")
    ncols = 2 if len(panels) > 1 else 1
    nrows = max(1, math.ceil(len(panels) / ncols))
    fig, axes = plt.subplots(nrows, ncols, figsize=(4.0 * ncols, 2.2 * nrows + 0.4),
                             squeeze=False, sharex=True)
    hue_order = [METHOD_LABELS[m] for m in learned]
    for ax, metric in zip(axes.ravel(), panels, strict=False):
        panel = data[data.metric == metric.key]
        if panel.empty or panel.value.isna().all():
            ax.text(0.5, 0.5, "not evaluated", ha="center", va="center", transform=ax.transAxes)
        else:
            sns.barplot(data=panel, x="Setting", y="value", hue="Method", order=order,
                        hue_order=hue_order, palette=PALETTE, errorbar=_t_errorbar,
                        capsize=0.15, err_kws={"linewidth": 1.0}, ax=ax)
        for method in (EXPERT, CONSTANT_VELOCITY):
            level = refs[(refs.method == method) & (refs.metric == metric.key)].value.mean()
            if pd.notna(level):
                ax.axhline(level, label=METHOD_LABELS[method], **_REFERENCE_STYLE[method])
        arrow = "↑" if metric.higher_is_better else "↓"
        ax.set_title(f"{metric.label} {arrow}", fontsize=9)
        ax.set_ylabel(metric.unit)
        ax.set_xlabel("")
        ax.set_xticks(range(len(order)), [setting_short(s) for s in order], rotation=30,
                      ha="right")
        if ax.get_legend() is not None:
            ax.get_legend().remove()
    for ax in axes.ravel()[len(panels):]:
        ax.set_visible(False)
    for col in range(ncols):  # setting names under the lowest drawn panel of each column
        drawn = [r for r in range(nrows) if r * ncols + col < len(panels)]
        if drawn:
            axes[drawn[-1], col].tick_params(axis="x", labelbottom=True)
    handles: dict[str, object] = {}
    for ax in axes.ravel():
        for handle, name in zip(*ax.get_legend_handles_labels(), strict=True):
            handles.setdefault(name, handle)
    if handles:
        fig.legend(list(handles.values()), list(handles), loc="lower center", frameon=False,
                   ncols=min(len(handles), 4), bbox_to_anchor=(0.5, 0.0))
    fig.tight_layout(rect=(0, 0.06 if handles else 0, 1, 1))
    return fig


_FIG6_REFERENCES = {CONSTANT_VELOCITY: "0.45", EXPERT: "0.1"}


def fig6_methods(seed_level: pd.DataFrame, panels: Sequence[str] = PANELS):
    """Fig. 6: one panel per metric key in ``panels``, settings on the x axis, a bar per
    learned method (mean over seeds, 95% t-interval over seed means), constant velocity and
    the expert as dashed horizontal lines when evaluated. ``seed_level``: :func:`seed_means`."""
    methods = learned_methods(seed_level)
    learned = seed_level[seed_level.method.isin(methods)]
    present = set(learned.setting.astype(str))
    settings = [s for s in table_settings(learned) if s in present]
    data = learned[learned.metric.isin(panels) & learned.setting.isin(settings)].copy()
    data["Method"] = data.method.map(method_label)
    data["Setting"] = data.setting.map(setting_short)
    order = [setting_short(s) for s in settings]
    hue_order = [method_label(m) for m in methods]
    palette = {method_label(m): c for m, c in method_colours(methods).items()}
    refs = seed_level[seed_level.method.isin(_FIG6_REFERENCES)]
    sns.set_theme(style="whitegrid", context="paper")
    width = max(5.0, 1.2 + 0.3 * len(settings) * max(len(methods), 2))
    fig, axes = plt.subplots(len(panels), 1, figsize=(width, 2.1 * len(panels) + 0.6),
                             sharex=True, squeeze=False)
    for ax, key in zip(axes[:, 0], panels, strict=True):
        metric = METRIC_BY_KEY[key]
        panel = data[data.metric == key]
        if panel.empty or panel.value.isna().all():
            ax.text(0.5, 0.5, "not evaluated", ha="center", va="center", transform=ax.transAxes)
        else:
            sns.barplot(data=panel, x="Setting", y="value", hue="Method", order=order,
                        hue_order=hue_order, palette=palette, errorbar=_t_errorbar,
                        capsize=0.15, err_kws={"linewidth": 1.0}, ax=ax)
        for method, colour in _FIG6_REFERENCES.items():
            level = refs[(refs.method == method) & (refs.metric == key)].value.mean()
            if pd.notna(level):
                ax.axhline(level, color=colour, linestyle="--", linewidth=1.0,
                           label=method_label(method))
        ax.set_ylabel(f"{' '.join(metric.label).replace(chr(92), '').replace(' (%)', '')} "
                      f"({metric.unit})")
        ax.set_xlabel("")
        if ax.get_legend() is not None:
            ax.get_legend().remove()
    axes[-1, 0].tick_params(axis="x", rotation=30)
    for label in axes[-1, 0].get_xticklabels():
        label.set_horizontalalignment("right")
    handles: dict[str, object] = {}
    for ax in axes.ravel():
        for handle, name in zip(*ax.get_legend_handles_labels(), strict=True):
            handles.setdefault(name, handle)
    ncols = 3 if width >= 6.5 else 2
    if handles:
        fig.legend(list(handles.values()), list(handles), loc="upper center", frameon=False,
                   ncols=min(len(handles), ncols), bbox_to_anchor=(0.5, 1.0))
    rows = math.ceil(len(handles) / ncols)
    fig.tight_layout(rect=(0, 0, 1, 1 - (0.035 * rows if handles else 0)))
    return fig
