"""Evaluation rollouts: tidy frames by hand, reference actors on a real scene, CLI errors.

Policy evaluation end to end (and its determinism) is covered by test_pipeline_smoke.py.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from igdrivsim.cli import main as cli_main
from igdrivsim.evaluation import rollout
from igdrivsim.evaluation.registry import SCENARIO_COLUMNS
from igdrivsim.evaluation.schema import PER_SCENARIO_COLUMNS, PER_STEP_COLUMNS

SAMPLE = Path(__file__).resolve().parents[2] / "shared" / "data" / "womd" / (
    "motion_data_one_example.tfrecord")


def test_tidy_frames_masks_and_aggregates():
    steps = 4
    ld = np.array([[[1.0, 2.0, 9.0, 3.0], [0.5, 0.5, 0.5, 0.5]]])  # [S=1, N=2, steps]
    ov = np.array([[[0, 1, 0, 0], [0, 0, 0, 0]]], float)
    off = np.array([[[0, 0, 1, 0], [0, 0, 0, 1]]], float)
    valid = np.array([[[True, True, False, True], [True, True, True, True]]])
    out = rollout.StepOutputs(ld, ov, off, valid)
    per_step, per_scenario = rollout.tidy_frames(out, ["a", "b"], "full", "bc", [7])
    assert list(per_step.columns) == list(PER_STEP_COLUMNS)
    assert list(per_scenario.columns) == list(SCENARIO_COLUMNS)  # Table I's, then the registry's
    assert list(per_scenario.columns)[: len(PER_SCENARIO_COLUMNS)] == list(PER_SCENARIO_COLUMNS)
    assert per_scenario.progress.isna().all()  # no episode metrics requested: NaN columns
    assert len(per_step) == steps and per_step.step.tolist() == [1, 2, 3, 4]
    # Step 3: scenario a is invalid, so only b counts.
    row3 = per_step[per_step.step == 3].iloc[0]
    assert row3.log_divergence == pytest.approx(0.5) and row3.offroad == 0.0
    a = per_scenario[per_scenario.scenario_id == "a"].iloc[0]
    assert a.max_log_divergence == pytest.approx(3.0)  # the 9.0 is at an invalid step
    assert a.log_divergence == pytest.approx(2.0)
    assert a.overlap == 1.0 and a.offroad == 0.0 and a.overlap_steps == pytest.approx(1 / 3)
    b = per_scenario[per_scenario.scenario_id == "b"].iloc[0]
    assert b.offroad == 1.0 and b.offroad_steps == pytest.approx(0.25) and a.seed == 7
    with pytest.raises(ValueError):
        rollout.tidy_frames(out, ["a"], "full", "bc", [7])


@pytest.fixture(scope="module")
def scene():
    if not SAMPLE.exists():
        pytest.skip(f"real WOMD sample not found at {SAMPLE}")
    from igdrivsim.data import Capacities, load_scenario, stack_scenarios
    from igdrivsim.simulator import SimParams

    caps = Capacities(max_objects=16, max_roadgraph_points=20_000)  # the whole map
    sc = load_scenario(SAMPLE, caps=caps)
    return stack_scenarios([sc, sc, sc]), SimParams()


def test_reference_actors_on_real_scene(scene):
    scenarios, params = scene
    per_step, per_scenario = rollout.reference_frames(scenarios, params, batch_size=2)
    expert = per_scenario[per_scenario.method == "expert"]
    cv = per_scenario[per_scenario.method == "constant_velocity"]
    assert len(expert) == 3 and (per_scenario.setting == "none").all()
    # The discretised expert tracks the log to a few centimetres and never crashes.
    assert expert.log_divergence.max() < 0.1 and expert.overlap.sum() == 0
    assert expert.offroad.sum() == 0
    assert cv.max_log_divergence.min() > 1.0  # this SDC turns/brakes: a straight line drifts
    assert per_step.groupby("method").step.max().eq(80).all()


def test_evaluate_cli_errors_are_one_line(tmp_path, capsys):
    assert cli_main(["evaluate", "--data", str(tmp_path), "--out", str(tmp_path)]) == 2
    assert "RUN_DIR" in capsys.readouterr().err
    assert cli_main(["evaluate", str(tmp_path / "nope"), "--data", str(tmp_path), "--out",
                     str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "not a training run" in err and len(err.strip().splitlines()) == 1
    assert cli_main(["report", "--evals", str(tmp_path / "absent"), "--out",
                     str(tmp_path / "p")]) == 2
