"""The reactive companion table (igdrivsim.report.reactive) on constructed evaluations."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from igdrivsim.errors import DataError
from igdrivsim.report.reactive import reactive_figure, reactive_markdown, reactive_table
from igdrivsim.report.results_tex import reactive_section
from igdrivsim.report.results_tex import reactive_verdict as verdict


def frame(overlap_p: float, seed_count: int = 3, n: int = 60, rng_seed: int = 0,
          methods=(("full", "bc"), ("full", "bc_rl"), ("none", "expert"))):
    """Per-scenario rows: overlap drawn with probability ``overlap_p`` (the expert never)."""
    rng = np.random.default_rng(rng_seed)
    rows = []
    for setting, method in methods:
        for seed in range(1 if setting == "none" else seed_count):
            for k in range(n):
                hit = float(method != "expert" and rng.random() < overlap_p)
                rows.append(dict(setting=setting, method=method, seed=seed,
                                 scenario_id=f"s{k}", overlap=hit, at_fault_overlap=hit / 2,
                                 offroad=0.0, max_log_divergence=1.0 + rng.random()))
    return pd.DataFrame(rows)


@pytest.fixture(scope="module")
def table():
    return reactive_table(frame(0.6), frame(0.1, rng_seed=1), n_resamples=2000)


def test_the_difference_log_minus_idm_is_found_where_it_is_and_not_elsewhere(table):
    rate = table[table.metric == "overlap_rate"].set_index("method")
    assert rate.loc["bc", "log_mean"] > 40 and rate.loc["bc", "idm_mean"] < 20
    assert rate.loc["bc", "diff"] == pytest.approx(
        rate.loc["bc", "log_mean"] - rate.loc["bc", "idm_mean"], abs=1e-6)
    assert rate.loc["bc", "significant"] and rate.loc["bc", "diff_low"] > 0
    assert rate.loc["expert", "diff"] == 0 and not rate.loc["expert", "significant"]
    div = table[table.metric == "max_log_divergence"]
    assert not div.significant.any()  # same distribution under both
    assert np.all(np.diff(table.p_holm[np.argsort(table.p_value.to_numpy())]) >= -1e-12)


def test_markdown_and_figure(table, tmp_path):
    md = reactive_markdown(table)
    assert "## at-fault overlap rate (%)" in md and "| Full | BC |" in md
    assert "| -- | Expert (its own log) |" in md and "**+" in md
    paths = reactive_figure(table, tmp_path)
    assert paths[0].read_bytes().startswith(b"%PDF") and paths[1].stat().st_size > 1000


def test_the_verdict_counts_the_learned_drivers_that_move(table):
    text = verdict(table)
    assert "of the 2 learned drivers" in text  # the expert is not counted
    assert "overlap rate 2 lower and 0 higher" in text
    assert "max log divergence 0 lower and 0 higher" in text
    flipped = table.assign(diff=-table["diff"])
    assert "overlap rate 0 lower and 2 higher" in verdict(flipped)
    assert reactive_section(None) == []
    assert reactive_section(table)[0] == "## Under reactive traffic"


def test_nothing_in_common_is_a_clear_error():
    with pytest.raises(DataError, match="both log and idm"):
        reactive_table(frame(0.5, methods=(("full", "bc"),)),
                       frame(0.5, methods=(("full", "bc_rl"),)))
