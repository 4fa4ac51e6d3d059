"""Real WOMD acceptance (discretised expert replay) and the ``igdrivsim replay`` command."""

import json
from pathlib import Path

import jax
import numpy as np
import pytest

from igdrivsim.cli import main
from igdrivsim.data import load_scenario
from igdrivsim.observation.replay import replay_fn
from igdrivsim.simulator.metrics import mean_log_divergence

WOMD = Path(__file__).resolve().parents[2] / "shared" / "data" / "womd"
EXAMPLE = WOMD / "motion_data_one_example.tfrecord"
needs_womd = pytest.mark.skipif(not EXAMPLE.exists(), reason=f"real WOMD samples not at {WOMD}")


@needs_womd
def test_discretised_expert_on_real_womd_matches_the_log():
    sc = load_scenario(EXAMPLE)
    _, m, log = replay_fn()(sc, jax.random.key(0))
    assert int(np.sum(m.valid)) == 80
    assert float(mean_log_divergence(m)) < 0.1  # paper: ~0.04 m; ours ~0.02 m
    assert float(np.max(m.log_divergence)) < 0.05
    np.testing.assert_array_equal(m.overlap, log.overlap)
    np.testing.assert_array_equal(m.offroad, log.offroad)


@needs_womd
def test_replay_command_prints_json_lines_and_writes_outputs(tmp_path, capsys):
    assert main(["replay", str(EXAMPLE), "--out", str(tmp_path), "--limit", "1"]) == 0
    captured = capsys.readouterr()
    lines = [json.loads(x) for x in captured.out.splitlines()]
    assert len(lines) == 1
    rec = lines[0]
    assert rec["scenario_id"] == "a3bb37c25ce56418"
    assert rec["replay_overlap_steps"] == rec["log_overlap_steps"]
    assert rec["replay_offroad_steps"] == rec["log_offroad_steps"]
    assert 0 < rec["replay_mean_log_divergence"] <= rec["replay_max_log_divergence"] < 0.05
    assert "summary:" in captured.err
    assert json.loads((tmp_path / "replay.jsonl").read_text()) == rec
    assert json.loads((tmp_path / "summary.json").read_text())["scenarios"] == 1
    assert json.loads((tmp_path / "config.json").read_text())["sim_params"]["edge_capacity"] > 0


def test_replay_command_reports_bad_input_in_one_line(tmp_path, capsys):
    bad = tmp_path / "not_a_record.tfrecord"
    bad.write_bytes(b"garbage")
    assert main(["replay", str(bad)]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith("igdrivsim replay: error:") and "not_a_record" in err
    assert main(["replay", str(tmp_path / "missing.tfrecord")]) == 2
    assert main(["replay", str(bad), "--limit", "0"]) == 2
