"""Pictures of scenarios: road edges, lanes, lines, crosswalks, agents' boxes and trajectories."""

from __future__ import annotations

import os
import re

import numpy as np

from igdrivsim.data.scenario import (
    CURRENT_INDEX,
    RG_CROSSWALK,
    RG_ROAD_EDGE_TYPES,
    TYPE_PEDESTRIAN,
    Scenario,
    decode_scenario_id,
)
from igdrivsim.io import atomic_savefig

_LANES, _LINES = (1, 2, 3), tuple(range(5, 14))
GENERATED_ID = re.compile(r"syn([0-9a-f]+)([a-z])(\d{8})")  # the generator's scenario names
SPLIT_LETTERS = {"training": "t", "validation": "v", "testing": "x"}  # a split's letter in them


def readable_title(scenario_id: str) -> str:
    """``syn0t00000003`` -> ``Synthetic training scenario 3 (seed 0)``; another id as it is."""
    match = GENERATED_ID.fullmatch(scenario_id)
    if match is None:
        return f"Scenario {scenario_id}"
    seed, split, index = match.groups()
    split = next((k for k, v in SPLIT_LETTERS.items() if v == split), split)
    return f"Synthetic {split} scenario {int(index)} (seed {int(seed, 16)})"


def draw_scenario(ax, scenario: Scenario, radius: float = 70.0, title: str | None = None) -> None:
    """Draw one (unbatched) scenario on a matplotlib axis: boxes at step 10, logged trajectories,
    centred on the middle of the SDC's log, a 20 m scale bar and ``title`` (default: its id's)."""
    from matplotlib.patches import Polygon  # heavy: only when drawing
    from mpl_toolkits.axes_grid1.anchored_artists import AnchoredSizeBar

    rg, tr, md = scenario.roadgraph, scenario.trajectory, scenario.metadata
    xy, t, ids = np.asarray(rg.xyz)[:, :2], np.asarray(rg.type), np.asarray(rg.id)
    ok = np.asarray(rg.valid)
    styles = [(_LANES, dict(color="0.75", lw=0.6, ls="--")), (_LINES, dict(color="goldenrod",
              lw=0.7)), (RG_ROAD_EDGE_TYPES, dict(color="black", lw=1.3)),
              ((RG_CROSSWALK,), dict(color="tab:blue", lw=0.8))]
    for types, style in styles:
        sel = ok & np.isin(t, types)
        for pid in np.unique(ids[sel]):
            ax.plot(*xy[sel & (ids == pid)].T, **style)
    sdc = int(np.argmax(np.asarray(md.is_sdc)))
    x, y, yaw, valid = (np.asarray(a) for a in (tr.x, tr.y, tr.yaw, tr.valid))
    now = CURRENT_INDEX
    for i in np.flatnonzero(np.asarray(md.valid)):
        color = "tab:red" if i == sdc else ("tab:green" if md.object_type[i] == TYPE_PEDESTRIAN
                                            else "tab:blue")
        v = valid[i]
        ax.plot(x[i, v], y[i, v], color=color, lw=1.6 if i == sdc else 0.8, alpha=0.7)
        if v[now]:
            c, s = np.cos(yaw[i, now]), np.sin(yaw[i, now])
            half = np.array([tr.length[i, now], tr.width[i, now]]) / 2
            box = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]]) * half
            box = box @ np.array([[c, s], [-s, c]]) + [x[i, now], y[i, now]]
            ax.add_patch(Polygon(box, closed=True, fc=color, ec="black", lw=0.5,
                                 alpha=1.0 if i == sdc else 0.6))
    tl = scenario.traffic_lights  # stop points, coloured by the state at the current step
    lit = np.asarray(tl.valid)[:, now] if np.asarray(tl.valid).size else np.zeros(0, bool)
    colours = {4: "red", 5: "orange", 6: "limegreen"}
    for k in np.flatnonzero(lit):
        ax.plot(tl.x[k, now], tl.y[k, now], "o", ms=3.5, mec="black", mew=0.4,
                color=colours.get(int(tl.state[k, now]), "0.5"))
    mid = np.flatnonzero(valid[sdc])  # centre the view on the middle of the SDC's log
    mid = mid[len(mid) // 2] if len(mid) else now
    cx, cy = x[sdc, mid], y[sdc, mid]
    ax.set(xlim=(cx - radius, cx + radius), ylim=(cy - radius, cy + radius), aspect="equal",
           xticks=[], yticks=[])
    ax.set_title(title or readable_title(decode_scenario_id(scenario.scenario_id)), fontsize=9)
    ax.add_artist(AnchoredSizeBar(ax.transData, 20.0, "20 m", "lower right", pad=0.4, sep=3,
                                  frameon=True, size_vertical=0.8, fontproperties={"size": 7}))


def add_legend(ax) -> None:
    """Explain the colours of :func:`draw_scenario` (below the axes, off the road)."""
    from matplotlib.lines import Line2D  # heavy: only when drawing

    items = [("SDC (box at t=1 s, log)", "tab:red", "-"), ("vehicles", "tab:blue", "-"),
             ("pedestrians", "tab:green", "-"), ("road edges", "black", "-"),
             ("lane centres", "0.75", "--"), ("road lines", "goldenrod", "-"),
             ("traffic light (stop point)", "red", "o")]
    handles = [Line2D([], [], color=c, ls="" if ls == "o" else ls, marker="o" if ls == "o" else
                      None, ms=3.5, lw=1.5) for _, c, ls in items]
    ax.legend(handles, [n for n, _, _ in items], loc="upper center", bbox_to_anchor=(0.5, -0.01),
              ncols=3, fontsize=7, frameon=False)


def save_pictures(scenarios: list[Scenario], out_dir: str) -> list[str]:
    """One PNG per scenario, ``out_dir/synthetic_{k}.png`` titled ``k: ...`` (k from 1)."""
    import matplotlib  # heavy: only when drawing

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # heavy: only when drawing

    os.makedirs(out_dir, exist_ok=True)
    paths = []
    for k, scenario in enumerate(scenarios, 1):
        fig, ax = plt.subplots(figsize=(5, 5.7), dpi=110)
        name = readable_title(decode_scenario_id(scenario.scenario_id))
        draw_scenario(ax, scenario, title=f"{k}: {name[0].lower()}{name[1:]}")
        add_legend(ax)
        fig.tight_layout()
        path = os.path.join(out_dir, f"synthetic_{k}.png")
        try:
            atomic_savefig(fig, path)
        finally:
            plt.close(fig)
        paths.append(path)
    return paths
