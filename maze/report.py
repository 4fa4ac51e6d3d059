"""Figure 2, its CSV and the summary tables of the maze study (written atomically)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from igdrivsim.io import atomic_savefig

# curve name -> (legend label, colour close to the paper's figure)
CURVES: dict[str, tuple[str, str]] = {
    "rl_full": ("RL, full obs. (PPO)", "#1f3b73"),
    "rl_partial": ("RL, partial obs. (PPO)", "#8c564b"),
    "bc_full_from_full": ("BC: full expert $\\to$ full imitator", "#1f77b4"),
    "bc_partial_from_full": ("BC: full expert $\\to$ partial imitator", "#17becf"),
    "bc_partial_from_partial": ("BC: partial expert $\\to$ partial imitator", "#e377c2"),
    "dagger_partial_from_full": ("DAgger: full expert $\\to$ partial imitator", "#2ca02c"),
    "bc_rl_partial_from_full": ("BC+PPO: full expert $\\to$ partial imitator", "#ff7f0e"),
    "advisor_partial_from_full": ("ADVISOR: full expert $\\to$ partial imitator", "#9467bd"),
}
PLAIN = {"rl_full": "RL full obs. (PPO)", "rl_partial": "RL partial obs. (PPO)",
         "bc_full_from_full": "BC full -> full", "bc_partial_from_full": "BC full -> partial",
         "bc_partial_from_partial": "BC partial -> partial",
         "dagger_partial_from_full": "DAgger full -> partial",
         "bc_rl_partial_from_full": "BC+PPO full -> partial",
         "advisor_partial_from_full": "ADVISOR full -> partial"}


def ci95(values) -> float:
    """Half-width of the Student-t 95% confidence interval of the mean (0 for one value)."""
    from scipy import stats  # heavy: scipy is needed only here

    values = np.asarray(values, dtype=float)
    if values.size < 2:
        return 0.0
    sem = values.std(ddof=1) / np.sqrt(values.size)
    return float(stats.t.ppf(0.975, values.size - 1) * sem)


def summarise(curves: pd.DataFrame) -> pd.DataFrame:
    """One row per curve: final return (and length) mean and 95% CI over seeds."""
    rows = []
    for name in CURVES:  # the paper's five, then the baselines of Fig. 2b
        final = curves[(curves.curve == name) & (curves.final)]
        if final.empty:
            continue
        rows.append({"curve": name, "final_return_mean": final["return"].mean(),
                     "final_return_ci95": ci95(final["return"]),
                     "final_length_mean": final["length"].mean(),
                     "final_length_ci95": ci95(final["length"]), "seeds": len(final)})
    return pd.DataFrame(rows)


def summary_markdown(summary: pd.DataFrame, refs: dict, note: str) -> str:
    lines = ["# Maze study (paper Fig. 2): final return per curve", "",
             "| curve | return (mean +- 95% CI) | episode length | seeds |",
             "|---|---|---|---|"]
    for r in summary.itertuples():
        lines.append(f"| {PLAIN[r.curve]} | {r.final_return_mean:.2f} +- {r.final_return_ci95:.2f}"
                     f" | {r.final_length_mean:.1f} +- {r.final_length_ci95:.1f} | {r.seeds} |")
    lines += [f"| shortest-path oracle (full obs., exact) | {refs['oracle_full'][0]:.2f} | "
              f"{refs['oracle_full'][1]:.1f} | - |",
              f"| exploring planner (partial obs., exact) | {refs['planner_partial'][0]:.2f} | "
              f"{refs['planner_partial'][1]:.1f} | - |", "", note, ""]
    return "\n".join(lines)


def summary_latex(summary: pd.DataFrame, refs: dict) -> str:
    tex = {"rl_full": "RL, full obs.\\ (PPO)", "rl_partial": "RL, partial obs.\\ (PPO)",
           "bc_full_from_full": "BC full $\\to$ full",
           "bc_partial_from_full": "BC full $\\to$ partial",
           "bc_partial_from_partial": "BC partial $\\to$ partial",
           "dagger_partial_from_full": "DAgger full $\\to$ partial",
           "bc_rl_partial_from_full": "BC+PPO full $\\to$ partial",
           "advisor_partial_from_full": "ADVISOR full $\\to$ partial"}
    lines = ["\\begin{tabular}{lcc}", "\\toprule",
             "Curve & Final return & Episode length \\\\", "\\midrule"]
    for r in summary.itertuples():
        lines.append(f"{tex[r.curve]} & ${r.final_return_mean:.2f} \\pm {r.final_return_ci95:.2f}$"
                     f" & ${r.final_length_mean:.1f} \\pm {r.final_length_ci95:.1f}$ \\\\")
    lines += ["\\midrule",
              f"Shortest-path oracle (full) & {refs['oracle_full'][0]:.2f} & "
              f"{refs['oracle_full'][1]:.1f} \\\\",
              f"Exploring planner (partial) & {refs['planner_partial'][0]:.2f} & "
              f"{refs['planner_partial'][1]:.1f} \\\\", "\\bottomrule", "\\end{tabular}", ""]
    return "\n".join(lines)


# the reward is 10 - 9 t / max_steps on reaching the goal at step t, else 0 (maze.env.step)
RETURN_LABEL = "mean episodic return (reward, max 10)"
PAPER_CURVES = ("rl_full", "rl_partial", "bc_full_from_full", "bc_partial_from_full",
                "bc_partial_from_partial")


def plot(curves: pd.DataFrame, summary: pd.DataFrame, refs: dict, stem: Path,
         converged: dict[str, bool] | None = None) -> None:
    """Write Fig. 2 (:func:`figure`) to ``stem.{pdf,png}``."""
    import matplotlib.pyplot as plt  # heavy: only when drawing

    fig = figure(curves, summary, refs, converged)
    for ext in ("pdf", "png"):
        atomic_savefig(fig, stem.with_suffix(f".{ext}"), dpi=200)
    plt.close(fig)


def figure(curves: pd.DataFrame, summary: pd.DataFrame, refs: dict,
           converged: dict[str, bool] | None = None):
    """Fig. 2 (the paper's five curves): mean return vs training progress, t-based 95% CI bands,
    dashed final RL returns marked "converged" or "not converged" (``converged``: curve -> the
    plateau test of :func:`maze.extended.plateau`), dotted exact references."""
    import matplotlib  # heavy: only when drawing

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # heavy: only when drawing
    import seaborn as sns  # heavy: only when drawing

    sns.set_theme(style="whitegrid", context="paper")
    fig, ax = plt.subplots(figsize=(8.6, 4.0))
    data = curves.assign(label=curves.curve.map(lambda c: CURVES[c][0]))
    names = [c for c in PAPER_CURVES if c in set(curves.curve)]
    data = data[data.curve.isin(names)]
    palette = {CURVES[c][0]: CURVES[c][1] for c in names}

    def band(values):
        m = float(np.mean(values))
        h = ci95(values)
        return m - h, m + h

    sns.lineplot(data=data, x="progress", y="return", hue="label", hue_order=[
        CURVES[c][0] for c in names], palette=palette, errorbar=band, ax=ax, linewidth=1.6)
    final = summary.set_index("curve").final_return_mean
    converged = converged or {}
    for name, kind in (("rl_full", "full"), ("rl_partial", "partial")):
        status = "converged" if converged.get(name, True) else "not converged"
        text = f"RL, {kind} obs., final ({status})"
        if name in final:
            ax.axhline(final[name], color=CURVES[name][1], ls="--", lw=1.1, label=text)
    ax.axhline(refs["oracle_full"][0], color="0.35", ls=":", lw=1.1,
               label="shortest-path oracle (full obs.)")
    ax.axhline(refs["planner_partial"][0], color="0.6", ls=":", lw=1.1,
               label="exploring planner (partial obs.)")
    ax.set_xlabel("training progress (fraction of each run's updates)")
    ax.set_ylabel(RETURN_LABEL)
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 10.3)
    ax.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.01, 0.5), frameon=False)
    ax.set_title("13x13 maze, imitator receptive field 3 (mean, 95% CI over seeds)", fontsize=8)
    fig.tight_layout()
    return fig
