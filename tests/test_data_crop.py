"""The load-time roadgraph crop keeps the map along the SDC's whole logged path."""

from pathlib import Path

import numpy as np
import pytest

from igdrivsim.data import Capacities, fit_to_capacities, load_scenario

SAMPLE = (Path(__file__).resolve().parents[1]
          / "../shared/data/womd/motion_data_one_example.tfrecord")


@pytest.mark.skipif(not SAMPLE.exists(), reason="real WOMD sample not present")
def test_crop_covers_the_end_of_the_logged_path():
    scenario = load_scenario(str(SAMPLE))
    small = fit_to_capacities(scenario, Capacities(max_objects=16, max_roadgraph_points=512))
    sdc = int(np.argmax(small.metadata.is_sdc))
    valid = np.asarray(small.trajectory.valid[sdc])
    last = np.flatnonzero(valid)[-1]
    end = np.array([small.trajectory.x[sdc, last], small.trajectory.y[sdc, last]])
    kept = np.asarray(small.roadgraph.xyz)[np.asarray(small.roadgraph.valid), :2]
    assert len(kept) == 512
    assert np.linalg.norm(kept - end, axis=-1).min() < 5.0
