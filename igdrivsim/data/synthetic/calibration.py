"""The motion calibration target: the logged SDC's constant-velocity divergence.

``igdrivsim cv-divergence`` prints per data set the median [p10, p90] over SDCs of
:func:`cv_divergence` (a constant-velocity actor's log divergence over the 8 s future).
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence

import numpy as np

from igdrivsim.data.filter import intersecting_objects, sdc_mean_speed
from igdrivsim.data.scenario import CURRENT_INDEX, DT, Scenario
from igdrivsim.data.source import open_scenarios
from igdrivsim.data.stats_command import parse_datasets
from igdrivsim.io import atomic_write_text

HORIZON_STEPS = 80  # 8 s after the current step


def cv_divergence(scenario: Scenario) -> tuple[float, float, float]:
    """``(distance, |along|, |across|)``: the SDC's mean distance from its constant-velocity
    extrapolation over the valid steps of the next 8 s, and its parts along/across its heading."""
    tr = scenario.trajectory
    i = int(np.argmax(np.asarray(scenario.metadata.is_sdc)))
    xy = np.stack([np.asarray(tr.x[i]), np.asarray(tr.y[i])], -1).astype(np.float64)
    v = np.array([tr.vel_x[i, CURRENT_INDEX], tr.vel_y[i, CURRENT_INDEX]], np.float64)
    k = np.arange(1, min(HORIZON_STEPS + 1, xy.shape[0] - CURRENT_INDEX))
    k = k[np.asarray(tr.valid[i], bool)[CURRENT_INDEX + k]]
    if not len(k) or not tr.valid[i, CURRENT_INDEX]:
        return np.nan, np.nan, np.nan
    e = xy[CURRENT_INDEX + k] - (xy[CURRENT_INDEX] + v * (k * DT)[:, None])
    yaw = float(tr.yaw[i, CURRENT_INDEX])
    along = e @ np.array([np.cos(yaw), np.sin(yaw)])
    across = e[:, 1] * np.cos(yaw) - e[:, 0] * np.sin(yaw)
    return (float(np.linalg.norm(e, axis=1).mean()), float(np.abs(along).mean()),
            float(np.abs(across).mean()))


def cv_table(datasets: dict[str, list[str]], kept_only: Sequence[str] = ()) -> str:
    """The Markdown table of :func:`cv_divergence` per data set (``kept_only``: filter-kept)."""
    lines = ["| data set | SDCs | CV divergence over 8 s (m) | along (m) | across (m) |",
             "|---|---|---|---|---|"]
    for name, paths in datasets.items():
        scenarios = (rec.scenario for rec in open_scenarios(paths, caps=None))
        rows = [cv_divergence(s) for s in scenarios if name not in kept_only
                or (intersecting_objects(s).any() and sdc_mean_speed(s) >= 0.7)]
        v = np.array(rows).reshape(-1, 3)
        v = v[np.isfinite(v).all(1)]
        kept = " (kept)" if name in kept_only else ""
        cells = " | ".join(f"{np.median(c):.2f} [{np.percentile(c, 10):.2f}, "  # median [p10, p90]
                           f"{np.percentile(c, 90):.2f}]" if len(v) else "-" for c in v.T)
        lines.append(f"| {name}{kept} | {len(v)} | {cells} |")
    return "\n".join(lines)


def cv_divergence_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("files", nargs="+", metavar="[NAME=]PATH",
                        help="data sets, as for igdrivsim stats")
    parser.add_argument("--kept-only", action="append", default=[], metavar="NAME",
                        help="only the filter-kept scenarios of data set NAME (repeatable)")
    parser.add_argument("--out", default=None, help="also write the table to this file")


def cv_divergence_command(args: argparse.Namespace) -> int:
    table = cv_table(parse_datasets(args.files), args.kept_only)
    print(table)
    if args.out:
        atomic_write_text(args.out, table + "\n")
    return 0
