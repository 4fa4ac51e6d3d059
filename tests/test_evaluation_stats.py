"""Two-level bootstrap, Holm bolding, minimum detectable effect and the learning-curve figure
(synthetic, test-only data; every test runs in about a second)."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from igdrivsim.errors import DataError
from igdrivsim.evaluation import aggregate
from igdrivsim.evaluation.schema import PER_SCENARIO_COLUMNS, REFERENCE_SETTING
from igdrivsim.report import tables
from igdrivsim.report.build import Provenance, build_report
from igdrivsim.report.figures import learning_curves_figure, load_curves

Z_SUM = 1.959963984540054 + 0.8416212335729143  # z_{0.975} + z_{0.8}


def _pair(rng, n=300, effect=0.2, seed_sd=0.0, seeds=3):
    """(xa, xb) of shape (seeds, n): shared scenario difficulty, BC-RL shifted by ``effect``,
    optional per-seed offsets (training-seed variance) of standard deviation ``seed_sd``."""
    base = rng.normal(0, 1, n)
    xb = base + rng.normal(0, 0.3, (seeds, n)) + rng.normal(0, seed_sd, (seeds, 1))
    xa = base + effect + rng.normal(0, 0.3, (seeds, n)) + rng.normal(0, seed_sd, (seeds, 1))
    return xa, xb


def _interval(xa, xb, n_resamples=2000):
    reps = aggregate.hierarchical_bootstrap(xa, xb, n_resamples, seed=0)[:, 0]
    return np.percentile(reps, [2.5, 97.5])


def test_bootstrap_covers_known_effect():
    rng = np.random.default_rng(0)
    hits = 0
    for _ in range(60):
        low, high = _interval(*_pair(rng), n_resamples=400)
        hits += low <= 0.2 <= high
    assert hits >= 52  # nominal 95%: about 57 of 60
    low, high = _interval(*_pair(np.random.default_rng(1)))
    assert 0 < low < 0.2 < high


def test_bootstrap_pairs_scenarios_and_widens_with_seed_variance():
    rng = np.random.default_rng(2)
    base = rng.normal(0, 1, (1, 200))
    low, high = _interval(base + 0.5, base)  # identical scenarios: only the shift remains
    assert low == pytest.approx(0.5) and high == pytest.approx(0.5)
    xa, xb = _pair(np.random.default_rng(3))
    offsets = np.array([[-0.4], [0.0], [0.4]])  # mean-zero seed effects: same true difference
    narrow = np.diff(_interval(xa, xb))[0]
    wide = np.diff(_interval(xa + offsets, xb - offsets[::-1] * 0.5))[0]
    assert wide > 1.5 * narrow


def test_bootstrap_is_reproducible_and_shapes():
    xa, xb = _pair(np.random.default_rng(4), n=50)
    stacked = np.stack([xa, 2 * xa], axis=-1), np.stack([xb, 2 * xb], axis=-1)
    a = aggregate.hierarchical_bootstrap(*stacked, n_resamples=3000, seed=[0, 7])
    b = aggregate.hierarchical_bootstrap(*stacked, n_resamples=3000, seed=[0, 7])
    assert a.shape == (3000, 2) and np.array_equal(a, b)
    assert np.allclose(a[:, 1], 2 * a[:, 0])  # metrics share the resamples
    p = aggregate.bootstrap_p_value(np.array([[1.0], [2.0], [-1.0], [3.0]]))
    assert p[0] == pytest.approx(2 * 2 / 5)


def test_holm_adjust_textbook():
    p = aggregate.holm_adjust([0.01, 0.04, 0.03, 0.005, np.nan])
    assert np.allclose(p[:4], [0.03, 0.06, 0.06, 0.02]) and np.isnan(p[4])


def _frame(values_a, values_b, setting="full"):
    """per_scenario rows (one seed per method per row of the arrays); every metric column
    carries the same value, so each metric's effect is known."""
    rows = []
    for method, values in (("bc_rl", values_a), ("bc", values_b)):
        for seed, row in enumerate(np.atleast_2d(values)):
            for i, v in enumerate(row):
                rows.append(dict(setting=setting, method=method, seed=seed,
                                 scenario_id=f"s{i:04d}", log_divergence=v,
                                 max_log_divergence=v, overlap=v, offroad=v, overlap_steps=v,
                                 offroad_steps=v))
    return pd.DataFrame(rows)[list(PER_SCENARIO_COLUMNS)]


def test_mde_matches_closed_form():
    assert aggregate.minimum_detectable_effect(1.0) == pytest.approx(Z_SUM)
    assert aggregate.minimum_detectable_effect(1.0, alpha=0.05 / 36) == pytest.approx(
        3.197 + 0.8416, abs=2e-3)
    rng = np.random.default_rng(5)
    n, sd = 400, 0.7
    diff = rng.normal(0.1, sd, n)
    tests = aggregate.compare_methods(_frame(diff, np.zeros(n)), n_resamples=4000)
    row = tests[tests.metric == "log_divergence"].iloc[0]
    closed = Z_SUM * diff.std(ddof=1) / np.sqrt(n)  # one seed a side: the paired-mean SE
    assert row.mde == pytest.approx(closed, rel=0.08)
    assert row["diff"] == pytest.approx(diff.mean())
    percent = tests[tests.metric == "overlap"].iloc[0]  # scaled to % like Table I
    assert percent.mde == pytest.approx(100 * row.mde, rel=1e-9)


