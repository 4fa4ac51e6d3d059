"""Imitation-gap baselines of the maze study (Fig. 2b): DAgger, BC+PPO and ADVISOR, each
teaching the partial-observation student with the full-observation RL expert, 10 seeds.

``run_dagger`` and ``run_mixed`` return the same record dicts as the paper's stages
(:mod:`maze.study`); x-axis of Fig. 2b: environment steps per seed (the student's own samples;
DAgger's first slot is the teacher's). ``plateau`` is the convergence criterion drawn on the
partial RL bound.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
from tqdm import tqdm

from igdrivsim.io import atomic_savefig
from maze.report import CURVES, RETURN_LABEL, ci95

MIXED_CURVES = {"bc_rl_partial_from_full": False, "advisor_partial_from_full": True}
EXTENDED = ("dagger_partial_from_full", *MIXED_CURVES)


def stage_key(seed: int, *path: int) -> jax.Array:
    key = jax.random.PRNGKey(seed)
    for p in path:
        key = jax.random.fold_in(key, p)
    return key


def records(curve: str, unit: str, points: list, seeds: int | Sequence[int]) -> list[dict]:
    """Tidy rows ``(curve, seed, progress, step, unit, return, length, final)``; ``seeds``: the
    seeds of the points' rows (a count: ``range(seeds)``); ``progress``: step / the last step."""
    seeds = range(seeds) if isinstance(seeds, int) else seeds
    rows = []
    last = len(points) - 1
    for i, (step, ret, length) in enumerate(points):
        for r, s in enumerate(seeds):
            rows.append({"curve": curve, "seed": int(s), "progress": step / points[-1][0],
                         "step": step, "unit": unit, "return": float(ret[r]),
                         "length": float(length[r]), "final": i == last})
    return rows


def plateau_start(anneal: bool) -> float:
    """Where the plateau test's last quarter of learning starts, as a fraction of the updates.

    With a constant learning rate, at 3/4 of the updates. Under PPO's linear decay to 0 the last
    quarter of the updates takes only 1/16 of the step sizes' sum, so it is flat whether or not
    the policy has converged (partial RL, GRU-32, 5 seeds: 320 updates rose 0.06 there and ended
    at 7.74, 640 updates ended at 8.10); the last quarter of the sum starts at half the updates
    (by then 1 - (1 - 1/2)^2 = 3/4 of it is spent)."""
    return 0.5 if anneal else 0.75


def plateau_point(chunks: int, start: float = 0.75) -> int:
    """The point (0: before training, ``chunks``: the final one) that :func:`plateau` compares
    the final point with: the last at or before ``start`` (:func:`plateau_start`) of the run. The
    RL stages evaluate it with as many episodes as the final point, so that the rise is not
    mostly the noise of a 1-round evaluation (partial RL: about 0.08 of SD with 256 episodes x
    10 seeds, against a tolerance of 0.1, which failed a flat curve about one time in ten)."""
    return int(np.floor(start * chunks + 1e-9))


def plateau(curves: pd.DataFrame, curve: str, tol: float, optimum: float | None = None,
            start: float = 0.75) -> dict:
    """Convergence test: the seed-mean return rose by less than ``tol`` over the last quarter of
    learning (final point vs. the last point at or before ``start`` of the run, see
    :func:`plateau_start`), or it is within 2% of a known exact ``optimum`` (the
    full-observation shortest path). ``since``: the compared point's fraction of the run;
    ``rise_ci95``: the half-width of the rise's 95% interval over seeds (NaN without a ``seed``
    column), which says how far from the tolerance the verdict is."""
    rows = curves[curves.curve == curve]
    mean = rows.groupby("progress")["return"].mean()
    if mean.empty:
        return {"converged": False, "rise": float("nan"), "rise_ci95": float("nan"),
                "since": start, "tol": tol}
    at = mean.index[mean.index <= start + 1e-9].max()
    rise = float(mean.iloc[-1] - mean.loc[at])
    spread = float("nan")
    if "seed" in rows:
        per_seed = rows.pivot_table(index="seed", columns="progress", values="return")
        spread = ci95(per_seed[mean.index[-1]] - per_seed[at])
    at_optimum = optimum is not None and float(mean.iloc[-1]) >= 0.98 * optimum
    return {"converged": bool(rise < tol or at_optimum), "rise": rise, "rise_ci95": spread,
            "since": float(at), "tol": tol, "at_optimum": bool(at_optimum)}


def run_dagger(study, experts: dict, bar: tqdm, seeds: Sequence[int] | None = None) -> dict:
    """DAgger from the full-observation expert, ``vmap`` over ``seeds`` (all; the expert's rows
    are these seeds), one eval per iteration."""
    cfg = study.cfg
    seeds = tuple(range(cfg.seeds)) if seeds is None else tuple(seeds)
    t0 = time.perf_counter()
    teacher = experts["rl_full"]
    net = study.init_params(7, cfg.seeds, seeds)
    state = study.dagger_init(jnp.stack([stage_key(cfg.seed, 7, 1, j) for j in seeds]), net)
    eval_key = stage_key(cfg.seed, 7, 2)
    points = [(0, *study.eval_rows(state.params, True, eval_key, seeds=seeds))]
    metrics = []
    for i in range(cfg.dagger.iterations):
        state, m = study.dagger_iter(state, teacher)
        metrics.append({k: np.asarray(v).mean(axis=0).tolist() for k, v in m.items()})
        last = i == cfg.dagger.iterations - 1
        ret, length = study.eval_rows(state.params, True, jax.random.fold_in(eval_key, i + 1),
                                      cfg.final_eval_rounds if last else 1, seeds)
        points.append(((i + 1) * cfg.dagger.steps_per_collection, ret, length))
        bar.update(1)
        bar.set_postfix_str(f"dagger return {ret.mean():.2f}")
    return {"records": records("dagger_partial_from_full", "env_steps_per_seed", points, seeds),
            "metrics": metrics, "seconds": time.perf_counter() - t0}


