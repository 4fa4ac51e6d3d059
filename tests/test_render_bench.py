"""``igdrivsim bench sim``: the package's road-edge path equals the Waymax port, and the CLI."""

from __future__ import annotations

from pathlib import Path

import jax
import numpy as np
import pytest

from igdrivsim.observation import ObservationConfig

WOMD = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "womd"
EXAMPLE = WOMD / "motion_data_one_example.tfrecord"
needs_womd = pytest.mark.skipif(not EXAMPLE.exists(), reason=f"real WOMD sample absent: {EXAMPLE}")


@needs_womd
def test_igdrivsim_path_equals_the_waymax_port_on_a_real_scenario():
    """The road-edge array gives the same offroad (and every other metric) as Waymax's test
    against every roadgraph point, and both observe the same thing, at every step."""
    from igdrivsim.bench.sim import _batch, episode
    from igdrivsim.data import load_scenario

    sc = _batch([load_scenario(EXAMPLE)], 2)  # different noise for the two examples
    cfg = ObservationConfig(num_objects=8, num_roadgraph_points=128)
    common = dict(setting_name="gaussian_noise", collect=True, obs_config=cfg)
    key = jax.random.PRNGKey(3)
    naive = jax.jit(lambda s, k: episode(s, k, impl="naive", **common))(sc, key)
    ours = jax.jit(lambda s, k: episode(s, k, impl="igdrivsim", **common))(sc, key)
    (m_n, _, o_n), (m_o, _, o_o) = naive, ours
    np.testing.assert_array_equal(m_n.overlap, m_o.overlap)
    np.testing.assert_array_equal(m_n.offroad, m_o.offroad)
    np.testing.assert_allclose(m_n.log_divergence, m_o.log_divergence, atol=1e-6)
    np.testing.assert_allclose(o_n.objects, o_o.objects, atol=1e-6)
    np.testing.assert_allclose(o_n.roadgraph, o_o.roadgraph, atol=1e-6)
    assert np.abs(np.asarray(o_n.sdc_yaw_rate)).max() > 0  # the policy turns: rates are seen
    assert np.asarray(o_n.roadgraph_valid).sum(-1).min() == 128


def test_bench_cli_rejects_bad_options(capsys):
    from igdrivsim.cli import main

    assert main(["bench", "sim", "--batch-sizes", "1,x"]) == 2
    assert main(["bench", "sim", "--impls", "naive,bogus"]) == 2
    assert main(["bench", "sim", "--repeats", "0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 3 and all(e.startswith("igdrivsim bench sim: error:") for e in err)


@needs_womd
@pytest.mark.parametrize("distinct", [False, True])
def test_bench_cli_writes_rows(tmp_path, capsys, distinct):
    import json

    from igdrivsim.cli import main

    out = tmp_path / "bench.json"
    assert main(["bench", "sim", "--batch-sizes", "2", "--impls", "igdrivsim", "--repeats", "1",
                 "--out", str(out)] + (["--distinct", "--data", str(WOMD)] if distinct else [])
                ) == 0
    result = json.loads(out.read_text())
    assert result["distinct"] is distinct
    rows = result["rows"]
    assert [(r["batch"], r["impl"], r["agents"]) for r in rows] == [
        (2, "igdrivsim", "log"), (2, "igdrivsim+idm", "idm")]  # both sim agents in one run
    assert all(r["scenario_steps_per_s"] > 0 and r["offroad_steps"] == 0 for r in rows)
    out = capsys.readouterr().out
    assert "igdrivsim+idm" in out and "idm cost" in out
