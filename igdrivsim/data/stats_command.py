"""``igdrivsim stats``: scene statistics of any data (synthetic, tf.Example, Scenario, ScenarioNet).

Prints the median [p10, p90] table per data set, writes ``OUT/stats.csv`` (one row per
scenario), ``OUT/divergence.csv`` (Jensen-Shannon divergence of each data set's pooled
speed / acceleration / nearest-object / road-edge histograms from the reference data set) and
``OUT/stats.png`` (one panel per statistic, one distribution per data set).
"""

from __future__ import annotations

import argparse
import os
from collections import defaultdict
from itertools import islice

import numpy as np
from tqdm.auto import tqdm

from igdrivsim.data.reader import iter_scenarios
from igdrivsim.data.stats import FEATURES, STATISTICS, js_divergence, scene_statistics, summary
from igdrivsim.errors import ConfigError, check_min
from igdrivsim.io import atomic_savefig, atomic_write_csv, atomic_write_text, require_folder


def parse_datasets(specs: list[str]) -> dict[str, list[str]]:
    """``NAME=PATH`` or ``PATH`` (named by its file or folder name) -> ``{name: [paths]}``;
    repeated names gather their paths into one data set."""
    out: dict[str, list[str]] = defaultdict(list)
    for spec in specs:
        name, sep, path = spec.partition("=")
        if not sep or os.path.exists(spec):
            name, path = os.path.basename(os.path.normpath(spec)) or spec, spec
        if not name or not path:
            raise ConfigError(f"bad data set {spec!r}: expected NAME=PATH or PATH")
        out[name].append(path)
    return dict(out)


def stats_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("files", nargs="+", metavar="[NAME=]FILE",
                        help="TFRecord files, folders, globs or name@N (either WOMD format), "
                             "ScenarioNet .pkl files / folders; NAME= groups files into one "
                             "data set (default name: the file or folder name)")
    parser.add_argument("--out", default=None, help="write stats.csv, divergence.csv, stats.png")
    parser.add_argument("--limit", type=int, default=None,
                        help="read at most N scenarios per data set")
    parser.add_argument("--kept-only", action="append", default=[], metavar="NAME",
                        help="summarise only the scenarios of data set NAME that the paper's "
                             "filter keeps (repeatable; the CSV has every scenario)")
    parser.add_argument("--reference", default=None, metavar="NAME",
                        help="data set the divergences are taken from (default: the last one)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def collect(datasets: dict[str, list[str]], limit: int | None = None, progress: bool = True):
    """Rows (one per scenario, with ``dataset, file, record``) and pooled histograms per set."""
    rows, hists = [], {}
    for name, paths in datasets.items():
        pooled = {k: np.zeros(len(e) - 1, np.int64) for k, e in FEATURES.items()}
        records = islice(iter_scenarios(paths, caps=None), limit)  # native sizes: nothing is cut
        for rec in tqdm(records, desc=name, unit="scn", disable=not progress, total=limit):
            row, h = scene_statistics(rec.scenario)
            rows.append({"dataset": name, "file": rec.file, "record": rec.record, **row})
            for k in pooled:
                pooled[k] += h[k]
        hists[name] = pooled
    return rows, hists


def summary_table(frame, kept_only=()) -> str:
    """The median [p10, p90] table (Markdown), one column per data set."""
    names = list(dict.fromkeys(frame["dataset"]))
    cells = {}
    for name in names:
        sub = frame[frame["dataset"] == name]
        if name in kept_only:
            sub = sub[sub["kept"]]
        cells[name] = (len(sub), {s.key: summary(sub[s.key]) for s in STATISTICS})
    head = [f"{n} ({cells[n][0]}{' kept' if n in kept_only else ''})" for n in names]
    lines = ["| statistic | " + " | ".join(head) + " |", "|---" * (len(names) + 1) + "|"]
    for s in STATISTICS:
        label = f"{s.label} ({s.unit})" if s.unit else s.label
        vals = []
        for n in names:
            med, p10, p90 = cells[n][1][s.key]
            fmt = ".2f" if abs(med) < 10 else ".1f" if abs(med) < 100 else ".0f"
            vals.append("-" if np.isnan(med) else
                        f"{med:{fmt}} [{p10:{fmt}}, {p90:{fmt}}]")
        lines.append(f"| {label} | " + " | ".join(vals) + " |")
    return "\n".join(lines)


def divergences(hists: dict[str, dict[str, np.ndarray]], reference: str):
    """Jensen-Shannon divergence of each data set's pooled feature histograms from ``reference``."""
    import pandas as pd  # heavy: pandas is needed only here

    rows = [{"dataset": name, "reference": reference,
             **{k: round(js_divergence(h[k], hists[reference][k]), 4) for k in FEATURES}}
            for name, h in hists.items() if name != reference]
    return pd.DataFrame(rows, columns=["dataset", "reference", *FEATURES])


def plot(frame, path: str, kept_only=()) -> None:
    """One panel per statistic, one box-and-points distribution per data set."""
    import matplotlib  # heavy: only when drawing

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # heavy: only when drawing
    import seaborn as sns  # heavy: only when drawing

    keep = ~frame["dataset"].isin(list(kept_only)) | frame["kept"]
    frame = frame[keep]
    cols = 4
    rows = -(-len(STATISTICS) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 2.4 * rows))
    for ax, s in zip(axes.ravel(), STATISTICS, strict=False):
        sns.boxplot(frame, x=s.key, y="dataset", hue="dataset", ax=ax, showfliers=False,
                    legend=False, width=0.5, boxprops={"alpha": 0.4})
        sns.stripplot(frame, x=s.key, y="dataset", hue="dataset", ax=ax, size=2.5, alpha=0.6,
                      legend=False, jitter=0.2)
        ax.set_title(s.label, fontsize=9)
        ax.set_xlabel(s.unit)
        ax.set_ylabel("")
    for ax in axes.ravel()[len(STATISTICS):]:
        ax.axis("off")
    fig.tight_layout()
    atomic_savefig(fig, path, dpi=110)
    plt.close(fig)


def stats_command(args: argparse.Namespace) -> int:
    """Compute, print and (with ``--out``) write the statistics of the given data sets."""
    import pandas as pd  # heavy: pandas is needed only here

    check_min("--limit", args.limit, 1)
    datasets = parse_datasets(args.files)
    for name in [*args.kept_only, *([args.reference] if args.reference else [])]:
        if name not in datasets:
            raise ConfigError(f"no data set named {name!r}; data sets: {', '.join(datasets)}")
    if args.out is not None:
        require_folder(args.out)
    rows, hists = collect(datasets, args.limit, not args.no_progress)
    frame = pd.DataFrame(rows)
    table = summary_table(frame, args.kept_only)
    print(table)
    reference = args.reference or list(datasets)[-1]
    div = divergences(hists, reference)
    if len(div):
        print(f"\nJensen-Shannon divergence (base 2) from {reference}:")
        print(div.drop(columns="reference").to_string(index=False))
    if args.out is not None:
        os.makedirs(args.out, exist_ok=True)
        atomic_write_csv(os.path.join(args.out, "stats.csv"), frame)
        atomic_write_csv(os.path.join(args.out, "divergence.csv"), div)
        atomic_write_text(os.path.join(args.out, "stats.md"), table + "\n")
        plot(frame, os.path.join(args.out, "stats.png"), args.kept_only)
    return 0
