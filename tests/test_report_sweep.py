"""`igdrivsim report sweep`: each variant's overrides, the updates its evaluation saw,
its compute relative to the profile's budget, and its log divergence against constant
velocity's on the same scenarios."""

from __future__ import annotations

import dataclasses
import json

import pandas as pd

from igdrivsim import cli
from igdrivsim.report.sweep import sweep_table
from igdrivsim.training.config import get_profile, to_dict

COLUMNS = ["setting", "method", "seed", "scenario_id", "log_divergence", "offroad_steps",
           "overlap_steps"]


def _variant(root, name, log_div, done=True, **training):
    config = get_profile("laptop")
    config = dataclasses.replace(config, training=dataclasses.replace(config.training,
                                                                      **training))
    run = root / "runs" / name
    run.mkdir(parents=True)
    (run / "config.json").write_text(json.dumps({"config": to_dict(config)}))
    if done:
        (run / "DONE").write_text("")
    else:
        rows = [{"update": u, "seed": 0, "log_divergence": 1.0} for u in (250, 500)]
        (run / "curves.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    evals = root / "evals" / name
    evals.mkdir(parents=True)
    rows = [["full", "bc", seed, f"s{i}", log_div[seed], 0.0, 0.1]
            for seed in range(len(log_div)) for i in range(2)]
    pd.DataFrame(rows, columns=COLUMNS).to_csv(evals / "per_scenario.csv", index=False)


def test_sweep_table_prices_and_scores_each_variant(tmp_path, capsys):
    _variant(tmp_path, "base", [4.0, 6.0])
    _variant(tmp_path, "long", [3.0, 3.0], done=False, num_updates=2000, ppo_epochs=4)
    refs = tmp_path / "refs"
    refs.mkdir()
    pd.DataFrame([["none", "constant_velocity", 0, f"s{i}", 10.0, 0.0, 0.0] for i in range(2)]
                 + [["none", "expert", 0, "s0", 0.0, 0.0, 0.0]],
                 columns=COLUMNS).to_csv(refs / "per_scenario.csv", index=False)
    table = sweep_table(tmp_path, refs).set_index("variant")
    assert table.loc["base", "overrides"] == "-" and table.loc["base", "updates"] == 1000
    assert table.loc["base", "log_divergence"] == 5.0
    assert table.loc["base", "seed_range"] == "4.00-6.00"
    assert table.loc["base", "x_constant_velocity"] == 0.5
    assert table.loc["base", "overlap_pct"] == 10.0
    # stopped early: its last validated checkpoint, priced at twice the passes per update
    assert table.loc["long", "updates"] == "500 of 2000"
    assert table.loc["long", "compute"] == 1.0
    assert "training.num_updates=2000" in table.loc["long", "overrides"]
    assert cli.main(["report", "sweep", str(tmp_path), "--references", str(refs), "--out",
                 str(tmp_path / "sweep.md")]) == 0
    assert "| long |" in (tmp_path / "sweep.md").read_text()


def test_sweep_without_runs_is_a_one_line_error(tmp_path, capsys):
    assert cli.main(["report", "sweep", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("igdrivsim report: error:") and "runs" in err and "\n" not in err


def test_sweep_with_a_broken_config_names_the_file(tmp_path, capsys):
    run = tmp_path / "runs" / "bad"
    run.mkdir(parents=True)
    (run / "config.json").write_text("{}")
    assert cli.main(["report", "sweep", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert "runs/bad/config.json" in err and "\n" not in err
