"""Do drivers trained on a synthetic motion model hold up on real logs? The table of
``scripts/transfer_check.sh`` (``igdrivsim report transfer WORK``, evaluations under
``WORK/<motion>/evals_<data set>/``): Full BC against constant velocity, the motion models'
BC against each other, and every driver against the references ego by ego."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from igdrivsim.errors import ConfigError
from igdrivsim.evaluation.aggregate import (
    complete_scenarios,
    load_evaluations,
    paired_difference,
    scenario_cube,
)
from igdrivsim.evaluation.paired import SOURCE_COLUMN, compare_on_egos, source_map
from igdrivsim.evaluation.schema import (
    EVAL_CONFIG,
    METRIC_BY_KEY,
    PER_SCENARIO_FILE,
    STEP_METRICS,
    table_settings,
)
from igdrivsim.io import read_json
from igdrivsim.machine import code_label, code_state
from igdrivsim.names import BC, CONSTANT_VELOCITY, METHOD_LABELS, REFERENCES, setting_short
from igdrivsim.report.real_logs import PAIRED_HEAD, PAIRED_REFERENCES, paired_cells
from igdrivsim.report.tables import md_head, md_row

METRICS = tuple(METRIC_BY_KEY[k] for k in STEP_METRICS)
FULL = "full"  # the observation setting of the first table's BC
VALIDATION = "validation"  # the synthetic validation set's name (evals_validation)
POOLED = "real, pooled"  # every real set of a motion model together


def evaluations(work: Path) -> dict[tuple[str, str], pd.DataFrame]:
    """``{(data set, motion): per-scenario rows}`` under ``work``."""
    found = {}
    for folder in sorted(work.glob("*/evals_*")):
        if all((folder / run / PER_SCENARIO_FILE).is_file() for run in (BC, "references")):
            others = [p.parent for p in sorted(folder.glob(f"*/{PER_SCENARIO_FILE}"))
                      if p.parent.name not in (BC, "references")]
            _, per_scenario = load_evaluations([folder / BC, folder / "references", *others])
            found[(folder.name.removeprefix("evals_"), folder.parent.name)] = per_scenario
    if not found:
        raise ConfigError(f"no evals_*/{{bc,references}}/per_scenario.csv under {work}/*/: "
                          "run bash scripts/transfer_check.sh first")
    return found | pooled(found)


def pooled(found: dict[tuple[str, str], pd.DataFrame]) -> dict[tuple[str, str], pd.DataFrame]:
    """``{(POOLED, motion): every real set of that motion}`` where it has several."""
    out = {}
    for motion in sorted({m for _, m in found}):
        real = [f.assign(scenario_id=d + "/" + f.scenario_id, **(
                    {SOURCE_COLUMN: d + "/" + f[SOURCE_COLUMN].astype(str)}
                    if SOURCE_COLUMN in f else {}))
                for (d, m), f in sorted(found.items()) if m == motion and d != VALIDATION]
        if len(real) > 1:
            out[(POOLED, motion)] = pd.concat(real, ignore_index=True)
    return out


def _in_order(found: dict) -> list:
    """``found``'s items, validation first, the pooled real sets last."""
    order = {VALIDATION: 0, POOLED: 2}
    return sorted(found.items(), key=lambda kv: (order.get(kv[0][0], 1), kv[0]))


def _paired(a: pd.DataFrame, method_a: str, b: pd.DataFrame, method_b: str, scen,
            **row) -> dict:
    """``row`` with each metric's paired difference of ``method_a`` in ``a`` minus
    ``method_b`` in ``b`` on the scenarios ``scen`` (clustered by ``a``'s source scenarios)."""
    source = source_map(a)
    c = paired_difference(scenario_cube(a, method_a, scen, METRICS),
                          scenario_cube(b, method_b, scen, METRICS),
                          clusters=[source[str(s)] for s in scen])
    return row | {f"{m.key}_{k}": float(v[i]) for i, m in enumerate(METRICS) for k, v in c.items()}


def against_constant_velocity(found: dict) -> pd.DataFrame:
    """One row per (data set, motion): BC against constant velocity."""
    rows = []
    for (data, motion), frame in _in_order(found):
        frame = frame[(frame.method != BC) | (frame.setting == FULL)]  # Full BC
        scen = complete_scenarios(frame, (BC, CONSTANT_VELOCITY))
        rows.append(_paired(frame, BC, frame, CONSTANT_VELOCITY, scen, data=data, motion=motion,
                            n=len(scen), seeds=frame[frame.method == BC].seed.nunique()))
    return pd.DataFrame(rows)


def ego_by_ego(found: dict) -> pd.DataFrame:
    """Every learned driver against each reference, ego by ego."""
    rows = []
    for (data, motion), frame in _in_order(found):
        learned = frame.loc[~frame.method.isin(REFERENCES), ["setting", "method"]]
        order = {s: i for i, s in enumerate(table_settings(learned))}  # Table I's order
        for setting, method in sorted(set(map(tuple, learned.to_numpy())),
                                      key=lambda sm: (order.get(sm[0], len(order)), sm)):
            for reference in PAIRED_REFERENCES.values():
                c = compare_on_egos(frame, setting, method, reference)
                if c["n_egos"]:
                    rows.append(dict(data=data, motion=motion, setting=setting, method=method,
                                     reference=reference, egos=c["n_egos"],
                                     sources=c["n_sources"]) | c)
    return pd.DataFrame(rows)