def test_holm_decides_bold():
    rng = np.random.default_rng(6)
    n = 300
    base = rng.normal(0, 1, n)
    frames = [_frame(base + rng.normal(0, 0.2, n) - 1.0, base, "full"),  # clear effect
              _frame(base + rng.normal(0, 1.0, n) + 0.13, base, "circular_r4")]  # marginal
    tests = aggregate.compare_methods(pd.concat(frames), n_resamples=4000)
    assert (tests.significant == (tests.p_holm < 0.05)).all()
    assert np.allclose(tests.p_holm, aggregate.holm_adjust(tests.p_value))
    full = tests[tests.setting == "full"]
    assert full.significant.all() and (full.better == "bc_rl").all()
    marginal = tests[tests.setting == "circular_r4"]
    assert (marginal.p_value < 0.05).all() and not marginal.significant.any()
    assert (marginal.ci_low > 0).all()  # the uncorrected interval excludes 0 ...
    summary = aggregate.summarize(pd.concat(frames))
    md = tables.table1_markdown(summary, tests)
    line = next(x for x in md.splitlines() if x.startswith("| log divergence | BC-RL |"))
    cells = [c.strip() for c in line.split("|")[3:-1]]
    assert cells[0].startswith("**") and not cells[2].startswith("**")  # ... but no bold


def _write_curves(path, method, settings=("full", "conic_r4"), seeds=(0, 1), n=12, k=4):
    path.parent.mkdir(parents=True, exist_ok=True)
    lines = []
    for setting in settings:
        for seed in seeds:
            for u in range(n):
                record = dict(update=u, setting=setting, method=method, seed=seed,
                              bc_loss=2.0 / (u + 1), val_bc_loss=2.2 / (u + 1) + 0.1 * seed)
                if u % k == 0:
                    record.update(log_divergence=5.0 / (u + 1), offroad=0.3 / (u + 1),
                                  overlap=0.05)
                if method == "bc_rl":
                    record["mean_return"] = float(u)
                lines.append(json.dumps(record))
    path.write_text("\n".join(lines) + "\n")


def test_learning_curves_figure(tmp_path):
    runs = tmp_path / "runs"
    _write_curves(runs / "bc" / "curves.jsonl", "bc")
    _write_curves(runs / "bc_rl" / "curves.jsonl", "bc_rl", settings=("full",))
    refs = pd.DataFrame([dict(setting=REFERENCE_SETTING, method=m, seed=0, scenario_id="s0",
                              log_divergence=v, max_log_divergence=v, overlap=0.0, offroad=0.0,
                              overlap_steps=0.01, offroad_steps=0.2)
                         for m, v in (("constant_velocity", 9.0), ("expert", 0.1))])
    curves = load_curves([runs])
    assert set(curves.method) == {"bc", "bc_rl"} and len(curves) == 12 * 2 * 3
    paths = learning_curves_figure(curves, tmp_path / "figs", refs)
    assert [p.name for p in paths] == ["fig4_learning_curves.pdf", "fig4_learning_curves.png"]
    from PIL import Image

    with Image.open(paths[1]) as im:
        assert im.size[0] > 600 and im.size[1] > 400
    assert learning_curves_figure(load_curves([tmp_path / "none"]), tmp_path / "figs2") == []
    (runs / "bad").mkdir()
    (runs / "bad" / "curves.jsonl").write_text('{"update": 1}\n')
    with pytest.raises(DataError, match="bad curves record"):
        load_curves([runs])


def test_report_reads_any_eval_folder_and_sibling_runs(tmp_path):
    rng = np.random.default_rng(7)
    base = rng.uniform(0, 1, 30)
    evals = tmp_path / "work" / "evals"
    frame = pd.concat([_frame(np.stack([base + 0.01 * s for s in range(3)]),
                              np.stack([base + 0.02 * s for s in range(3)]), setting)
                       for setting in ("full", "circular_r4")])
    for method in ("bc", "bc_rl"):  # new layout: one folder per method, several settings
        (evals / method).mkdir(parents=True)
        frame[frame.method == method].to_csv(evals / method / "per_scenario.csv", index=False)
    _write_curves(tmp_path / "work" / "runs" / "bc" / "curves.jsonl", "bc")
    written = build_report([evals], tmp_path / "paper", Provenance(profile="t", data="d"))
    names = {p.name for p in written}
    assert {"fig4_learning_curves.png", "power.md", "power.tex"} <= names
    tests = pd.read_csv(tmp_path / "paper" / "tables" / "tests.csv")
    assert len(tests) == 2 * 6 and set(tests.setting) == {"full", "circular_r4"}
