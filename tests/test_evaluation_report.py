"""Aggregation, Table I, vs-paper table and Fig. 3 on fabricated tidy CSVs (test-only data)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from igdrivsim.errors import DataError
from igdrivsim.evaluation import aggregate
from igdrivsim.evaluation.schema import PER_SCENARIO_COLUMNS, PER_STEP_COLUMNS, REFERENCE_SETTING
from igdrivsim.names import SETTINGS
from igdrivsim.report import tables
from igdrivsim.report.build import Provenance, build_report

N_SCENARIOS, SEEDS = 40, (0, 1, 2)


def fabricate(tmp_path, better_setting="circular_r4", effect=0.3):
    """Write fake per_scenario/per_step CSVs: BC-RL clearly safer in ``better_setting`` only."""
    rng = np.random.default_rng(1)
    base = rng.uniform(0, 1, N_SCENARIOS)  # shared scenario difficulty (pairing matters)
    scen, steps = [], []
    for setting in SETTINGS:
        for method in ("bc", "bc_rl"):
            for seed in SEEDS:
                shift = -effect if (method == "bc_rl" and setting == better_setting) else 0.0
                noise = rng.normal(0, 0.02, N_SCENARIOS)
                frac = np.clip(base * 0.5 + shift * 0.5 + noise, 0, 1)
                for i in range(N_SCENARIOS):
                    scen.append(dict(setting=setting, method=method, seed=seed,
                                     scenario_id=f"s{i:03d}", max_log_divergence=3 * frac[i] + 1,
                                     overlap=float(frac[i] > 0.3), offroad=float(frac[i] > 0.4),
                                     log_divergence=frac[i] + 0.5, overlap_steps=frac[i] / 2,
                                     offroad_steps=frac[i] / 3))
                for t in range(80):
                    steps.append(dict(setting=setting, method=method, seed=seed, step=t,
                                      log_divergence=t / 80, overlap=0.1, offroad=0.05))
    for method in ("expert", "constant_velocity"):
        for i in range(N_SCENARIOS):
            scen.append(dict(setting=REFERENCE_SETTING, method=method, seed=0,
                             scenario_id=f"s{i:03d}", max_log_divergence=0.05, overlap=0.0,
                             offroad=0.0, log_divergence=0.04, overlap_steps=0.0,
                             offroad_steps=0.0))
    root = tmp_path / "eval"
    (root / "runA").mkdir(parents=True)
    frame = pd.DataFrame(scen)[list(PER_SCENARIO_COLUMNS)]
    half = len(frame) // 2  # split over two run folders: load_evaluations must find both
    frame.iloc[:half].to_csv(root / "per_scenario.csv", index=False)
    frame.iloc[half:].to_csv(root / "runA" / "per_scenario.csv", index=False)
    pd.DataFrame(steps)[list(PER_STEP_COLUMNS)].to_csv(root / "runA" / "per_step.csv",
                                                       index=False)
    return root


def test_t_interval_matches_textbook():
    mean, low, high = aggregate.t_interval(np.array([1.0, 2.0, 3.0]))
    assert mean == pytest.approx(2.0)
    assert high - mean == pytest.approx(4.302653 * 1.0 / np.sqrt(3), rel=1e-5)
    assert np.isnan(aggregate.t_interval(np.array([5.0]))[1])


def test_summary_and_tests(tmp_path):
    _, per_scenario = aggregate.load_evaluations([fabricate(tmp_path)])
    summary = aggregate.summarize(per_scenario)
    row = summary[(summary.metric == "overlap") & (summary.setting == "full")
                  & (summary.method == "bc")].iloc[0]
    assert row.n_seeds == 3 and row.n_scenarios == N_SCENARIOS
    assert row.ci_low < row["mean"] < row.ci_high
    tests = aggregate.compare_methods(per_scenario)
    assert len(tests) == 6 * 6 and (tests.method == "bc_rl").all()
    assert (tests.p_holm >= tests.p_value).all()
    good = tests[tests.setting == "circular_r4"]
    assert good.significant.all() and (good.better == "bc_rl").all()
    assert not tests[tests.setting == "full"].significant.any()


def test_load_rejects_bad_csv(tmp_path):
    (tmp_path / "per_scenario.csv").write_text("setting,method\nfull,bc\n")
    with pytest.raises(DataError, match="missing columns"):
        aggregate.load_evaluations([tmp_path])
    with pytest.raises(DataError, match="does not exist"):
        aggregate.load_evaluations([tmp_path / "absent"])
    (tmp_path / "empty").mkdir()
    with pytest.raises(DataError, match="no per_scenario.csv"):
        aggregate.load_evaluations([tmp_path / "empty"])


def test_build_report_outputs(tmp_path):
    root = fabricate(tmp_path)
    out = tmp_path / "paper"
    build_report([root], out, Provenance(profile="smoke", data="synthetic_test"))
    tex = (out / "tables" / "table1.tex").read_text()
    assert tex.count(r"\midrule") == 6 and r"\begin{tabular}{lcccccc}" in tex
    for label in ("Full obs", "Gaussian", "Circular", "Conic FoV", "Random"):
        assert label in tex
    assert r"\textbf{" in tex and "bootstrap" in tex and "Holm" in tex and r"\multicolumn{6}" in tex
    md = (out / "tables" / "table1.md").read_text()
    assert "Circ r=4**: yes" in md and "Full**: no significant difference" in md
    assert "BC-RL − BC (95% bootstrap interval" in md and "minimum detectable" in md.lower()
    power = (out / "tables" / "power.md").read_text()
    assert power.count("| MDE (α=0.05) |") == 6
    power_tex = (out / "tables" / "power.tex").read_text()
    assert r"\label{tab:power}" in power_tex and power_tex.count(r"\midrule") == 6
    vs = (out / "tables" / "vs_paper.md").read_text()
    assert "| Full |" in vs and "3.67" in vs
    prov = (out / "generated" / "provenance.tex").read_text()
    assert r"\newcommand{\ProvProfile}{smoke}" in prov and r"synthetic\_test" in prov
    verdicts = (out / "generated" / "verdicts.tex").read_text()
    assert verdicts.count(r"\item") == 6 and "Circular FoV (r=4)" in verdicts
    from PIL import Image

    with Image.open(out / "figures" / "fig3_metrics.png") as im:
        assert im.size[0] > 300
    assert (out / "figures" / "fig3_metrics.pdf").read_bytes().startswith(b"%PDF")
    # Rerun: tables identical.
    before = {p.name: p.read_bytes() for p in (out / "tables").glob("*") if p.suffix != ".tex"
              or p.name == "table1.tex"}
    build_report([root], out, Provenance(profile="smoke", data="synthetic_test"))
    after = {name: (out / "tables" / name).read_bytes() for name in before}
    assert before == after


def test_verdict_says_bc_safer_when_it_is(tmp_path):
    _, per_scenario = aggregate.load_evaluations([fabricate(tmp_path, "full", effect=-0.3)])
    verdicts = tables.safety_verdicts(aggregate.compare_methods(per_scenario))
    assert verdicts["full"].startswith("no (BC is safer)")


def test_compare_states_how_two_runs_conclusions_differ(tmp_path):
    """The comparison of two report folders reads each run's BC order, the gap to Full and
    BC-RL - BC from its own tables; a folder without them is a one-line error."""
    import pandas as pd
    import pytest

    from igdrivsim.errors import ConfigError
    from igdrivsim.report.compare import compare_markdown

    def write(folder, offroad):
        folder.mkdir()
        rows = [("offroad", s, "bc", v) for s, v in offroad.items()]
        rows += [(m, s, "bc", 1.0) for m in ("log_divergence", "overlap") for s in offroad]
        rows += [(m, "none", "constant_velocity", 9.0)
                 for m in ("log_divergence", "offroad", "overlap")]
        pd.DataFrame(rows, columns=["metric", "setting", "method", "mean"]).to_csv(
            folder / "summary.csv", index=False)
        pd.DataFrame([("bc_rl", "offroad", s, -1.5, True, 1.0) for s in offroad],
                     columns=["method", "metric", "setting", "diff", "significant", "mde"]
                     ).to_csv(folder / "tests.csv", index=False)
        return folder

    old = write(tmp_path / "old", {"full": 2.0, "circular_r4": 5.0})
    new = write(tmp_path / "new", {"full": 2.0, "circular_r4": 1.0})
    text = compare_markdown(old, new)
    offroad = text.split("## offroad")[1].split("##")[0]
    assert "| BC, best to worst | Full < Circ r=4 | Circ r=4 < Full |" in offroad
    assert "| BC gap to Full | Circ r=4 +3.00 | Circ r=4 -1.00 |" in offroad
    assert "Circ r=4 -1.50* (1.00)" in offroad
    with pytest.raises(ConfigError, match="expected summary.csv"):
        compare_markdown(tmp_path, new)