def between_motions(found: dict) -> pd.DataFrame:
    """On each real set, BC of each motion against BC of the first."""
    rows = []
    for data in sorted({d for d, _ in found} - {VALIDATION, POOLED}) + [POOLED]:
        motions = sorted(m for d, m in found if d == data)
        if len(motions) < 2:
            continue
        frames = {m: found[(data, m)] for m in motions}
        frames = {m: f[(f.method == BC) & (f.setting == FULL)] for m, f in frames.items()}
        for motion in motions[1:]:
            a, b = frames[motion], frames[motions[0]]
            scen = complete_scenarios(a, (BC,)).intersection(complete_scenarios(b, (BC,)))
            rows.append(_paired(a, BC, b, BC, scen, data=data, motion=motion,
                                baseline=motions[0], n=len(scen)))
    return pd.DataFrame(rows)


def _diff(row: pd.Series, key: str) -> str:
    return (f"{row[f'{key}_diff']:+.2f} [{row[f'{key}_lo']:+.2f}, {row[f'{key}_hi']:+.2f}] "
            f"p={row[f'{key}_p']:.2f}, MDE {row[f'{key}_mde']:.2f}")


def code_lines(work: Path) -> list[str]:
    """Per motion folder, the code behind its BC run and its evaluations."""

    def label(code) -> str:
        return code_label(code) if isinstance(code, dict) else "unknown"

    lines = []
    for folder in sorted(p for p in work.iterdir() if any(p.glob(f"evals_*/{BC}"))):
        records = [read_json(f, {}) for f in sorted(folder.glob(f"evals_*/*/{EVAL_CONFIG}"))]
        evaluated = sorted({label(r.get("code")) for r in records})
        runs = [r["trained"] for r in records if isinstance(r.get("trained"), dict)]
        trained = sorted({label(r.get("code")) for r in runs}) or ["unknown"]
        scenarios = sorted({r["num_scenarios"] for r in runs if r.get("num_scenarios")})
        trained_on = f"{scenarios[0]:,} training scenarios; " if len(scenarios) == 1 else ""
        lines.append(f"- {folder.name}: {trained_on}trained at {', '.join(trained)}; "
                     f"evaluated at {', '.join(evaluated) or 'unknown'}")
    return lines


def markdown(vs_cv: pd.DataFrame, motions: pd.DataFrame, code: list[str],
             egos: pd.DataFrame) -> str:
    lines = [
        "# Full BC trained on each synthetic motion model, against constant velocity",
        "",
        "Written by `bash scripts/transfer_check.sh WORK MOTION` "
        "(`igdrivsim report transfer`). Laptop profile, 3 seeds, 1,000 updates. "
        "Means are over seeds of each seed's mean over the N scenarios; differences with a "
        "95% hierarchical-bootstrap interval (seeds, then paired scenarios; egos of one source "
        "scenario together), its p-value and "
        "the minimum detectable effect (MDE, 80% power). On the real sets every vehicle that "
        "passes the scenario filter is the ego in turn (N: egos). Log divergence in m, "
        "offroad and overlap in % of steps.",
        "", *md_head("data", "motion", "N", "BC log div.", "CV log div.", "BC / CV",
                     "BC - CV log div.", "BC offroad", "CV offroad", "BC overlap", "CV overlap")]
    lines += [md_row(r.data, r.motion, str(r.n), f"{r.log_divergence_a:.2f}",
                     f"{r.log_divergence_b:.2f}", f"{r.log_divergence_a / r.log_divergence_b:.2f}",
                     _diff(r, "log_divergence"), f"{r.offroad_a:.1f}", f"{r.offroad_b:.1f}",
                     f"{r.overlap_a:.1f}", f"{r.overlap_b:.1f}") for _, r in vs_cv.iterrows()]
    if not motions.empty:
        lines += ["", "BC of one motion model against BC of another, on the same real scenarios:",
                  "", *md_head("data", "motion - baseline", "N", "log divergence (m)",
                               "offroad (%)")]
        lines += [md_row(r.data, f"{r.motion} - {r.baseline}", str(r.n),
                         _diff(r, "log_divergence"), _diff(r, "offroad"))
                  for _, r in motions.iterrows()]
    if not egos.empty:
        lines += ["", "Every driver against constant velocity and the expert, ego by ego (heavy "
                  "tails leave a mean weak): N egos (source scenarios); the share of egos where "
                  "the driver stays closer to the log (over its seeds; a tie counts half); the "
                  "median over egos of its log divergence minus the reference's (m); its mean "
                  "log divergence over the reference's, with the smallest departure from 1 "
                  "detectable at 80% power (MDE). 95% intervals: bootstrap resampling source "
                  "scenarios, then seeds.", "",
                  *md_head("data", "motion", "setting", "method", "against", *PAIRED_HEAD)]
        for _, r in egos.iterrows():
            names = [r.data, r.motion, setting_short(r.setting), METHOD_LABELS.get(
                r.method, r.method), METHOD_LABELS.get(r.reference, r.reference)]
            lines.append(md_row(*names, *paired_cells(r)))
    if code:
        lines += ["", "Each motion model's training set and the code (commit) behind its numbers:",
                  "", *code,
                  f"- this table: written at {code_label(code_state())}"]
    return "\n".join(lines) + "\n"
