"""The real_logs table's ego-by-ego comparisons: every learned driver against constant velocity
and the expert, with N egos and N source scenarios (egos ``<scenario>#<object>``), in the CSV,
the Markdown's second table and the summary sentence; the main table still reads back."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from igdrivsim.report.real_logs import (
    main,
    paired_cells,
    real_log_table,
    real_logs_markdown,
    real_logs_summary,
    table_from_markdown,
)

COLUMNS = dict(overlap_steps=0.0, offroad_steps=0.0, max_log_divergence=9.0, overlap=0,
               offroad=0)


def _frame() -> pd.DataFrame:
    """12 egos from 4 source scenarios; BC (3 seeds) closer to the log than constant velocity
    on the first 9 egos; the expert replays the log."""
    egos = [f"src{i // 3}#{10 + i % 3}" for i in range(12)]
    cv = np.linspace(3.0, 8.0, 12)
    rows = [dict(setting="full", method="bc", seed=s, scenario_id=e,
                 log_divergence=cv[i] + (-1.0 if i < 9 else 2.0) + 0.1 * s, **COLUMNS)
            for s in range(3) for i, e in enumerate(egos)]
    rows += [dict(setting="none", method="constant_velocity", seed=0, scenario_id=e,
                  log_divergence=cv[i], **COLUMNS) for i, e in enumerate(egos)]
    rows += [dict(setting="none", method="expert", seed=0, scenario_id=e, log_divergence=0.02,
                  **COLUMNS) for e in egos]
    return pd.DataFrame(rows)


def test_each_driver_is_compared_ego_by_ego_with_cv_and_the_expert(tmp_path):
    table = real_log_table(_frame()).set_index("method")
    bc = table.loc["bc"]
    assert bc.real_n == 12 and bc.real_sources == 4
    assert bc.real_vs_cv_egos == 12 and bc.real_vs_cv_sources == 4
    assert bc.real_vs_cv_win == pytest.approx(0.75)
    assert bc.real_vs_cv_win_lo <= 0.75 <= bc.real_vs_cv_win_hi
    assert bc.real_vs_cv_median == pytest.approx(-0.9)  # 9 of 12 egos at -1 + 0.1
    assert bc.real_vs_cv_ratio_lo <= bc.real_vs_cv_ratio <= bc.real_vs_cv_ratio_hi
    assert bc.real_vs_cv_ratio_mde > 0
    assert bc.real_vs_expert_win == 0.0 and bc.real_vs_expert_ratio > 100
    assert np.isnan(table.loc["constant_velocity", "real_vs_cv_win"])
    md = real_logs_markdown(table.reset_index(), "logs", "synthetic")
    assert "## Ego by ego on the real logs" in md
    assert "| Full | BC | Constant velocity | 12 (4) | 75% [" in md
    # no win on any ego: Wilson's interval over the 4 sources, not the bootstrap's point
    assert "| Full | BC | Expert (discretised replay) | 12 (4) | 0% [0, 49] |" in md
    sentence = real_logs_summary(table.reset_index())
    assert sentence.startswith("On 12 real egos from 4 source scenarios, ")
    assert "closer to the log than constant velocity on 75% of the egos, Full BC on 75% (95% CI " \
        in sentence
    back = table_from_markdown(md)  # the ego-by-ego rows are not read as the main table's
    assert back.method.tolist() == ["bc", "expert", "constant_velocity"]
    folder = tmp_path / "evals_real" / "bc"
    folder.mkdir(parents=True)
    _frame().to_csv(folder / "per_scenario.csv", index=False)
    assert main(["--real", str(tmp_path / "evals_real"), "--out", str(tmp_path / "t")]) == 0
    csv = pd.read_csv(tmp_path / "t" / "real_logs.csv").set_index("method")
    assert csv.loc["bc", "real_vs_cv_win"] == pytest.approx(0.75)
    written = (tmp_path / "t" / "real_logs.md").read_text()
    assert md[md.index("## Ego by ego"):] == written[written.index("## Ego by ego"):]


def test_paired_cells_read_without_egos_as_dashes():
    assert paired_cells({}) == ["--"] * 4
    cells = paired_cells(dict(egos=79, sources=30, win=0.48, win_lo=0.37, win_hi=0.59,
                              median=-0.14, median_lo=-0.6, median_hi=0.31, ratio=1.08,
                              ratio_lo=0.95, ratio_hi=1.22, ratio_mde=0.19))
    assert cells == ["79 (30)", "48% [37, 59]", "-0.14 [-0.60, +0.31]",
                     "1.08x [0.95, 1.22], MDE 0.19"]
