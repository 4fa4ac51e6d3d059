"""``igdrivsim stats``: scene and motion statistics of any data set, beside each other: the
median [p10, p90] tables and, with ``--out``, :data:`OUTPUTS` (``stats.csv``, ``motion_agents.csv``:
a row per scenario / agent; ``divergence.csv``, ``motion_stats.csv``: Jensen-Shannon divergences
from the reference data set, the motion ones with their sampling floor; ``road_edge.csv``: the
road-edge distances per object class; ``stats.md``: the tables; the figures)."""

from __future__ import annotations

import argparse
import os
from collections import defaultdict
from collections.abc import Sequence
from itertools import islice

import numpy as np
from tqdm.auto import tqdm

from igdrivsim.data.egos import add_egos_argument
from igdrivsim.data.motion_stats import (
    FLOOR_DRAWS,
    GROUP_LABELS,
    GROUPS,
    MOTION_STATISTICS,
    MotionPool,
    motion_statistics,
    motion_summary,
    plot_motion,
)
from igdrivsim.data.source import open_scenarios
from igdrivsim.data.stats import (
    EDGE_CLASSES,
    FEATURES,
    STATISTICS,
    js_divergence,
    scene_statistics,
    summary,
)
from igdrivsim.errors import ConfigError, DataError, check_min
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


OUTPUTS = ("stats.csv", "divergence.csv", "road_edge.csv", "stats.md", "stats.png",
           "motion_stats.csv", "motion_agents.csv", "motion_stats.png")


def stats_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("files", nargs="+", metavar="[NAME=]FILE",
                        help="TFRecord files, folders, globs or name@N (either WOMD format), "
                             "ScenarioNet .pkl files / folders, GPUDrive .json files / "
                             "folders, `igdrivsim filter` output "
                             "folders (their kept scenarios); NAME= groups files into one "
                             "data set (default name: the file or folder name)")
    parser.add_argument("--out", default=None,
                        help="write " + ", ".join(OUTPUTS) + " into this folder")
    parser.add_argument("--limit", type=int, default=None,
                        help="read at most N scenarios per data set")
    parser.add_argument("--kept-only", action="append", default=[], metavar="NAME",
                        help="summarise only the scenarios of data set NAME that the paper's "
                             "filter keeps, in the tables and the motion statistics "
                             "(repeatable; the CSVs have every scenario)")
    parser.add_argument("--reference", default=None, metavar="NAME",
                        help="data set the divergences are taken from (default: the last one)")
    add_egos_argument(parser)
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def collect(datasets: dict[str, list[str]], limit: int | None = None, progress: bool = True,
            kept_only: Sequence[str] = (), egos: str = "sdc"):
    """Scene rows (one per scenario, with ``dataset, file, record``), pooled scene histograms
    per set, pooled motion statistics per set (only the filter-kept scenarios of the sets in
    ``kept_only``) and motion rows (one per agent)."""
    rows, hists, pools, agents = [], {}, {}, []
    for name, paths in datasets.items():
        pooled: dict[str, np.ndarray] = defaultdict(lambda: 0)
        pools[name] = MotionPool()
        records = islice(open_scenarios(paths, caps=None, egos=egos), limit)
        count = 0
        for rec in tqdm(records, desc=name, unit="scn", disable=not progress, total=limit):
            count, scenario = count + 1, rec.scenario
            row, h = scene_statistics(scenario)
            where = {"dataset": name, "file": rec.file, "record": rec.record}
            rows.append({**where, **row})
            for k, v in h.items():
                pooled[k] = pooled[k] + v
            motion = motion_statistics(scenario)
            if row["kept"] or name not in kept_only:
                pools[name].add(motion)
            agents += [{**where, "scenario_id": row["scenario_id"], "kept": row["kept"], **a}
                       for a in motion.agents]
        if not count:
            raise DataError(f"no scenarios in data set {name!r}", file=", ".join(paths))
        hists[name] = dict(pooled)
    return rows, hists, pools, agents


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
        vals = []
        for n in names:
            med, p10, p90 = cells[n][1][s.key]
            fmt = ".2f" if abs(med) < 10 else ".1f" if abs(med) < 100 else ".0f"
            vals.append("-" if np.isnan(med) else f"{med:{fmt}} [{p10:{fmt}}, {p90:{fmt}}]")
        lines.append(f"| {s.title} | " + " | ".join(vals) + " |")
    return "\n".join(lines)


def _cell(med: float, p10: float, p90: float) -> str:
    """``median [p10, p90]`` with decimals for the largest of the three."""
    if np.isnan(med):
        return "-"
    scale = max(abs(med), abs(p10), abs(p90))
    fmt = ".3f" if scale < 0.5 else ".2f" if scale < 10 else ".1f" if scale < 100 else ".0f"
    return f"{med:{fmt}} [{p10:{fmt}}, {p90:{fmt}}]"


