"""Fig. 3: per-step metrics of BC versus BC-RL for each observation setting.

Three panels (log divergence, overlap %, offroad %), one group of bars per setting, BC in blue
and BC-RL in orange as in the paper; bars are the mean over seeds and error bars the 95%
t-interval over the seed means (the same numbers as Table I).
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # figures are files; never open a window

import matplotlib.pyplot as plt  # noqa: E402
import pandas as pd  # noqa: E402
import seaborn as sns  # noqa: E402

from igdrivsim.evaluation.aggregate import CONFIDENCE, t_interval  # noqa: E402
from igdrivsim.evaluation.schema import (  # noqa: E402
    BC,
    BC_RL,
    METHOD_LABELS,
    METRIC_BY_KEY,
    SETTING_SHORT,
    SETTINGS,
)
from igdrivsim.io import atomic_savefig  # noqa: E402

PALETTE = {METHOD_LABELS[BC]: "#4C9BE8", METHOD_LABELS[BC_RL]: "#F28E2B"}  # blue / orange
PANELS = ("log_divergence", "overlap", "offroad")


def _t_errorbar(values) -> tuple[float, float]:
    """seaborn error-bar callable: the t-interval over seed means (no bar for one seed)."""
    mean, low, high = t_interval(values.to_numpy(), CONFIDENCE)
    return (low, high) if pd.notna(low) else (mean, mean)


def fig3_metrics(seed_level: pd.DataFrame):
    """Build the figure from the long ``setting, method, seed, metric, value`` frame
    (:func:`igdrivsim.evaluation.aggregate.seed_means`)."""
    data = seed_level[seed_level.method.isin((BC, BC_RL)) & seed_level.metric.isin(PANELS)
                      & seed_level.setting.isin(SETTINGS)].copy()
    data["Method"] = data.method.map(METHOD_LABELS)
    data["Setting"] = data.setting.map(SETTING_SHORT)
    order = [SETTING_SHORT[s] for s in SETTINGS if s in set(data.setting)]
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
