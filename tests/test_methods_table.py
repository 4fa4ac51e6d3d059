"""Table II (every learned method vs BC) and Fig. 6 on fabricated tidy CSVs (test-only data)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from igdrivsim.evaluation import aggregate
from igdrivsim.evaluation.schema import METRICS, PER_SCENARIO_COLUMNS, REFERENCE_SETTING
from igdrivsim.report import methods_table
from igdrivsim.report.build import Provenance, build_report

N_SCENARIOS, SEEDS = 20, (0, 1, 2)
PARTIAL = "circular_r6"
BETTER, BETTER_METRIC = "advisor", "log_divergence"  # far lower than BC in PARTIAL


def fabricate(extended: bool = True) -> pd.DataFrame:
    """bc and bc_rl in ``full`` and PARTIAL; dagger and advisor (``extended``) in PARTIAL only,
    advisor's log divergence 0.5 m below BC's; the two references with setting "none"."""
    rng = np.random.default_rng(3)
    base = rng.uniform(0, 1, N_SCENARIOS)  # shared scenario difficulty
    runs = [(s, m) for s in ("full", PARTIAL) for m in ("bc", "bc_rl")]
    if extended:
        runs += [(PARTIAL, "dagger"), (PARTIAL, "advisor")]
    rows = []
    for setting, method in runs:
        for seed in SEEDS:
            frac = np.clip(base * 0.5 + rng.normal(0, 0.02, N_SCENARIOS), 0, 1)
            shift = -0.5 if method == BETTER else 0.0
            for i in range(N_SCENARIOS):
                rows.append(dict(setting=setting, method=method, seed=seed,
                                 scenario_id=f"s{i:03d}", max_log_divergence=3 * frac[i] + 1,
                                 overlap=float(frac[i] > 0.3), offroad=float(frac[i] > 0.4),
                                 log_divergence=frac[i] + 1.0 + shift,
                                 overlap_steps=frac[i] / 2, offroad_steps=frac[i] / 3))
    for method in ("expert", "constant_velocity"):
        for i in range(N_SCENARIOS):
            rows.append(dict(setting=REFERENCE_SETTING, method=method, seed=0,
                             scenario_id=f"s{i:03d}", max_log_divergence=0.05, overlap=0.0,
                             offroad=0.0, log_divergence=0.04, overlap_steps=0.0,
                             offroad_steps=0.0))
    return pd.DataFrame(rows)[list(PER_SCENARIO_COLUMNS)]


def write_evals(tmp_path, frame: pd.DataFrame):
    """The evaluation folder layout load_evaluations reads: a per_scenario.csv per run."""
    root = tmp_path / "evals"
    for (setting, method), part in frame.groupby(["setting", "method"]):
        folder = root / f"{method}_{setting}"
        folder.mkdir(parents=True)
        part.to_csv(folder / "per_scenario.csv", index=False)
    return root


def _table_rows(md: str) -> list[list[str]]:
    return [[c.strip() for c in line.strip("|").split("|")] for line in md.splitlines()
            if line.startswith("| ") and not line.startswith("| metric")]


@pytest.fixture(scope="module")
def compared():
    per_scenario = fabricate()
    return per_scenario, aggregate.summarize(per_scenario), methods_table.compare_all(
        per_scenario)


def test_method_order_and_fallback_label(compared):
    per_scenario, _, _ = compared
    assert methods_table.learned_methods(per_scenario)[:2] == ["bc", "bc_rl"]
    assert set(methods_table.extended_methods(per_scenario)) == {"dagger", "advisor"}
    assert methods_table.extended_methods(fabricate(extended=False)) == []
    assert methods_table.method_label("bc_rl") == "BC-RL"
    assert methods_table.method_label("no_such_method") == "no_such_method"
    colours = methods_table.method_colours(["bc", "no_such_method"])
    assert colours["bc"] == "#4C9BE8" and colours["no_such_method"] == "C2"


def test_table2_markdown(compared):
    _, summary, tests = compared
    md = methods_table.table2_markdown(summary, tests, "header line")
    assert "header line" in md
    rows = _table_rows(md)
    for method in ("bc", "bc_rl", "dagger", "advisor"):
        label = methods_table.method_label(method)
        mine = [r for r in rows if r[1] == label]
        assert len(mine) == len(METRICS)  # one row per method and metric
        if method in ("dagger", "advisor"):  # columns: full, then the partial setting
            assert all(r[2] == "--" for r in mine) and all(r[3] != "--" for r in mine)
    # Holm over all of Table II's comparison cells: bc_rl 2 settings, the others 1, 6 metrics.
    assert len(tests) == (2 + 1 + 1) * len(METRICS)
    assert f"over the table's {len(tests)} comparison cells" in md
    np.testing.assert_allclose(tests.p_holm, aggregate.holm_adjust(tests.p_value))
    good = tests[(tests.method == BETTER) & (tests.metric == BETTER_METRIC)].iloc[0]
    assert good.significant and good.ci_high < 0 and good.better == BETTER
    name = [r for r in rows if r[1] == methods_table.method_label(BETTER)
            and r[0].startswith("log divergence")][0]
    cell = name[3]
    assert cell.startswith("**") and cell.endswith("**") and "Δ -0.5" in cell or "Δ -0.4" in cell
    low, high = (float(x) for x in cell.split("[")[1].split("]")[0].split(","))
    assert low < high < 0  # the interval excludes 0


def test_table2_latex(compared):
    _, summary, tests = compared
    tex = methods_table.table2_latex(summary, tests, "extra caption")
    assert r"\label{tab:methods}" in tex and r"\begin{tabular}{llcc}" in tex
    assert tex.count(r"\midrule") == len(METRICS) and r"\resizebox{\textwidth}" in tex
    assert "Full obs" in tex and "Circular" in tex and "extra caption" in tex
    assert r"\textbf{$-$0.5" in tex or r"\textbf{$-$0.4" in tex
    assert f"{len(tests)} comparison cells" in tex
    assert tex.count(r"$\Delta$ vs BC") == 3 * len(METRICS)
    assert r"\multicolumn{2}{c}" in tex  # reference rows span the settings


def test_build_report_writes_table2_only_with_extended_methods(tmp_path):
    out = tmp_path / "paper"
    written = build_report([write_evals(tmp_path / "ext", fabricate())], out,
                           Provenance(profile="smoke", data="synthetic_test"), run_dirs=[])
    tables, figures = out / "tables", out / "figures"
    for path in (tables / "table2.md", tables / "table2.tex", tables / "tests_all.csv",
                 figures / "fig6_methods.pdf", figures / "fig6_methods.png"):
        assert path in written and path.is_file()
    assert (figures / "fig6_methods.pdf").read_bytes().startswith(b"%PDF")
    table1_tests = pd.read_csv(tables / "tests.csv")
    assert set(table1_tests.method) == {"bc_rl"}  # Table I: BC-RL vs BC only
    np.testing.assert_allclose(table1_tests.p_holm,
                               aggregate.holm_adjust(table1_tests.p_value), atol=1e-6)
    all_tests = pd.read_csv(tables / "tests_all.csv")
    assert set(all_tests.method) == {"bc_rl", "dagger", "advisor"}
    dagger = methods_table.method_label("dagger")  # "dagger" until it is registered
    assert f"| log divergence (m) | {dagger} |" in (tables / "table2.md").read_text()

    plain = tmp_path / "plain_paper"
    written = build_report([write_evals(tmp_path / "plain", fabricate(extended=False))], plain,
                           Provenance(profile="smoke", data="synthetic_test"), run_dirs=[])
    assert not any("table2" in p.name or "fig6" in p.name or "tests_all" in p.name
                   for p in written)
    assert not (plain / "tables" / "table2.md").exists()
    assert not (plain / "figures" / "fig6_methods.png").exists()
    assert set(pd.read_csv(plain / "tables" / "tests.csv").method) == {"bc_rl"}
    # a plain report over an extended one's folder leaves no Table II of the earlier run
    build_report([tmp_path / "plain" / "evals"], out,
                 Provenance(profile="smoke", data="synthetic_test"), run_dirs=[])
    assert not (tables / "table2.md").exists() and not (figures / "fig6_methods.png").exists()
    assert (tables / "table1.md").is_file()