def motion_tables(summary_frame, kept_only: Sequence[str] = ()) -> str:
    """The motion tables (Markdown), one per group: median [p10, p90] (counts: mean) per data
    set, then the Jensen-Shannon divergence of each other data set from the reference."""
    names = list(dict.fromkeys(summary_frame["dataset"]))
    reference = summary_frame["reference"].iloc[0]
    others = [n for n in names if n != reference]
    parts = []
    for g in GROUPS:
        sub = summary_frame[summary_frame["group"] == g].set_index(["dataset", "statistic"])
        head = [f"{n} ({sub.loc[(n, MOTION_STATISTICS[0].key), 'agents']}"
                f"{' in kept scenarios' if n in kept_only else ''})" for n in names]
        head += [f"JS {n}" for n in others]
        lines = [f"{GROUP_LABELS[g]} (n = agents; CV: constant velocity from t = 1.0 s; "
                 f"JS: Jensen-Shannon divergence from {reference}, base 2)", "",
                 "| statistic | " + " | ".join(head) + " |", "|---" * (len(head) + 1) + "|"]
        for s in MOTION_STATISTICS:
            cells = []
            for n in names:
                r = sub.loc[(n, s.key)]
                cells.append(("-" if np.isnan(r["mean"]) else f"{r['mean']:.2f}") if s.count
                             else _cell(r["median"], r["p10"], r["p90"]))
            cells += ["-" if np.isnan(sub.loc[(n, s.key), "js"]) else
                      f"{sub.loc[(n, s.key), 'js']:.3f}" for n in others]
            lines.append(f"| {s.title} | " + " | ".join(cells) + " |")
        parts.append("\n".join(lines))
        floored = [n for n in others if sub.loc[n, "js_floor_median"].notna().any()]
        if floored:
            parts.append(_floor_table(sub, g, floored))
    return "\n\n".join(parts)


