"""The whole maze study of paper Fig. 2: ``python -m maze.study [--profile default|smoke]``.

Stages (each cached under ``--work`` so an interrupted run resumes at the stage level):
``rl_full`` and ``rl_partial`` (recurrent PPO, the experts and the dashed RL bounds), then ``bc``
(three BC curves, ``vmap``ped over curves x seeds: full->full, full->partial, partial->partial,
labels = the expert's sampled actions on the states it visits), then, unless ``--no-baselines``,
the remedies of :mod:`maze.extended` for the full expert -> partial imitator case: ``dagger``
and ``mixed`` (BC+PPO and ADVISOR in one program). Every curve point is the mean return of fresh
evaluation episodes; the final point uses ``final_eval_rounds`` times more. The RL curves are
tested for a plateau (:func:`maze.extended.plateau`) and drawn "converged" or "not converged".
Outputs under ``--out`` (default ``outputs/maze/``): ``figures/fig2_maze.{pdf,png,csv}``,
``figures/fig2b_maze_baselines.{pdf,png}``, ``tables/maze_summary.{md,tex,csv}`` and
``maze_config.json``. Deterministic for a given config and number of usable CPU cores: XLA
compiles different CPU code for a process pinned to one core (the pipeline's maze stage) than
for two (``python -m maze``), so the two agree within the seeds' intervals, not bit for bit.
``--replot`` redraws Fig. 2 and 2b from ``--out``'s ``figures/fig2_maze.csv`` and
``maze_config.json`` without training.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import os
import pickle
import platform
import shlex
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
from tqdm import tqdm

from igdrivsim.cli_args import DefaultsFormatter
from igdrivsim.errors import ConfigError, DataError, run_command
from igdrivsim.io import (
    atomic_write_bytes,
    atomic_write_csv,
    atomic_write_json,
    atomic_write_text,
    read_json,
    require_folder,
)
from igdrivsim.lanes import Job, run_jobs
from igdrivsim.machine import code_state, machine_record
from maze import extended, report
from maze.bc import BCConfig
from maze.compiled import Program, Study, _key, use_compile_cache  # noqa: F401 (Program: re-exported)
from maze.dagger import DAggerConfig
from maze.env import make_params
from maze.extended import records as _records
from maze.mixed import MixedConfig
from maze.oracles import reference_returns
from maze.ppo import PPOConfig
from maze.render import save_frames

BC_CURVES = {  # name -> (expert curve, expert partial?, imitator partial?)
    "bc_full_from_full": ("rl_full", False, False),
    "bc_partial_from_full": ("rl_full", False, True),
    "bc_partial_from_partial": ("rl_partial", True, True),
}


# ADVISOR's alpha in the maze study, its profiles' value of the driving benchmark's parameter
# (igdrivsim.core.params.AdvisorParams.alpha, default 1.0): the report's Fig. 2b, its numbers
# and its text ("exp(-4 KL)", paper/main.tex) were made with 4. (The maze's KL is over 4
# actions, the driving one a sum over 3 x 257 bins: one alpha need not suit both.)
MAZE_ADVISOR_ALPHA = 4.0


@dataclasses.dataclass(frozen=True)
class StudyConfig:
    """Resolved configuration (written next to the outputs)."""

    profile: str = "default"
    seeds: int = 10
    seed: int = 0
    size: int = 13
    receptive_field: int = 3
    max_steps: int = 200
    hidden: int = 32  # paper: 128; 32 keeps the study near a minute on 2 cores (docs/bench)
    ppo: PPOConfig = PPOConfig()
    rl_full_updates: int = 80  # the plateau test passes (60: rose 0.14; 80: 0.01, at 9.70)
    rl_partial_updates: int = 640  # the plateau test passes (480: rose 0.14; see PPOConfig)
    chunk_updates: int = 10
    # BC lr 1e-2 at GRU-32 (seeds 0-4, BC full -> full / partial -> partial after 6 epochs):
    # 3e-3 9.19 / 7.06, 6e-3 9.52 / 7.66, 1e-2 9.61 / 7.82, 1.5e-2 9.64 / 7.90
    bc: BCConfig = BCConfig(num_envs=64, num_steps=768, epochs=6, num_minibatches=32, lr=1e-2)
    bc_chunk_epochs: int = 1  # epochs between evaluations of the BC curves
    eval_episodes: int = 128
    final_eval_rounds: int = 8  # the final point (and the plateau test's): 1,024 episodes
    rl_curve_points: int = 12  # an RL curve is evaluated every max(1, chunks // this) chunks
    baselines: bool = True  # Fig. 2b: DAgger, BC+PPO, ADVISOR (full expert -> partial student)
    dagger: DAggerConfig = DAggerConfig()
    mixed: MixedConfig = MixedConfig(alpha=MAZE_ADVISOR_ALPHA)
    mixed_updates: int = 60
    plateau_tol: float = 0.1  # RL "converged": rose < this over the last quarter of learning
    lanes: int = 2  # stages run in 2 threads (1: one after another); results are the same
    seed_parts: int = 2  # each stage runs once per part of the seeds (vmap over the part)

    def validate(self) -> None:
        make_params(self.size, self.receptive_field, self.max_steps)
        if self.seeds < 1:
            raise ConfigError(f"--seeds must be >= 1, got {self.seeds}")
        if self.seed_parts < 1:
            raise ConfigError(f"seed_parts must be >= 1, got {self.seed_parts}")
        if self.rl_curve_points < 1:
            raise ConfigError(f"rl_curve_points must be >= 1, got {self.rl_curve_points}")
        if self.hidden < 1:
            raise ConfigError(f"--hidden must be >= 1, got {self.hidden}")
        for name in ("rl_full_updates", "rl_partial_updates") + (
                ("mixed_updates",) if self.baselines else ()):
            if getattr(self, name) % self.chunk_updates:
                raise ConfigError(f"{name} must be a multiple of chunk_updates")
        if self.bc.epochs % self.bc_chunk_epochs:
            raise ConfigError("bc.epochs must be a multiple of bc_chunk_epochs")
        if self.ppo.num_envs % self.ppo.num_minibatches or (
                self.bc.num_envs % self.bc.num_minibatches):
            raise ConfigError("num_envs must be a multiple of num_minibatches")


PROFILES = {
    "default": StudyConfig(),
    "smoke": StudyConfig(
        profile="smoke", seeds=2, hidden=16,
        ppo=PPOConfig(num_envs=8, num_steps=32, num_minibatches=2, update_epochs=2),
        rl_full_updates=4, rl_partial_updates=4, chunk_updates=2,
        bc=BCConfig(num_envs=8, num_steps=64, epochs=2, num_minibatches=2),
        bc_chunk_epochs=1, eval_episodes=16, final_eval_rounds=1,
        dagger=DAggerConfig(iterations=2, num_envs=8, num_steps=32, steps_per_iteration=4,
                            batch_streams=4), mixed_updates=2),
}


def config_dict(cfg: StudyConfig) -> dict:
    return dataclasses.asdict(cfg)


def seed_parts(cfg: StudyConfig) -> list[tuple[int, ...]]:
    """The seeds split into ``cfg.seed_parts`` contiguous parts: each stage runs once per part
    (``vmap`` over the part's seeds), so two lanes share even the longest curve."""
    return [tuple(int(i) for i in p) for p in np.array_split(np.arange(cfg.seeds),
                                                             cfg.seed_parts) if len(p)]


def run_rl(study: Study, name: str, partial: bool, bar: tqdm, updates: int | None = None,
           seeds: Sequence[int] | None = None) -> dict:
    """PPO curve ``name`` (``updates`` overrides the config's length) for ``seeds`` (all)."""
    cfg = study.cfg
    seeds = tuple(range(cfg.seeds)) if seeds is None else tuple(seeds)
    rows = len(seeds)
    total = updates or getattr(cfg, f"{name}_updates")
    curve_id = 1 if name == "rl_full" else 2  # stable small ints for the PRNG keys
    net = study.init_params(curve_id, cfg.seeds, seeds)
    keys = jnp.stack([_key(cfg, curve_id, 1, s) for s in seeds])
    state = study.ppo_init(keys, net, jnp.full(rows, partial),
                           jnp.full(rows, total, jnp.int32))
    eval_key = _key(cfg, curve_id, 2)
    n_chunks = total // cfg.chunk_updates
    # the final point and the one the plateau test compares it with: final_eval_rounds rounds
    compared = extended.plateau_point(n_chunks, extended.plateau_start(cfg.ppo.anneal_lr))
    rounds = {n_chunks: cfg.final_eval_rounds, compared: cfg.final_eval_rounds}
    every = max(1, n_chunks // cfg.rl_curve_points)
    points = [(0, *study.eval_rows(state.params, partial, eval_key, rounds.get(0, 1), seeds))]
    t0 = time.perf_counter()
    for c in range(1, n_chunks + 1):
        state, _ = study.ppo_chunk(state)
        bar.update(1)
        if c % every and c not in rounds:
            continue
        ret, length = study.eval_rows(state.params, partial, jax.random.fold_in(eval_key, c),
                                      rounds.get(c, 1), seeds)
        points.append((c * cfg.chunk_updates * cfg.ppo.steps_per_update, ret, length))
        bar.set_postfix_str(f"{name} return {ret.mean():.2f}")
    seconds = time.perf_counter() - t0
    return {"records": _records(name, "env_steps_per_seed", points, seeds),
            "params": jax.device_get(state.params), "seconds": seconds}


def run_bc(study: Study, experts: dict, bar: tqdm, names: tuple[str, ...] = tuple(BC_CURVES),
           seeds: Sequence[int] | None = None) -> dict:
    """The BC curves ``names`` (``vmap`` over curves x ``seeds``; the experts' rows are these
    seeds)."""
    cfg = study.cfg
    seeds = tuple(range(cfg.seeds)) if seeds is None else tuple(seeds)
    ids = [3 + list(BC_CURVES).index(c) for c in names]  # stable PRNG paths per curve
    n, s = len(names), len(seeds)
    t0 = time.perf_counter()
    expert = jax.tree.map(lambda *xs: jnp.concatenate(xs),
                          *[experts[BC_CURVES[c][0]] for c in names])
    e_flags = jnp.repeat(jnp.array([BC_CURVES[c][1] for c in names]), s)
    i_flags = jnp.repeat(jnp.array([BC_CURVES[c][2] for c in names]), s)
    keys = jnp.stack([_key(cfg, i, 1, j) for i in ids for j in seeds])
    demos = study.collect(expert, keys, e_flags, i_flags)
    net = jax.tree.map(lambda *xs: jnp.concatenate(xs),
                       *[study.init_params(i, cfg.seeds, seeds) for i in ids])
    state = study.bc_init(jnp.stack([_key(cfg, i, 3, j) for i in ids for j in seeds]),
                          net, demos)

    def evaluate_all(chunk: int, rounds: int = 1):
        out = []
        for i, c in enumerate(names):
            rows = jax.tree.map(lambda x, i=i: x[i * s:(i + 1) * s], state.params)
            out.append(study.eval_rows(rows, BC_CURVES[c][2],
                                       jax.random.fold_in(_key(cfg, ids[i], 2), chunk), rounds,
                                       seeds))
        return out

    points = [[(0, *r)] for r in evaluate_all(0)]
    n_chunks = cfg.bc.epochs // cfg.bc_chunk_epochs
    losses = []
    for c in range(n_chunks):
        state, loss = study.bc_chunk(state)
        losses.append(np.asarray(loss).reshape(n, s).mean(axis=1))
        last = c == n_chunks - 1
        for i, r in enumerate(evaluate_all(c + 1, cfg.final_eval_rounds if last else 1)):
            points[i].append(((c + 1) * cfg.bc_chunk_epochs, *r))
        bar.update(1)
        bar.set_postfix_str(f"bc loss {np.round(losses[-1], 3).tolist()}")
    records = []
    for i, c in enumerate(names):
        records += _records(c, "bc_epochs", points[i], seeds)
    return {"records": records, "seconds": time.perf_counter() - t0,
            "losses": np.asarray(losses).tolist()}


def _part_path(folder: Path, name: str, part: tuple[int, ...]) -> Path:
    return folder / f"{name}.seeds{part[0]}-{part[-1]}.pkl"


def _merge(results: list[dict], weights: list[int]) -> dict:
    """One stage's results over the seed parts: records joined, seconds summed, per-chunk
    losses and metrics averaged (weighted by the parts' seeds)."""
    out = {"records": [r for res in results for r in res["records"]],
           "seconds": sum(res["seconds"] for res in results)}
    if "losses" in results[0]:
        out["losses"] = np.average([np.asarray(r["losses"]) for r in results], axis=0,
                                   weights=weights).tolist()
    if "metrics" in results[0]:
        out["metrics"] = [{k: np.average([np.asarray(r["metrics"][i][k]) for r in results],
                                         axis=0, weights=weights).tolist() for k in m}
                          for i, m in enumerate(results[0]["metrics"])]
    return out


def _cached(path: Path, fn):
    """Result of ``fn()``, stored as a pickle at ``path`` (atomic) and reused when present."""
    if path.exists():
        with path.open("rb") as f:
            return pickle.load(f), True
    result = fn()
    atomic_write_bytes(path, pickle.dumps(result))
    return result, False


OUTPUTS = ("figures/fig2_maze.pdf", "figures/fig2_maze.png", "figures/fig2_maze.csv",
           "tables/maze_summary.md", "tables/maze_summary.tex", "tables/maze_summary.csv",
           "figures/maze_frames.png", "maze_config.json")
BASELINE_OUTPUTS = ("figures/fig2b_maze_baselines.pdf", "figures/fig2b_maze_baselines.png")


def outputs(cfg: StudyConfig) -> tuple[str, ...]:
    return OUTPUTS + (BASELINE_OUTPUTS if cfg.baselines else ())


def cpu_text() -> str:
    """``<CPU model>, <N> cores`` of this machine (what provenance names as the device)."""
    model = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{model}, {os.cpu_count()} cores"


def run_study(cfg: StudyConfig, out: Path, work: Path, force: bool = False,
              study: Study | None = None, progress: bool = True,
              command: str | None = None) -> pd.DataFrame:
    """Run (or resume) the study and write every output; returns the summary table.

    ``study`` reuses already compiled functions (tests); it must have been built from ``cfg``.
    ``progress`` False turns the progress bar off (``--no-progress``). ``command``: the command
    line that ran it (recorded in ``maze_config.json`` for provenance).
    """
    cfg.validate()
    require_folder(out, "--out")
    require_folder(work, "--work")
    resolved = config_dict(cfg)
    config_path = out / "maze_config.json"
    if not force and all((out / p).exists() for p in outputs(cfg)):
        if read_json(config_path, {}).get("config") == resolved:
            print(f"maze study: outputs in {out} are up to date with this config; skipping "
                  "(--force to rerun)")
            return pd.read_csv(out / "tables/maze_summary.csv")

    def digest(d: dict) -> str:
        return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()[:12]

    # Each stage is keyed by what it depends on, so changing one stage's settings reuses the
    # others (e.g. the trained experts).
    later = ("bc", "baselines", "dagger", "mixed", "plateau_tol", "lanes")
    shared = {k: v for k, v in resolved.items()
              if not k.startswith(later) and not k.endswith("_updates")}
    stage_dirs = {name: work / digest({**shared, "updates": resolved[f"{name}_updates"]})
                  for name in ("rl_full", "rl_partial")}
    bc = {"bc": resolved["bc"], "bc_chunk_epochs": cfg.bc_chunk_epochs}
    full = {**shared, "rl_full_updates": cfg.rl_full_updates}
    stage_dirs.update({c: work / digest({**shared, f"{BC_CURVES[c][0]}_updates": resolved[
        f"{BC_CURVES[c][0]}_updates"], **bc}) for c in BC_CURVES})
    stage_dirs["dagger"] = work / digest({**full, "dagger": resolved["dagger"]})
    for name in extended.MIXED_CURVES:
        stage_dirs[name] = work / digest({**full, "mixed": resolved["mixed"], "curve": name,
                                          "mixed_updates": cfg.mixed_updates})
    study = study or Study(cfg)
    parts = seed_parts(cfg)
    mixed_ticks = cfg.mixed_updates // cfg.chunk_updates
    ticks = {"rl_full": cfg.rl_full_updates // cfg.chunk_updates,
             "rl_partial": cfg.rl_partial_updates // cfg.chunk_updates,
             **dict.fromkeys(BC_CURVES, cfg.bc.epochs // cfg.bc_chunk_epochs)}
    if cfg.baselines:
        ticks.update(dagger=cfg.dagger.iterations, **dict.fromkeys(extended.MIXED_CURVES,
                                                                   mixed_ticks))
    t_start, cpu_start = time.perf_counter(), time.process_time()
    with tqdm(total=sum(ticks.values()) * len(parts), desc="maze study", unit="chunk",
              dynamic_ncols=True, disable=not progress) as bar:

        results: dict = {}  # (stage, part) -> its result
        cached_parts = {(n, k) for n in ticks for k, part in enumerate(parts)
                        if _part_path(stage_dirs[n], n, part).exists()}
        if len(cached_parts) < len(ticks) * len(parts):  # something to train: compile first
            for rows in sorted({len(p) for p in parts}):
                study.warm(rows, cfg.lanes)

        def stage(name: str, inputs: tuple[str, ...], fn) -> list[Job]:
            jobs = []
            for k, part in enumerate(parts):
                def cached(_echo: bool, k=k, part=part):
                    experts = {n: results[n, k]["params"] for n in inputs}
                    out, hit = _cached(_part_path(stage_dirs[name], name, part),
                                       lambda: fn(experts, part))
                    bar.update(ticks[name] if hit else 0)
                    results[name, k] = out
                jobs.append(Job(f"{name}@{k}", cached, tuple(f"{n}@{k}" for n in inputs)))
            return jobs

        # the first ready stage in this order starts in the first free lane: the longest first
        jobs = [*stage("rl_partial", (), lambda _, p: run_rl(study, "rl_partial", True, bar,
                                                             seeds=p)),
                *stage("rl_full", (), lambda _, p: run_rl(study, "rl_full", False, bar,
                                                          seeds=p))]
        for c in BC_CURVES:
            jobs += stage(c, (BC_CURVES[c][0],), lambda e, p, c=c: run_bc(study, e, bar, (c,), p))
        if cfg.baselines:
            for name in extended.MIXED_CURVES:
                jobs += stage(name, ("rl_full",), lambda e, p, name=name: extended.run_mixed(
                    study, e, bar, (name,), p))
            jobs += stage("dagger", ("rl_full",),
                          lambda e, p: extended.run_dagger(study, e, bar, p))
        run_jobs(jobs, cfg.lanes)
    wall, cpu = time.perf_counter() - t_start, time.process_time() - cpu_start
    order = ["rl_full", "rl_partial", *BC_CURVES, "dagger", *extended.MIXED_CURVES]
    weights = [len(p) for p in parts]
    merged = {n: _merge([results[n, k] for k in range(len(parts))], weights)
              for n in order if (n, 0) in results}
    curves = pd.DataFrame([r for n in order if n in merged for r in merged[n]["records"]])
    curves = curves.assign(_order=pd.factorize(curves.curve)[0]).sort_values(
        ["_order", "progress", "seed"], kind="stable").drop(columns="_order").reset_index(
        drop=True)
    summary = report.summarise(curves)
    refs = reference_returns(study.params)
    start = extended.plateau_start(cfg.ppo.anneal_lr)
    plateaus = {n: extended.plateau(curves, n, cfg.plateau_tol, opt, start) for n, opt in (
        ("rl_full", refs["oracle_full"][0]), ("rl_partial", None))}
    converged = {n: p["converged"] for n, p in plateaus.items()}
    timings = {f"{n}_s": r["seconds"] for n, r in merged.items()}
    compiled = study.compiled()
    timings.update(compile_s=study.compile_seconds(), this_invocation_wall_s=wall,
                   this_invocation_cpu_s=cpu)
    status = "; ".join(
        f"{n}: {'converged' if p['converged'] else 'NOT converged'} (rose "
        f"{p['rise']:.2f} +- {p['rise_ci95']:.2f} (95% CI over seeds) over the last quarter of "
        f"learning, from {p['since']:.0%} of the "
        f"updates; criterion < {p['tol']}"
        + (", within 2% of the exact optimum)" if p.get("at_optimum") else ")")
        + f" after {getattr(cfg, n + '_updates')} updates, "
        f"{getattr(cfg, n + '_updates') * cfg.ppo.steps_per_update:,} env steps per seed"
        for n, p in plateaus.items())
    note = (f"{cfg.seeds} seeds, GRU-{cfg.hidden}; PPO lr {cfg.ppo.lr}, "
            f"{cfg.rl_full_updates * cfg.ppo.steps_per_update:,} (full) / "
            f"{cfg.rl_partial_updates * cfg.ppo.steps_per_update:,} (partial) env steps per seed;"
            f" BC {cfg.bc.epochs} epochs on {cfg.bc.dataset_size:,} expert transitions per seed. "
            + (f"DAgger {cfg.dagger.iterations} x {cfg.dagger.steps_per_collection:,} "
               f"transitions; BC+PPO (w_BC {cfg.mixed.w_bc}, w_RL {cfg.mixed.w_rl}) and ADVISOR "
               f"(alpha {cfg.mixed.alpha}) {cfg.mixed_updates * cfg.ppo.steps_per_update:,} env "
               "steps per seed. " if cfg.baselines else "")
            + f"Plateau test: {status}. Stage seconds (summed over {len(parts)} seed parts, "
            "compile excluded): "
            + ", ".join(f"{k} {v:.0f}" for k, v in timings.items()))
    atomic_write_csv(out / "figures/fig2_maze.csv", curves)
    atomic_write_csv(out / "tables/maze_summary.csv", summary)
    atomic_write_text(out / "tables/maze_summary.md", report.summary_markdown(summary, refs, note))
    atomic_write_text(out / "tables/maze_summary.tex", report.summary_latex(summary, refs))
    report.plot(curves, summary, refs, out / "figures/fig2_maze", converged)
    if cfg.baselines:
        extended.plot_baselines(curves, summary, refs, plateaus["rl_partial"],
                                out / "figures/fig2b_maze_baselines")
    save_frames(out / "figures/maze_frames.png")
    meta = {"config": resolved, "references": {k: list(v) for k, v in refs.items()},
            "timings_s": timings, "compiled_programs": compiled, "plateau": plateaus,
            "bc_loss_per_chunk": np.stack([np.asarray(merged[c]["losses"])[:, 0]
                                           for c in BC_CURVES], 1).tolist(),
            "baseline_metrics": {n: merged[n]["metrics"] for n in order[5:] if n in merged},
            "jax": jax.__version__, "device": str(jax.devices()[0]),
            # what provenance records of this run (igdrivsim.report.provenance maze)
            "code": code_state(), "machine": {**machine_record(), "command": command,
                                              "cpu": cpu_text()}}
    atomic_write_json(config_path, meta, indent=2)
    print(summary.to_string(index=False))
    print(f"maze study: {status}")
    print("maze study: compiled " + ", ".join(f"{n} x{c}" for n, c in compiled.items())
          + f" ({timings['compile_s']:.0f} s)")
    print(f"maze study: wrote {', '.join(outputs(cfg))} under {out} ({wall:.0f} s wall, "
          f"{cpu:.0f} s CPU)")
    return summary


def replot(out: Path) -> list[Path]:
    """Redraw Fig. 2 (and Fig. 2b when the curves hold the baselines) under ``out`` from the
    study's curves and config, as :func:`run_study` draws them; the written paths."""
    csv, config = out / "figures" / "fig2_maze.csv", out / "maze_config.json"
    for path in (csv, config):
        if not path.is_file():
            raise DataError("missing: run the maze study first", file=str(path))
    curves = pd.read_csv(csv)
    meta = read_json(config)
    refs = {k: tuple(v) for k, v in meta["references"].items()}
    plateaus = meta.get("plateau", {})
    summary = report.summarise(curves)
    report.plot(curves, summary, refs, out / "figures/fig2_maze",
                {n: bool(p["converged"]) for n, p in plateaus.items()})
    stems = ["fig2_maze"]
    if set(extended.EXTENDED) & set(curves.curve):
        extended.plot_baselines(curves, summary, refs, plateaus.get("rl_partial", {}),
                                out / "figures/fig2b_maze_baselines")
        stems.append("fig2b_maze_baselines")
    return [out / "figures" / f"{stem}.{ext}" for stem in stems for ext in ("pdf", "png")]


def study_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--profile", choices=sorted(PROFILES), default="default",
                        help="named study configuration")
    parser.add_argument("--seeds", type=int, default=None, help="seeds per curve (default 10)")
    parser.add_argument("--seed", type=int, default=None, help="base PRNG seed")
    parser.add_argument("--hidden", type=int, default=None,
                        help=f"GRU width (default {StudyConfig.hidden})")
    parser.add_argument("--out", type=Path, default=Path("outputs/maze"),
                        help="output directory (`--out paper` writes the report's figures "
                             "and tables in place)")
    parser.add_argument("--work", type=Path, default=Path("runs/maze"),
                        help="stage cache (resume) directory")
    parser.add_argument("--force", action="store_true", help="rerun even if outputs are current")
    parser.add_argument("--no-baselines", dest="baselines", action="store_false", default=None,
                        help="only the paper's five curves (skip DAgger, BC+PPO, ADVISOR)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--no-compile-cache", dest="compile_cache", action="store_false",
                        help="compile every program (default: reuse those in WORK/xla-cache, "
                             "JAX's persistent compilation cache)")


def resolve(args: argparse.Namespace) -> StudyConfig:
    cfg = PROFILES[args.profile]
    overrides = {k: getattr(args, k) for k in ("seeds", "seed", "hidden", "baselines")
                 if getattr(args, k) is not None}
    return dataclasses.replace(cfg, **overrides)


def study_command(args: argparse.Namespace) -> int:
    if getattr(args, "replot", False):
        for path in replot(args.out):
            print(f"wrote {path}")
        return 0
    if args.compile_cache:
        use_compile_cache(args.work / "xla-cache")
    run_study(resolve(args), args.out, args.work, args.force, progress=not args.no_progress,
              command=command_text("python -m maze.study", args.argv))
    return 0


def command_text(prog: str, argv: list[str] | None) -> str:
    """The command line ``prog ARGV...`` (``sys.argv`` when ``argv`` is None), quoted."""
    argv = sys.argv[1:] if argv is None else argv
    return " ".join([prog, *(shlex.quote(str(a)) for a in argv)])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m maze.study", description=__doc__.split(
        "\n")[0], formatter_class=DefaultsFormatter)
    study_arguments(parser)
    parser.add_argument("--replot", action="store_true",
                        help="only redraw Fig. 2 and 2b from OUT's figures/fig2_maze.csv and "
                             "maze_config.json (no training)")
    args = parser.parse_args(argv)
    args.argv = argv
    return run_command("maze study", study_command, args)


if __name__ == "__main__":
    sys.exit(main())
