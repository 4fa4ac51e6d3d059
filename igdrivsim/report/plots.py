"""Bar panels shared by Fig. 3, 5 and 6: per setting a group of bars (mean over seeds, 95%
t-interval clipped to the metric's range), asterisks where significant after Holm, the reference
actors as horizontal lines."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd

from igdrivsim.evaluation.aggregate import ALPHA, CONFIDENCE, t_interval
from igdrivsim.names import BC, CONSTANT_VELOCITY, EXPERT, METHOD_LABELS

Cell = tuple[str, str]  # (setting, method)

INF = math.inf
# what each unit can take; other units (e.g. "ratio") are not clipped
FEASIBLE: dict[str, tuple[float, float]] = {
    "%": (0.0, 100.0), "score": (0.0, 1.0), "m": (0.0, INF), "s": (0.0, INF),
    "m/s": (0.0, INF), "m/s²": (0.0, INF), "m/s³": (0.0, INF), "rad/s": (0.0, INF),
}
REFERENCE_STYLE: dict[str, dict] = {  # distinct colour, dash and width, labelled in the legend
    CONSTANT_VELOCITY: dict(color="#b2182b", linestyle="-.", linewidth=1.2),
    EXPERT: dict(color="0.1", linestyle=":", linewidth=1.5),
}
SIGNIFICANT = "*"


def feasible_range(unit: str) -> tuple[float, float]:
    """``(low, high)`` a metric in ``unit`` can take (unbounded for an unknown unit)."""
    return FEASIBLE.get(unit, (-INF, INF))


def clip_interval(low: float, high: float, unit: str) -> tuple[float, float]:
    """A confidence interval clipped to :func:`feasible_range` (NaN bounds stay NaN)."""
    lo, hi = feasible_range(unit)
    return (float(np.clip(low, lo, hi)) if math.isfinite(low) else low,
            float(np.clip(high, lo, hi)) if math.isfinite(high) else high)


def cell_stats(frame: pd.DataFrame, metric: str, unit: str) -> pd.DataFrame:
    """``setting, method, mean, low, high`` of ``metric``, clipped to the unit's range."""
    part = frame[frame.metric == metric]
    rows = []
    if "value" in part.columns:
        for (setting, method), cell in part.groupby(["setting", "method"], sort=False):
            values = cell["value"].dropna().to_numpy(float)
            if values.size:
                rows.append((setting, method, *t_interval(values, CONFIDENCE)))
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
    tops = []
    for cell in marked:
        x, top = positions[cell]
        ax.text(x, top + pad, SIGNIFICANT, ha="center", va="bottom", fontsize=12,
                fontweight="bold", color="0.1")
        tops.append(top + 5 * pad)
    ax.set_ylim(low, max(high, *tops))
    return marked


def reference_lines(ax, frame: pd.DataFrame, metric: str) -> None:
    """A labelled horizontal line at each reference actor's mean of ``metric``."""
    column = "value" if "value" in frame.columns else "mean"
    for method in (CONSTANT_VELOCITY, EXPERT):
        value = frame[(frame.method == method) & (frame.metric == metric)][column].mean()
        if pd.notna(value):
            ax.axhline(float(value), label=METHOD_LABELS[method], zorder=3,
                       **REFERENCE_STYLE[method])


def significance_handle(baseline: str = BC):
    """A legend entry explaining the asterisk."""
    from matplotlib.lines import Line2D  # heavy: only when drawing

    return Line2D([], [], linestyle="", marker="$*$", markersize=7, color="0.1",
                  label=f"significant vs {METHOD_LABELS.get(baseline, baseline)} "
                        f"(Holm, α={ALPHA})")


def figure_handles(fig) -> dict[str, object]:
    """Each distinct legend entry of the figure's axes, first occurrence first."""
    handles: dict[str, object] = {}
    for ax in fig.axes:
        for handle, name in zip(*ax.get_legend_handles_labels(), strict=True):
            handles.setdefault(name, handle)
    return handles