def _floor_table(sub, group: str, names: list[str]) -> str:
    """Each divergence beside its sampling floor (:func:`motion_stats.js_floor`)."""
    head = [f"{x} {n}" for n in names for x in ("JS", "floor")]
    lines = [f"{GROUP_LABELS[group]}: sampling floor of JS, median [p10, p90] over "
             f"{FLOOR_DRAWS} random subsets (as many scenarios as the smaller set has, drawn "
             "from the larger one, against its other scenarios); a JS inside it cannot tell the "
             "two sets apart", "",
             "| statistic | " + " | ".join(head) + " |", "|---" * (len(head) + 1) + "|"]
    for s in MOTION_STATISTICS:
        cells = []
        for n in names:
            r = sub.loc[(n, s.key)]
            cells += ["-" if np.isnan(r["js"]) else f"{r['js']:.3f}",
                      "-" if np.isnan(r["js_floor_median"]) else
                      f"{r['js_floor_median']:.3f} [{r['js_floor_p10']:.3f}, "
                      f"{r['js_floor_p90']:.3f}]"]
        lines.append(f"| {s.title} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def divergences(hists: dict[str, dict[str, np.ndarray]], reference: str):
    """Jensen-Shannon divergence of each data set's pooled feature histograms from ``reference``."""
    import pandas as pd  # heavy: pandas is needed only here

    rows = [{"dataset": name, "reference": reference,
             **{k: round(js_divergence(h[k], hists[reference][k]), 4) for k in FEATURES}}
            for name, h in hists.items() if name != reference]
    return pd.DataFrame(rows, columns=["dataset", "reference", *FEATURES])


def road_edge_classes(hists: dict[str, dict[str, np.ndarray]]):
    """Tidy rows per data set, object class and road-edge bin: object-steps and their share of
    the data set's (signed distance to the nearest road-edge point; < 0: on the road side)."""
    import pandas as pd  # heavy: pandas is needed only here

    edges = FEATURES["road_edge_distance"]
    rows = [{"dataset": name, "class": c, "lo": lo, "hi": hi, "steps": int(n),
             "share": round(n / max(h["road_edge_distance"].sum(), 1), 4)}
            for name, h in hists.items() for c in EDGE_CLASSES
            for lo, hi, n in zip(edges[:-1], edges[1:], h[f"road_edge:{c}"], strict=True)]
    return pd.DataFrame(rows)


def road_edge_table(frame, top: int = 3) -> str:
    """Markdown: per data set, its ``top`` most populated road-edge bins and the outermost one
    (everything beyond the range), each with its share of object-steps split by class."""
    lines = [f"Road-edge distance by object class (share of object-steps; the {top} most "
             "populated 0.5-m bins and the outermost, which holds everything beyond it; < 0: on "
             "the road side)", "",
             "| data set | bin (m) | share | " + " | ".join(EDGE_CLASSES) + " |",
             "|---" * (len(EDGE_CLASSES) + 3) + "|"]
    for name, sub in frame.groupby("dataset", sort=False):
        bins = sub.pivot_table(index=["lo", "hi"], columns="class", values="share",
                               aggfunc="sum")[list(EDGE_CLASSES)]
        total = bins.sum(axis=1)
        shown = list(dict.fromkeys([*total.nlargest(top).index, total.index[-1]]))
        for lo, hi in shown:
            label = f">= {lo:g}" if (lo, hi) == total.index[-1] else f"{lo:g} to {hi:g}"
            lines.append(f"| {name} | {label} | {total[lo, hi]:.2f} | " + " | ".join(
                f"{bins.loc[(lo, hi), c]:.2f}" for c in EDGE_CLASSES) + " |")
    return "\n".join(lines)


def plot(frame, path: str, kept_only=(), min_box: int = 10) -> None:
    """One panel per statistic, one distribution per data set, its scenario count ``n`` in its
    label: the points over a box from ``min_box`` scenarios on, the points and their median
    (black tick) below, where a box would pretend to a distribution."""
    import matplotlib  # heavy: only when drawing

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # heavy: only when drawing
    import seaborn as sns  # heavy: only when drawing

    frame = frame[~frame["dataset"].isin(list(kept_only)) | frame["kept"]]
    counts = frame["dataset"].value_counts()
    labels = {n: f"{n} (n={counts[n]})" for n in dict.fromkeys(frame["dataset"])}
    frame = frame.assign(dataset=frame["dataset"].map(labels))
    order = list(labels.values())
    palette = dict(zip(order, sns.color_palette(n_colors=len(order)), strict=True))
    boxed = [labels[n] for n in labels if counts[n] >= min_box]
    cols = 4
    rows = -(-len(STATISTICS) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 2.4 * rows))
    jitter = np.random.default_rng(0)  # the same figure from the same data
    for ax, s in zip(axes.ravel(), STATISTICS, strict=False):
        if boxed:
            sns.boxplot(frame[frame["dataset"].isin(boxed)], x=s.key, y="dataset", order=order,
                        hue="dataset", palette=palette, ax=ax, showfliers=False, legend=False,
                        width=0.5, boxprops={"alpha": 0.4})
        for row, name in enumerate(order):  # the points, jittered by a seeded generator
            values = frame.loc[frame["dataset"] == name, s.key].dropna()
            ax.scatter(values, row + jitter.uniform(-0.2, 0.2, len(values)), s=9, alpha=0.7,
                       color=palette[name], linewidths=0)
            if name not in boxed and len(values):
                ax.plot(values.median(), row, marker="|", ms=14, mew=1.5, color="black")
        ax.set_yticks(range(len(order)), order)
        ax.set_ylim(len(order) - 0.5, -0.5)
        ax.set_title(s.label, fontsize=9)
        ax.set_xlabel(s.unit or ("fraction" if s.key.endswith("share") else "count"))
        ax.set_ylabel("")
    for ax in axes.ravel()[len(STATISTICS):]:
        ax.axis("off")
    fig.text(0.99, 0.02, f"n: scenarios; a box (quartiles, whiskers 1.5 IQR) from n = {min_box} "
             "on,\nbelow it the points and their median (black tick)", ha="right", va="bottom",
             fontsize=8, color="0.3")
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
    rows, hists, pools, agents = collect(datasets, args.limit, not args.no_progress,
                                         args.kept_only, args.egos)
    frame = pd.DataFrame(rows)
    table = summary_table(frame, args.kept_only)
    print(table)
    reference = args.reference or list(datasets)[-1]
    div = divergences(hists, reference)
    if len(div):
        print(f"\nJensen-Shannon divergence (base 2) from {reference}:")
        print(div.drop(columns="reference").to_string(index=False))
    edge = road_edge_classes(hists)
    edge_md = road_edge_table(edge)
    print(f"\n{edge_md}")
    motion = pd.DataFrame(motion_summary(pools, reference))
    motion_md = motion_tables(motion, args.kept_only)
    print(f"\nMotion statistics, median [p10, p90]:\n\n{motion_md}")
    if args.out is not None:
        atomic_write_csv(os.path.join(args.out, "stats.csv"), frame)
        atomic_write_csv(os.path.join(args.out, "divergence.csv"), div)
        atomic_write_csv(os.path.join(args.out, "road_edge.csv"), edge)
        atomic_write_text(os.path.join(args.out, "stats.md"),
                          f"{table}\n\n{edge_md}\n\n## Motion statistics, median [p10, p90]"
                          f"\n\n{motion_md}\n")
        plot(frame, os.path.join(args.out, "stats.png"), args.kept_only)
        atomic_write_csv(os.path.join(args.out, "motion_stats.csv"), motion)
        atomic_write_csv(os.path.join(args.out, "motion_agents.csv"), pd.DataFrame(agents))
        plot_motion(pools, os.path.join(args.out, "motion_stats.png"))
    return 0