def run_mixed(study, experts: dict, bar: tqdm,
              names: tuple[str, ...] = tuple(MIXED_CURVES),
              seeds: Sequence[int] | None = None) -> dict:
    """BC+PPO and/or ADVISOR (``names``) in one program (``vmap`` over methods x ``seeds``)."""
    cfg = study.cfg
    seeds = tuple(range(cfg.seeds)) if seeds is None else tuple(seeds)
    s = len(seeds)
    ids = [8 + list(MIXED_CURVES).index(c) for c in names]  # stable PRNG paths per curve
    n = len(names)
    t0 = time.perf_counter()
    teacher = jax.tree.map(lambda x: jnp.concatenate([x] * n), experts["rl_full"])
    net = jax.tree.map(lambda *xs: jnp.concatenate(xs),
                       *[study.init_mixed_params(i, cfg.seeds, seeds) for i in ids])
    keys = jnp.stack([stage_key(cfg.seed, i, 1, j) for i in ids for j in seeds])
    flags = jnp.repeat(jnp.array([MIXED_CURVES[c] for c in names]), s)
    state = study.mixed_init(keys, net, flags, jnp.full(n * s, cfg.mixed_updates, jnp.int32))

    def evaluate_all(chunk: int, rounds: int = 1):
        plain = study.strip_aux(state.params)
        return [study.eval_rows(jax.tree.map(lambda x, i=i: x[i * s:(i + 1) * s], plain), True,
                                jax.random.fold_in(stage_key(cfg.seed, ids[i], 2), chunk), rounds,
                                seeds)
                for i in range(n)]

    points = [[(0, *r)] for r in evaluate_all(0)]
    n_chunks = cfg.mixed_updates // cfg.chunk_updates
    metrics = []
    for c in range(n_chunks):
        state, m = study.mixed_chunk(state, teacher)
        metrics.append({k: np.asarray(v).reshape(n, s, -1).mean(axis=(1, 2)).tolist()
                        for k, v in m.items()})
        last = c == n_chunks - 1
        for i, r in enumerate(evaluate_all(c + 1, cfg.final_eval_rounds if last else 1)):
            points[i].append(((c + 1) * cfg.chunk_updates * cfg.ppo.steps_per_update, *r))
        bar.update(1)
        bar.set_postfix_str(" ".join(f"{c.split('_')[0]} {p[-1][1].mean():.2f}"
                                     for c, p in zip(names, points, strict=True)))
    rows = []
    for i, c in enumerate(names):
        rows += records(c, "env_steps_per_seed", points[i], seeds)
    return {"records": rows, "metrics": metrics, "seconds": time.perf_counter() - t0}


def plot_baselines(curves: pd.DataFrame, summary: pd.DataFrame, refs: dict, converged: dict,
                   stem: Path) -> None:
    """Write Fig. 2b (:func:`baselines_figure`) to ``stem.{pdf,png}``."""
    import matplotlib.pyplot as plt  # heavy: only when drawing

    fig = baselines_figure(curves, summary, refs, converged)
    for ext in ("pdf", "png"):
        atomic_savefig(fig, stem.with_suffix(f".{ext}"), dpi=200)
    plt.close(fig)


def baselines_figure(curves: pd.DataFrame, summary: pd.DataFrame, refs: dict, converged: dict):
    """Fig. 2b: return vs environment steps per seed for the partial student (mean, 95% CI);
    ``converged``: the partial RL curve's plateau test."""
    import matplotlib  # heavy: only when drawing

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # heavy: only when drawing
    from matplotlib.ticker import StrMethodFormatter  # heavy: only when drawing

    fig, ax = plt.subplots(figsize=(8.6, 4.0))
    for name in ("rl_partial", *EXTENDED):
        data = curves[curves.curve == name]
        if data.empty:
            continue
        g = data.groupby("step")["return"]
        m = g.mean()
        h = g.agg(ci95)
        ax.plot(m.index, m.values, color=CURVES[name][1], lw=1.6, label=CURVES[name][0])
        ax.fill_between(m.index, m - h, m + h, color=CURVES[name][1], alpha=0.2, lw=0)
    final = summary.set_index("curve").final_return_mean
    status = "converged" if converged.get("converged") else "not converged"
    for name, text, ls in (("rl_full", "RL full obs. (final)", "--"),
                           ("rl_partial", f"RL partial obs. (final, {status})", "--"),
                           ("bc_partial_from_full", "BC full $\\to$ partial (final)", "-.")):
        if name in final:
            ax.axhline(final[name], color=CURVES[name][1], ls=ls, lw=1.1, label=text)
    ax.axhline(refs["planner_partial"][0], color="0.6", ls=":", lw=1.1,
               label="exploring planner (partial obs.)")
    ax.set_xlabel("environment steps per seed (steps)")
    ax.xaxis.set_major_formatter(StrMethodFormatter("{x:,.0f}"))  # 600,000, not 600000
    ax.set_ylabel(RETURN_LABEL)
    ax.set_ylim(0, 10.3)
    ax.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.01, 0.5), frameon=False)
    ax.set_title("Full-obs. expert $\\to$ partial-obs. student: remedies (mean, 95% CI over "
                 "seeds)", fontsize=8)
    fig.tight_layout()
    return fig
