"""Paired per-ego statistics (igdrivsim.evaluation.paired): the win share's interval holds a
known share, clustering by source widens it when a source's egos are copies, the median ignores
one huge outlier where the mean ratio does not, the MDE shrinks as 1/sqrt(N), reruns agree."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from igdrivsim.evaluation.paired import (
    compare_on_egos,
    ego_arrays,
    paired_ego_statistics,
    source_of,
    sources,
    weighted_median,
)

B = 2_000  # resamples: enough for stable interval widths in these checks, fast


def _egos(n: int, p_win: float = 0.7, seeds: int = 3, seed: int = 0):
    """``n`` egos (one source each): a reference with heavy-tailed log divergence, a driver
    that is closer to the log on a share ``p_win`` of them in expectation (the same on every
    seed): driver - reference is normal with P(< 0) = p_win."""
    rng = np.random.default_rng(seed)
    ref = 3.0 + rng.lognormal(1.0, 0.8, n)
    driver = ref + rng.normal(-stats.norm.ppf(p_win), 1.0, n)
    return np.repeat(driver[None], seeds, axis=0), ref, [f"s{i}" for i in range(n)]


def test_ego_ids_name_their_source():
    assert source_of("1a2b3c#17") == "1a2b3c"
    assert source_of("1a2b3c") == "1a2b3c"  # one ego per scenario: its own source
    assert source_of("womd/1a2b#4") == "womd/1a2b"  # pooled sets keep their prefix
    frame = pd.DataFrame(dict(scenario_id=["a#1", "a#2", "b"]))
    assert sources(frame).tolist() == ["a", "a", "b"]
    assert sources(frame.assign(source=["x", "y", "z"])).tolist() == ["x", "y", "z"]


def test_weighted_median_is_numpys_with_unit_weights_and_counts_repeat_values():
    rng = np.random.default_rng(1)
    for n in (5, 6):
        v = rng.normal(size=(4, n))
        assert weighted_median(v, np.ones_like(v, int)) == pytest.approx(np.median(v, axis=1))
    v = np.array([[1.0, 2.0, 10.0]])
    assert weighted_median(v, np.array([[0, 1, 3]]))[0] == 10.0
    assert weighted_median(v, np.array([[2, 0, 2]]))[0] == 5.5  # [1, 1, 10, 10]


def test_known_win_share_is_inside_its_interval_and_half_is_not():
    driver, ref, src = _egos(400, p_win=0.7)
    out = paired_ego_statistics(driver, ref, src, n_resamples=B)
    assert out["n_egos"] == 400 and out["n_sources"] == 400 and out["n_seeds"] == 3
    assert out["win_lo"] <= 0.7 <= out["win_hi"] and out["win_lo"] > 0.5
    assert abs(out["win"] - 0.7) < 0.05
    binomial = 2 * 1.96 * np.sqrt(0.7 * 0.3 / 400)  # the width of the textbook interval
    assert out["win_hi"] - out["win_lo"] == pytest.approx(binomial, rel=0.25)
    assert out["median_lo"] <= out["median"] <= out["median_hi"] < 0
    assert out["ratio_lo"] <= out["ratio"] <= out["ratio_hi"]
    even = paired_ego_statistics(*_egos(400, p_win=0.5, seed=3), n_resamples=B)
    assert even["win_lo"] <= 0.5 <= even["win_hi"]


def test_copies_of_a_source_do_not_narrow_the_clustered_interval():
    driver, ref, src = _egos(60, p_win=0.6)
    base = paired_ego_statistics(driver, ref, src, n_resamples=B)
    k = 5  # each source's ego five times (e.g. five vehicles of one scene that agree)
    copies = np.repeat(driver, k, axis=1), np.repeat(ref, k)
    clustered = paired_ego_statistics(*copies, np.repeat(src, k), n_resamples=B)
    naive = paired_ego_statistics(*copies, [f"e{i}" for i in range(60 * k)], n_resamples=B)
    assert clustered["n_egos"] == 300 and clustered["n_sources"] == 60
    assert clustered["win"] == pytest.approx(base["win"])
    for name in ("win", "median", "ratio"):
        width = {k: v[f"{name}_hi"] - v[f"{name}_lo"] for k, v in
                 dict(base=base, clustered=clustered, naive=naive).items()}
        assert width["clustered"] == pytest.approx(width["base"], rel=0.25), name
        assert width["clustered"] > 1.6 * width["naive"], name


def test_the_median_shrugs_off_one_huge_outlier_and_the_mean_ratio_does_not():
    driver, ref, src = _egos(80, p_win=0.6)
    clean = paired_ego_statistics(driver, ref, src, n_resamples=B)
    driver = driver.copy()
    driver[:, 0] = 1_000.0  # one ego driven a kilometre away
    tail = paired_ego_statistics(driver, ref, src, n_resamples=B)
    spread = clean["median_hi"] - clean["median_lo"]
    assert abs(tail["median"] - clean["median"]) < 0.25 * spread
    assert tail["median_hi"] - tail["median_lo"] < 1.5 * spread
    assert abs(tail["win"] - clean["win"]) <= 1 / 80 + 1e-12
    assert tail["ratio"] > 2 * clean["ratio"]  # the mean follows the outlier
    assert tail["ratio_mde"] > 5 * clean["ratio_mde"]


def test_the_minimum_detectable_effect_shrinks_as_one_over_root_n():
    small = paired_ego_statistics(*_egos(100, seed=5), n_resamples=B)
    large = paired_ego_statistics(*_egos(1_600, seed=6), n_resamples=B)
    assert small["ratio_mde"] / large["ratio_mde"] == pytest.approx(4.0, rel=0.3)
    assert small["win_mde"] / large["win_mde"] == pytest.approx(4.0, rel=0.3)


def test_seed_spread_widens_the_interval_and_reruns_are_identical():
    driver, ref, src = _egos(100, seeds=3)
    steady = paired_ego_statistics(driver, ref, src, n_resamples=B)
    shaky = driver + np.array([-1.5, 0.0, 1.5])[:, None]  # seeds disagree by a constant
    varied = paired_ego_statistics(shaky, ref, src, n_resamples=B)
    assert varied["ratio"] == pytest.approx(steady["ratio"])
    assert varied["ratio_hi"] - varied["ratio_lo"] > 1.5 * (steady["ratio_hi"]
                                                            - steady["ratio_lo"])
    assert paired_ego_statistics(shaky, ref, src, n_resamples=B, seed=7) == \
        paired_ego_statistics(shaky, ref, src, n_resamples=B, seed=7)
    assert paired_ego_statistics(shaky, ref, src, n_resamples=B, seed=8)["ratio_lo"] != \
        varied["ratio_lo"]
    never = paired_ego_statistics(driver + 100.0, ref, src, n_resamples=B)
    assert never["win"] == 0.0 and never["win_lo"] == 0.0  # Wilson's, one trial per source
    assert never["win_hi"] == pytest.approx(1.96 ** 2 / (100 + 1.96 ** 2), rel=1e-3)
    empty = paired_ego_statistics(np.zeros((3, 0)), np.zeros(0), [], n_resamples=10)
    assert empty["n_egos"] == 0 and np.isnan(empty["win"]) and np.isnan(empty["ratio_mde"])
    with pytest.raises(ValueError, match="agree on the egos"):
        paired_ego_statistics(driver, ref[:-1], src)


def test_tidy_rows_give_the_egos_every_seed_shares_grouped_by_source():
    rows = [dict(setting="full", method="bc", seed=s, scenario_id=e, log_divergence=1.0 + s)
            for s in (0, 1) for e in ("a#1", "a#2", "b#1", "c")]
    rows = [r for r in rows if not (r["seed"] == 1 and r["scenario_id"] == "c")]  # one seed
    rows += [dict(setting="none", method="constant_velocity", seed=0, scenario_id=e,
                  log_divergence=2.0) for e in ("a#1", "a#2", "b#1", "c", "d")]
    frame = pd.DataFrame(rows)
    driver, ref, src = ego_arrays(frame, "full", "bc", "constant_velocity")
    assert driver.tolist() == [[1.0, 1.0, 1.0], [2.0, 2.0, 2.0]] and ref.tolist() == [2.0] * 3
    assert src == ["a", "a", "b"]
    out = compare_on_egos(frame, "full", "bc", "constant_velocity", n_resamples=200)
    assert (out["n_egos"], out["n_sources"], out["n_seeds"]) == (3, 2, 2)
    assert out["win"] == 0.75  # seed 0 closer, seed 1 a tie, on every ego
    assert out["median"] == -0.5 and out["ratio"] == pytest.approx(0.75)
    assert out["diff"] == pytest.approx(-0.5) and out["diff_lo"] <= -0.5 <= out["diff_hi"]
    assert compare_on_egos(frame, "full", "bc_rl", "constant_velocity")["n_egos"] == 0


def test_the_mean_difference_bootstrap_resamples_clusters_when_given():
    from igdrivsim.evaluation.aggregate import hierarchical_bootstrap

    rng = np.random.default_rng(2)
    xb = rng.lognormal(1.0, 0.8, (1, 60, 1))
    xa = xb + rng.normal(0.3, 1.0, (3, 60, 1))
    distinct = [f"s{i}" for i in range(60)]
    assert np.array_equal(hierarchical_bootstrap(xa, xb, B, 0, clusters=distinct),
                          hierarchical_bootstrap(xa, xb, B, 0))  # the plain resample
    k = 5
    copies = np.repeat(xa, k, axis=1), np.repeat(xb, k, axis=1)

    def width(reps):
        return float(np.diff(np.percentile(reps[:, 0], [2.5, 97.5]))[0])

    base = width(hierarchical_bootstrap(xa, xb, B, 0))
    clustered = width(hierarchical_bootstrap(*copies, B, 0, clusters=np.repeat(distinct, k)))
    naive = width(hierarchical_bootstrap(*copies, B, 0))
    assert clustered == pytest.approx(base, rel=0.2) and clustered > 1.6 * naive
    with pytest.raises(ValueError, match="one entry per scenario"):
        hierarchical_bootstrap(xa, xb, 10, 0, clusters=distinct[:-1])
