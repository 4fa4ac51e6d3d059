"""A sweep of one setting's training variants in one table (``scripts/competence_sweep.sh``):
per variant its overrides, updates, compute relative to the profile's budget and metrics."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from igdrivsim.errors import ConfigError
from igdrivsim.evaluation.schema import PER_SCENARIO_FILE
from igdrivsim.names import CONSTANT_VELOCITY
from igdrivsim.report.tables import md_head, md_row

# the fields a variant's compute per update scales with (and the updates it trained)
_PER_UPDATE = (("data", "batch_size"), ("training", "ppo_epochs"))


def _overrides(config: dict, base: dict) -> list[str]:
    """``section.field=value`` where ``config`` differs from ``base`` (no bookkeeping)."""
    skip = {"log_every", "eval_every", "val_scenarios", "checkpoint_every", "max_checkpoints"}
    return [f"{section}.{key}={value}" for section, fields in config.items()
            if isinstance(fields, dict) for key, value in fields.items()
            if key not in skip and base.get(section, {}).get(key) != value]


def sweep_table(sweep: Path, references: Path | None = None) -> pd.DataFrame:
    """One row per variant of ``sweep`` (see the module docstring)."""
    # lazy: the run reader and the configuration import JAX
    from igdrivsim.training.config import get_profile, to_dict
    from igdrivsim.training.run import Run, is_run

    runs = sorted(p for p in (sweep / "runs").glob("*") if is_run(p))
    if not runs:
        raise ConfigError(f"{sweep}/runs: no trained run found")
    cv = None
    if references is not None:
        ref = pd.read_csv(references / PER_SCENARIO_FILE)
        cv = ref[ref.method == CONSTANT_VELOCITY].set_index("scenario_id")["log_divergence"]
    rows = []
    for path in runs:
        run = Run.open(path)
        saved, base = to_dict(run.config), to_dict(get_profile(run.config.profile))
        scores = sweep / "evals" / path.name / PER_SCENARIO_FILE
        if not scores.exists():
            raise ConfigError(f"{scores}: no evaluation of run {path.name}")
        frame = pd.read_csv(scores)
        seeds = frame.groupby("seed")["log_divergence"].mean()
        planned = run.config.training.num_updates
        # what the evaluation saw: all if done, else the last validated update
        updates = planned if run.complete else max(
            (c.get("update", 0) for c in run.curves() if "log_divergence" in c), default=0)
        compute = updates / base["training"]["num_updates"]
        for section, key in _PER_UPDATE:
            compute *= saved[section][key] / base[section][key]
        row = {"variant": path.name, "overrides": " ".join(_overrides(saved, base)) or "-",
               "updates": updates if updates == planned else f"{updates} of {planned}",
               "compute": round(compute, 2),
               "log_divergence": round(seeds.mean(), 2),
               "seed_range": f"{seeds.min():.2f}-{seeds.max():.2f}",
               "offroad_pct": round(100 * frame["offroad_steps"].mean(), 2),
               "overlap_pct": round(100 * frame["overlap_steps"].mean(), 2),
               "scenarios": frame["scenario_id"].nunique()}
        if cv is not None:
            row["x_constant_velocity"] = round(
                seeds.mean() / cv.reindex(frame["scenario_id"].unique()).mean(), 3)
        rows.append(row)
    return pd.DataFrame(rows).sort_values(["compute", "log_divergence"]).reset_index(drop=True)


def sweep_markdown(sweep: Path, references: Path | None = None) -> str:
    table = sweep_table(sweep, references)
    head = ("Log divergence (m): mean over seeds, and the range of the seed means; offroad and "
            "overlap: % of steps. compute: scenario-episodes trained, relative to the "
            "profile's budget.\n\n")
    rows = [md_row(*map(str, row)) for row in table.itertuples(index=False)]
    return head + "\n".join(md_head(*table.columns) + rows) + "\n"
