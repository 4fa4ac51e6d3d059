"""`igdrivsim report transfer`: Full BC against constant velocity per (data set,
motion model), and the motion models' BC against each other on the shared real scenarios, with
bootstrap intervals that contain the true difference."""

from __future__ import annotations

import json

import pandas as pd
import pytest

from igdrivsim import cli
from igdrivsim.errors import ConfigError
from igdrivsim.report.transfer import (
    against_constant_velocity,
    between_motions,
    ego_by_ego,
    evaluations,
)


def main(argv):
    return cli.main(["report", "transfer", *argv])


COLUMNS = ["setting", "method", "seed", "scenario_id", "log_divergence", "offroad_steps",
           "overlap_steps", "max_log_divergence", "overlap", "offroad"]


def _evals(root, motion, data, bc_log_div, cv_log_div, n=8):
    """BC (two seeds, ``bc_log_div`` plus a per-scenario wobble) and constant velocity."""
    folder = root / motion / f"evals_{data}"
    for who, rows in (("bc", [["full", "bc", s, f"s{i}", bc_log_div + (-1) ** i * 0.5 + s * 0.1,
                               0.1, 0.0, 9.0, 0, 1] for s in range(2) for i in range(n)]),
                      ("references", [["none", "constant_velocity", 0, f"s{i}", cv_log_div,
                                       0.2, 0.0, 9.0, 0, 1] for i in range(n)])):
        (folder / who).mkdir(parents=True)
        pd.DataFrame(rows, columns=COLUMNS).to_csv(folder / who / "per_scenario.csv",
                                                   index=False)


def test_transfer_tables_measure_bc_against_cv_and_the_motions(tmp_path, capsys):
    _evals(tmp_path, "default", "validation", 5.0, 8.0)
    _evals(tmp_path, "default", "real", 6.0, 5.0)
    _evals(tmp_path, "calibrated", "real", 4.0, 5.0)
    found = evaluations(tmp_path)
    assert set(found) == {("validation", "default"), ("real", "default"), ("real", "calibrated")}
    for motion in ("default", "calibrated"):  # a second real set: pooled with the first
        (tmp_path / motion / "evals_real").rename(tmp_path / motion / "evals_other")
        _evals(tmp_path, motion, "real", 6.0 if motion == "default" else 4.0, 5.0)
    found = evaluations(tmp_path)
    pooled = found[("real, pooled", "default")]
    assert len(pooled) == 2 * len(found[("real", "default")])
    assert ("real, pooled", "calibrated") in found and ("real, pooled", "validation") not in found
    vs_cv = against_constant_velocity(found).set_index(["data", "motion"])
    assert list(vs_cv.index)[0] == ("validation", "default")  # validation first, pooled last
    assert list(vs_cv.index)[-1] == ("real, pooled", "default")
    row = vs_cv.loc[("real", "default")]
    assert row.n == 8 and row.seeds == 2
    assert row.log_divergence_a == pytest.approx(6.05) and row.log_divergence_b == 5.0
    assert row.log_divergence_lo <= 1.05 <= row.log_divergence_hi
    assert row.offroad_a == pytest.approx(10.0) and row.offroad_b == pytest.approx(20.0)
    motions = between_motions(found).set_index("data")
    assert list(motions.index) == ["other", "real", "real, pooled"]
    assert motions.loc["real", "motion"] == "default" and motions.loc["real", "baseline"] == (
        "calibrated")
    assert motions.loc["real", "log_divergence_diff"] == pytest.approx(2.0)
    assert motions.loc["real", "log_divergence_p"] < 0.05
    # the BC evaluations' records name the code that trained and the code that evaluated
    code = {"commit": "abc1234", "dirty": False, "diff_hash": None}
    (tmp_path / "default" / "evals_real" / "bc" / "eval_config.json").write_text(json.dumps(
        {"code": {**code, "commit": "def5678"}, "trained": {"num_scenarios": 1970,
                                                             "code": code}}))
    assert main([str(tmp_path), "--out", str(tmp_path / "transfer.md")]) == 0
    text = (tmp_path / "transfer.md").read_text()
    assert "- default: 1,970 training scenarios; trained at abc1234; evaluated at def5678" in text
    assert "- calibrated: trained at unknown; evaluated at unknown" in text
    assert "| real | default | 8 | 6.05 | 5.00 | 1.21 |" in text
    assert "| real | default - calibrated | 8 | +2.00" in text


def test_transfer_compares_every_driver_ego_by_ego_clustered_by_source(tmp_path):
    """BC and a BC-RL folder beside it, on egos ``<scenario>#<object>`` (two per source):
    each against constant velocity and the expert, N egos and N sources, also when pooled."""
    for data in ("validation", "real", "other"):
        _evals(tmp_path, "default", data, 5.0, 5.0)
        folder = tmp_path / "default" / f"evals_{data}"
        for who in ("bc", "references"):
            frame = pd.read_csv(folder / who / "per_scenario.csv")
            frame["scenario_id"] = frame.scenario_id.str[1:].astype(int).map(
                lambda i: f"src{i // 2}#{i % 2}")
            if who == "references":  # and the expert, replaying the log
                frame = pd.concat([frame, frame.assign(method="expert", log_divergence=0.02)])
            frame.to_csv(folder / who / "per_scenario.csv", index=False)
        rl = pd.read_csv(folder / "bc" / "per_scenario.csv").assign(
            method="bc_rl", log_divergence=lambda f: f.log_divergence + 2.0)
        (folder / "bc_rl").mkdir()
        rl.to_csv(folder / "bc_rl" / "per_scenario.csv", index=False)
    found = evaluations(tmp_path)
    egos = ego_by_ego(found).set_index(["data", "method", "reference"])
    bc = egos.loc[("real", "bc", "constant_velocity")]
    assert (bc.egos, bc.sources, bc.n_seeds) == (8, 4, 2)
    # BC wobbles by +-0.5 around CV, and every source holds one win and one loss: resampling
    # sources (not egos) cannot move the share
    assert bc.win == bc.win_lo == bc.win_hi == 0.5
    assert bc["median"] == pytest.approx(0.05) and bc.ratio == pytest.approx(5.05 / 5.0)
    rl = egos.loc[("real", "bc_rl", "constant_velocity")]
    assert rl.win == 0.0 and rl.ratio == pytest.approx(7.05 / 5.0)
    expert = egos.loc[("real", "bc", "expert")]
    assert (expert.egos, expert.win) == (8, 0.0) and expert.ratio == pytest.approx(5.05 / 0.02)
    pooled = egos.loc[("real, pooled", "bc", "constant_velocity")]
    assert (pooled.egos, pooled.sources) == (16, 8)
    assert list(ego_by_ego(found).data)[0] == "validation"
    assert against_constant_velocity(found).set_index("data").loc["real", "n"] == 8
    assert main([str(tmp_path), "--out", str(tmp_path / "transfer.md")]) == 0
    text = (tmp_path / "transfer.md").read_text()
    assert "| real | default | Full | BC | Constant velocity | 8 (4) | 50% [" in text
    assert "| real, pooled | default | Full | BC-RL | Constant velocity | 16 (8) | 0% [0, 32] |" \
        in text


def test_transfer_without_evaluations_is_one_line(tmp_path, capsys):
    with pytest.raises(ConfigError, match="transfer_check.sh"):
        evaluations(tmp_path)
    assert main([str(tmp_path)]) == 2
    assert capsys.readouterr().err.count("\n") == 1
