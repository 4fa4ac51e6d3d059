"""Figures read at a glance: error bars within a metric's range, significant cells marked,
reference actors drawn and labelled, no hole for a method without a run, a unit on every axis,
thousands separators, Fig. 1 per profile, the scene pictures' titles, scale bar and legend."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import jax
import matplotlib
import numpy as np
import pandas as pd
import pytest

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from igdrivsim.evaluation.schema import REFERENCE_SETTING  # noqa: E402
from igdrivsim.names import SETTINGS  # noqa: E402
from igdrivsim.report import figures  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
WOMD = REPO.parent / "shared" / "data" / "womd" / "motion_data_one_example.tfrecord"
SEEDS = (0, 1, 2)


def seed_frame(methods=("bc", "bc_rl"), skip=()) -> pd.DataFrame:
    """Seed means of Fig. 3's metrics: offroad near 0 % with a wide spread (its t-interval
    reaches below 0), the references as in ``seed_means``; ``skip``: (setting, method) left
    out."""
    rows = []
    for setting in SETTINGS:
        for method in methods:
            if (setting, method) in skip:
                continue
            for seed in SEEDS:
                rows += [(setting, method, seed, "log_divergence", 5.0 + 0.1 * seed),
                         (setting, method, seed, "overlap", 6.0 + seed),
                         (setting, method, seed, "offroad", [0.1, 0.2, 4.0][seed])]
    for method, level in (("constant_velocity", 8.0), ("expert", 0.5)):
        rows += [(REFERENCE_SETTING, method, 0, key, level)
                 for key in ("log_divergence", "overlap", "offroad")]
    return pd.DataFrame(rows, columns=["setting", "method", "seed", "metric", "value"])


def holm_rows(significant: list[tuple[str, str, str]]) -> pd.DataFrame:
    """Rows of ``tests.csv``: ``(method, metric, setting)`` significant, one other row not."""
    rows = [dict(method=m, baseline="bc", metric=k, setting=s, significant=True)
            for m, k, s in significant]
    rows.append(dict(method="bc_rl", baseline="bc", metric="overlap", setting="full",
                     significant=False))
    return pd.DataFrame(rows)


def errorbar_lows(ax) -> list[float]:
    """The lower end of every error bar drawn on ``ax``."""
    lows = []
    for collection in ax.collections:
        for segment in collection.get_segments():
            if len(segment) == 2 and segment[0][0] == segment[1][0]:  # a vertical bar
                lows.append(min(segment[0][1], segment[1][1]))
    return lows


# ------------------------------------------------------------------ the bars' numbers
def test_rate_intervals_are_clipped_to_0_100():
    assert figures.clip_interval(-2.5, 104.0, "%") == (0.0, 100.0)
    assert figures.clip_interval(1.0, 3.0, "%") == (1.0, 3.0)
    assert figures.clip_interval(-0.3, 1.2, "score") == (0.0, 1.0)
    assert figures.clip_interval(-1.0, 2.0, "m") == (0.0, 2.0)  # a distance
    assert figures.clip_interval(-1.0, 2.0, "ratio") == (-1.0, 2.0)  # no known range
    low, high = figures.clip_interval(float("nan"), float("nan"), "%")
    assert math.isnan(low) and math.isnan(high)


def test_cell_stats_clip_the_t_interval_of_seed_means_and_read_summaries():
    cells = figures.cell_stats(seed_frame(), "offroad", "%").set_index(["setting", "method"])
    row = cells.loc[("full", "bc")]
    assert row["mean"] == pytest.approx(4.3 / 3) and row["low"] == 0.0 < row["high"]
    summary = pd.DataFrame(dict(metric="overlap", setting="full", method="bc", mean=[1.0],
                                ci_low=[-0.5], ci_high=[101.0]))
    clipped = figures.cell_stats(summary, "overlap", "%").iloc[0]
    assert (clipped["low"], clipped["high"]) == (0.0, 100.0)


def test_significant_cells_follow_holm_column():
    tests = holm_rows([("bc_rl", "offroad", "circular_r4")])
    assert figures.significant_cells(tests, "offroad") == {("circular_r4", "bc_rl")}
    assert figures.significant_cells(tests, "overlap") == set()
    assert figures.significant_cells(None, "offroad") == set()


# ------------------------------------------------------------------ Fig. 3, 5, 6
def test_fig3_marks_significant_cells_clips_bars_and_draws_references():
    fig = figures.fig3_metrics(seed_frame(), holm_rows([("bc_rl", "offroad", "circular_r4")]))
    try:
        assert fig.marked == {"log_divergence": [], "overlap": [],
                              "offroad": [("circular_r4", "bc_rl")]}
        offroad = fig.axes[2]
        assert [t.get_text() for t in offroad.texts] == [figures.SIGNIFICANT]
        assert min(errorbar_lows(offroad)) == 0.0  # the t-interval reached below 0 %
        assert all(low >= 0 for ax in fig.axes for low in errorbar_lows(ax))
        assert [ax.get_ylabel() for ax in fig.axes] == [
            "log divergence (m)", "overlap (%)", "offroad (%)"]
        labels = fig.legends[0].get_texts()
        names = [t.get_text() for t in labels]
        assert names[:2] == ["BC", "BC-RL"]
        assert "Constant velocity" in names and "Expert (discretised replay)" in names
        assert any(n.startswith("significant vs BC") for n in names)
        lines = {ln.get_label(): ln for ln in offroad.get_lines()}
        cv, expert = lines["Constant velocity"], lines["Expert (discretised replay)"]
        assert cv.get_ydata()[0] == 8.0 and expert.get_ydata()[0] == 0.5
        assert (cv.get_linestyle(), cv.get_color()) != (expert.get_linestyle(),
                                                         expert.get_color())
    finally:
        plt.close(fig)


def test_fig6_has_no_hole_where_taught_methods_have_no_full_run():
    skip = {("full", "dagger"), ("full", "advisor")}
    frame = seed_frame(("bc", "bc_rl", "dagger", "advisor"), skip)
    fig = figures.fig6_methods(frame, tests=holm_rows([("dagger", "offroad", "circular_r4")]))
    try:
        ax = fig.axes[0]
        bars = [p for p in ax.patches if p.get_height() > 0]
        full = sorted(p.get_x() + p.get_width() / 2 for p in bars
                      if abs(p.get_x() + p.get_width() / 2) < 0.5)
        assert len(full) == 2 and full[0] == pytest.approx(-full[1])  # centred, no empty slot
        assert fig.marked["offroad"] == [("circular_r4", "dagger")]
        notes = " ".join(t.get_text() for t in fig.texts)
        assert "Full: no DAgger, ADVISOR" in notes and "teacher" in notes
        assert all(ax.get_ylabel().endswith(("(m)", "(%)")) for ax in fig.axes)
    finally:
        plt.close(fig)


def test_fig5_says_it_is_descriptive_and_clips_rates():
    from igdrivsim.evaluation import registry

    metrics = registry.metrics()
    rate = next(m for m in metrics if m.unit == "%" and m.figure)
    rows = [(s, m, seed, rate.key, v) for s in SETTINGS for m in ("bc", "bc_rl")
            for seed, v in zip(SEEDS, (0.0, 0.1, 3.0), strict=True)]
    frame = pd.DataFrame(rows, columns=["setting", "method", "seed", "metric", "value"])
    fig = figures.supplementary_figure(frame, metrics)
    try:
        ax = next(a for a in fig.axes if a.get_title().startswith(rate.label))
        assert ax.get_ylabel() == "%" and min(errorbar_lows(ax)) == 0.0
        assert "no significance tests" in " ".join(t.get_text() for t in fig.texts)
    finally:
        plt.close(fig)


def test_figures_redraw_from_the_committed_tables(tmp_path):
    shutil.copytree(REPO / "paper" / "tables", tmp_path / "tables")
    written = figures.redraw_from_tables(tmp_path)
    assert sorted(p.name for p in written) == [
        "fig3_metrics.pdf", "fig3_metrics.png", "fig5_supplementary.pdf",
        "fig5_supplementary.png"]  # Fig. 6 needs its methods' seed means
    assert all(p.stat().st_size > 10_000 for p in written)


# ------------------------------------------------------------------ the maze
@pytest.fixture(scope="module")
def maze_curves() -> pd.DataFrame:
    return pd.read_csv(REPO / "paper" / "figures" / "fig2_maze.csv")


def test_maze_baselines_axis_has_thousands_separators_and_units(maze_curves):
    from maze import extended, report

    refs = {"oracle_full": (9.7, 6.6), "planner_partial": (8.0, 45.0)}
    fig = extended.baselines_figure(maze_curves, report.summarise(maze_curves), refs,
                                    {"converged": False})
    try:
        ax = fig.axes[0]
        fig.canvas.draw()
        ticks = [t.get_text() for t in ax.get_xticklabels() if t.get_text()]
        assert any(t.endswith(",000") for t in ticks) and not any("00000" in t for t in ticks)
        assert ax.get_xlabel().endswith("(steps)") and "(reward" in ax.get_ylabel()
    finally:
        plt.close(fig)
    fig = report.figure(maze_curves, report.summarise(maze_curves), refs)
    try:
        assert "(reward" in fig.axes[0].get_ylabel() and "(fraction" in fig.axes[0].get_xlabel()
    finally:
        plt.close(fig)


def test_maze_replot_rewrites_both_figures(tmp_path):
    from maze import study

    (tmp_path / "figures").mkdir()
    shutil.copy(REPO / "paper" / "figures" / "fig2_maze.csv", tmp_path / "figures")
    shutil.copy(REPO / "paper" / "maze_config.json", tmp_path)
    assert sorted(p.name for p in study.replot(tmp_path)) == [
        "fig2_maze.pdf", "fig2_maze.png", "fig2b_maze_baselines.pdf",
        "fig2b_maze_baselines.png"]
    assert study.main(["--replot", "--out", str(tmp_path / "absent")]) == 2


def test_every_paper_figure_is_referenced():
    tex = (REPO / "paper" / "main.tex").read_text()
    for path in sorted((REPO / "paper" / "figures").glob("*.png")):
        assert f"figures/{path.stem}." in tex, path.name
    for label in ("fig:observations", "fig:maze-frames", "fig:maze", "fig:maze-baselines",
                  "fig:metrics", "fig:curves", "fig:methods", "fig:supplementary"):
        assert rf"\label{{{label}}}" in tex and (rf"ref{{{label}}}" in tex
                                                  or rf"Cref{{{label}}}" in tex), label


# ------------------------------------------------------------------ Fig. 1
def test_fig1_profiles_match_the_training_profiles():
    from igdrivsim.observation.render import PROFILE_VIEWS
    from igdrivsim.training.config import get_profile

    for name, view in PROFILE_VIEWS.items():
        obs = get_profile(name).observation
        assert (view.num_objects, view.num_roadgraph_points, view.roadgraph_stride) == (
            obs.num_objects, obs.num_roadgraph_points, obs.roadgraph_stride), name
    assert "64 nearest road points" in PROFILE_VIEWS["laptop"].describe()


def test_panel_note_stays_within_its_width():
    from igdrivsim.observation.render import Snapshot, panel_note

    snap = Snapshot(*[np.zeros((0, 2))] * 5, ego_size=(4.0, 2.0),
                    seen_road_xy=np.zeros((1500, 2)), seen_road_type=np.zeros(0),
                    seen_obj_xy=np.zeros((0, 2)), seen_obj_yaw=np.zeros(0),
                    seen_obj_size=np.zeros((0, 2)), noise_offset=np.array([3.0, 0.0]))
    lines = panel_note(snap).splitlines()
    assert len(lines) == 2 and all(len(line) <= 44 for line in lines)
    assert "1,500 road points" in lines[0] and "3.0 m off" in lines[1]


@pytest.mark.skipif(not WOMD.exists(), reason=f"real WOMD sample absent: {WOMD}")
def test_fig1_has_a_block_per_profile_with_metre_axes():
    import igdrivsim.simulator as sim
    from igdrivsim.data import load_scenario
    from igdrivsim.observation.render import X_LABEL, Y_LABEL, observation_figure

    state = jax.jit(sim.reset)(load_scenario(WOMD))
    fig = observation_figure(state, ["full"], jax.random.PRNGKey(0))
    try:
        titles = [sub.get_suptitle() for sub in fig.subfigs]
        assert titles[0].startswith("laptop profile: 16 objects, 64")
        assert titles[1].startswith("paper profile: 32 objects, 1,500")
        panels = [ax for sub in fig.subfigs for ax in sub.axes if ax.get_title() == "Full obs"]
        assert len(panels) == 2
        assert all(ax.get_xlabel() == X_LABEL and ax.get_ylabel() == Y_LABEL for ax in panels)
        assert "(m)" in X_LABEL and "(m)" in Y_LABEL
        notes = [t.get_text() for ax in panels for t in ax.texts if t.get_text().startswith(
            "seen")]
        assert "64 road points" in notes[0] and "1,500 road points" in notes[1]
    finally:
        plt.close(fig)


# ------------------------------------------------------------------ docs/images
def test_scene_stats_show_n_and_points_below_ten(monkeypatch, tmp_path):
    from igdrivsim.data import stats_command
    from igdrivsim.data.stats import STATISTICS

    captured = []
    monkeypatch.setattr(stats_command, "atomic_savefig", lambda fig, path, **k: captured.append(
        fig))
    rng = np.random.default_rng(0)
    rows = [{"dataset": name, "kept": True, **{s.key: rng.normal() for s in STATISTICS}}
            for name, n in (("many", 12), ("few", 4)) for _ in range(n)]
    stats_command.plot(pd.DataFrame(rows), str(tmp_path / "stats.png"))
    ax = captured[0].axes[0]
    assert [t.get_text() for t in ax.get_yticklabels()] == ["many (n=12)", "few (n=4)"]
    medians = [ln for ln in ax.get_lines() if ln.get_marker() == "|"]
    assert len(medians) == 1 and medians[0].get_ydata()[0] == 1  # the n=4 row: no box
    assert all(a.get_xlabel() for a in captured[0].axes if a.axison)
    stats_command.plot(pd.DataFrame(rows), str(tmp_path / "stats.png"))  # again: same points
    points = [[c.get_offsets().tolist() for c in fig.axes[0].collections] for fig in captured]
    assert points[0] == points[1] and sum(map(len, points[0])) == 16
    for fig in captured:
        plt.close(fig)


def test_scene_pictures_have_titles_scale_bar_and_legend_off_the_road():
    from mpl_toolkits.axes_grid1.anchored_artists import AnchoredSizeBar

    from igdrivsim.data.scenario import decode_scenario_id
    from igdrivsim.data.synthetic.generator import generate_scenario
    from igdrivsim.data.synthetic.plot import add_legend, draw_scenario, readable_title

    assert readable_title("syn0t00000003") == "Synthetic training scenario 3 (seed 0)"
    assert readable_title("syn2av00000010") == "Synthetic validation scenario 10 (seed 42)"
    ids = {split: decode_scenario_id(generate_scenario(1, 2, split).scenario_id)
           for split in ("training", "validation", "testing")}
    assert len(set(ids.values())) == 3  # a testing id is not a training one
    assert readable_title(ids["testing"]) == "Synthetic testing scenario 2 (seed 1)"
    fig, ax = plt.subplots()
    try:
        draw_scenario(ax, generate_scenario(0, 0))
        add_legend(ax)
        assert ax.get_title() == "Synthetic training scenario 0 (seed 0)"
        bars = [a for a in ax.artists if isinstance(a, AnchoredSizeBar)]
        assert len(bars) == 1 and bars[0].txt_label.get_text() == "20 m"
        fig.canvas.draw()
        legend = ax.get_legend().get_window_extent()
        assert legend.y1 <= ax.get_window_extent().y0 + 1  # below the axes, not on the road
    finally:
        plt.close(fig)
