"""The speed-walk diagnostic on the real WOMD sample: label statistics and the four actors."""

from pathlib import Path

import jax
import numpy as np
import pytest

from igdrivsim.data import load_scenario
from igdrivsim.evaluation.speed_walk import label_statistics, measure, transition_log_probs

SAMPLE = (Path(__file__).resolve().parents[1]
          / "../shared/data/womd/motion_data_one_example.tfrecord")


def test_label_statistics_by_hand():
    offsets = np.array([[0, 1], [1, -1], [0, 0], [1, 1]])  # [T=4, B=2]
    valid = np.ones_like(offsets, bool)
    stats = label_statistics(offsets, valid)
    assert stats["offset_levels"] == [-1, 0, 1]
    np.testing.assert_allclose(stats["offset_probability"], [1 / 8, 3 / 8, 4 / 8], atol=1e-4)
    # after 0 always 1 (or 0: ...): the conditional entropy is below the marginal
    assert stats["entropy_given_previous_nats"] < stats["entropy_nats"]


def test_transition_table_by_hand():
    offsets = np.array([[1], [-1], [1], [-1], [0], [0], [5]])  # [T=7, B=1]; 5 clips to 3
    valid = np.ones_like(offsets, bool)
    p = np.exp(transition_log_probs(offsets, valid, min_count=2))
    np.testing.assert_allclose(p.sum(1), 1.0, atol=1e-6)
    np.testing.assert_allclose(p[1 + 3, -1 + 3], 1.0, atol=1e-6)  # after +1 always -1
    np.testing.assert_allclose(p[-1 + 3, [1 + 3, 0 + 3]], [0.5, 0.5], atol=1e-6)
    # a previous offset never seen (-2) gets the marginal of the next offsets
    np.testing.assert_allclose(p[-2 + 3, 3 + 3], 1 / 6, atol=1e-6)


@pytest.mark.skipif(not SAMPLE.exists(), reason="real WOMD sample not present")
def test_expert_replays_and_constant_speed_drifts_on_the_real_sample():
    scenario = load_scenario(str(SAMPLE))
    result = measure(jax.tree.map(lambda x: np.asarray(x)[None], scenario))
    actors = result["actors"]
    assert actors["expert"]["log_divergence_m"] < 0.05
    assert actors["expert_steering_constant_speed"]["log_divergence_m"] > 0.1
    assert 0.0 < actors["expert_steering_offsets_given_previous"]["log_divergence_m"] < 100.0
    assert sum(result["label_offsets"]["offset_probability"]) == pytest.approx(1.0, abs=1e-3)


def test_report_files_carry_the_numbers():
    from igdrivsim.evaluation.speed_walk import ACTORS, report_markdown, report_tex

    result = {"scenarios": 3,
              "label_offsets": {"offset_levels": [-1, 0, 1],
                                "offset_probability": [0.25, 0.5, 0.25],
                                "entropy_nats": 1.04, "entropy_given_previous_nats": 0.9},
              "actors": {a: {"log_divergence_m": 1.0 + i, "offroad_pct_steps": 2.0,
                             "overlap_pct_steps": 3.5} for i, a in enumerate(ACTORS)}}
    tex = report_tex(result)
    assert r"\newcommand{\SpeedWalkProbs}{0.25, 0.50, 0.25}" in tex
    assert r"\newcommand{\SpeedWalkSampled}{3.00}" in tex
    assert r"\newcommand{\SpeedWalkHistory}{4.00}" in tex
    assert "| expert_steering_constant_speed | 2.00 | 2.00 | 3.50 |" in report_markdown(result)
