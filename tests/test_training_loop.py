"""End to end on the smoke profile: BC-RL training, resume, seeds, multi-device equivalence.

One compiled update (smoke, bc_rl) is shared by every in-process run of this module; the
4-device run happens in a subprocess (``--xla_force_host_platform_device_count=4``).
"""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys

import jax
import numpy as np
import pandas as pd
import pytest
from conftest import write_toy_shard

from igdrivsim.cli import main as cli_main
from igdrivsim.training import inputs
from igdrivsim.training.config import get_profile, with_overrides
from igdrivsim.training.loop import train
from igdrivsim.training.run import Run

CONFIG = with_overrides(get_profile("smoke"), ["training.method=bc_rl"])


def _max_diff(a, b) -> float:
    diffs = jax.tree.map(lambda x, y: float(np.abs(np.asarray(x) - np.asarray(y)).max()), a, b)
    return max(jax.tree.leaves(diffs))


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory):
    """Eight toy straight-road scenarios (different speeds and lanes) as a tf.Example shard."""
    return write_toy_shard(tmp_path_factory.mktemp("toy"), CONFIG)


@pytest.fixture(scope="module")
def full_run(data_dir, tmp_path_factory):
    out = tmp_path_factory.mktemp("runs") / "full"
    result = train(CONFIG, data_dir, out, progress=False, log=lambda *_: None)
    return out, result


def test_run_writes_config_metrics_checkpoints(full_run):
    out, result = full_run
    assert result.complete and result.updates_done == CONFIG.training.num_updates
    record = json.loads((out / "config.json").read_text())
    assert record["config"]["training"]["method"] == "bc_rl"
    lines = [json.loads(x) for x in (out / "metrics.jsonl").read_text().splitlines()]
    assert [x["update"] for x in lines] == [1, 2, 3, 4]
    for key in ("bc_loss", "lr", "entropy", "mean_return", "ppo_loss", "updates_per_s"):
        assert all(np.isfinite(x[key]) for x in lines), key
    # BC loss goes down; PPO's ratio moves away from 1 after the first minibatch step.
    assert lines[-1]["bc_loss"] < lines[0]["bc_loss"]
    assert lines[0]["bc_loss"] == pytest.approx(3 * np.log(257), rel=0.05)
    assert all(x["ratio_dev"] > 0 for x in lines)
    assert sorted(os.listdir(out / "checkpoints")) == ["2", "4"]
    # Seeds are different networks trained on different batches ([settings, seeds, ...]).
    leaves = jax.tree.leaves(result.params)
    assert all(x.shape[:2] == (1, CONFIG.training.seeds) for x in leaves)
    assert any(not np.allclose(x[0, 0], x[0, 1]) for x in leaves)


def test_open_run_and_complete_run_is_left_alone(full_run, data_dir, capsys):
    out, result = full_run
    run = Run.open(out)
    config, params = run.config, run.params()
    assert config == CONFIG.validate() and run.complete and run.latest_step() == 4
    assert [line["update"] for line in run.metrics()] == [1, 2, 3, 4]
    assert {line["update"] for line in run.curves()} == {1, 2, 3, 4}
    assert _max_diff(params, result.params) == 0.0
    code = cli_main(["train", "--profile", "smoke", "--method", "bc_rl", "--data", data_dir,
                     "--out", str(out), "--no-progress"])
    assert code == 0 and "already complete" in capsys.readouterr().out


def test_resume_reaches_the_same_parameters(full_run, data_dir, tmp_path):
    _, result = full_run
    out = tmp_path / "resumed"
    first = train(CONFIG, data_dir, out, stop_after=2, progress=False, log=lambda *_: None)
    assert not first.complete and first.updates_done == 2
    with pytest.raises(Exception, match="--resume"):
        train(CONFIG, data_dir, out, progress=False, log=lambda *_: None)
    other_lr = dataclasses.replace(CONFIG, training=dataclasses.replace(
        CONFIG.training, lr=CONFIG.training.lr * 2))
    with pytest.raises(Exception, match="different configuration"):
        train(other_lr, data_dir, out, resume=True, progress=False, log=lambda *_: None)
    # how often it is checkpointed is bookkeeping: the run resumes under another value
    kept_otherwise = dataclasses.replace(CONFIG, training=dataclasses.replace(
        CONFIG.training, checkpoint_every=1, max_checkpoints=3))
    second = train(kept_otherwise, data_dir, out, resume=True, progress=False,
                   log=lambda *_: None)
    assert second.complete
    assert _max_diff(second.params, result.params) == 0.0
    lines = [json.loads(x) for x in (out / "metrics.jsonl").read_text().splitlines()]
    assert [x["update"] for x in lines] == [1, 2, 3, 4]


def test_batches_are_a_function_of_seed_and_update():
    a = inputs.batch_indices(10, 4, seed=1, update=3)
    np.testing.assert_array_equal(a, inputs.batch_indices(10, 4, seed=1, update=3))
    assert not np.array_equal(a, inputs.batch_indices(10, 4, seed=2, update=3))
    # Each epoch is a permutation: 5 updates of 4 over 10 scenarios cover each twice.
    seen = np.concatenate([inputs.batch_indices(10, 4, 0, u) for u in range(5)])
    np.testing.assert_array_equal(np.bincount(seen, minlength=10), np.full(10, 2))


def test_bad_override_is_a_one_line_error(capsys, data_dir, tmp_path):
    code = cli_main(["train", "--profile", "smoke", "--data", data_dir, "--out",
                     str(tmp_path / "x"), "--set", "training.nope=1"])
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert "unknown field" in err and len(err.splitlines()) == 1


def test_four_devices_match_one_device(full_run, data_dir, tmp_path):
    _, result = full_run
    out = tmp_path / "four"
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=4",
               JAX_PLATFORMS="cpu")
    cmd = [sys.executable, "-m", "igdrivsim.cli", "train", "--profile", "smoke", "--method",
           "bc_rl", "--data", data_dir, "--out", str(out), "--no-progress"]
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert json.loads((out / "config.json").read_text())["devices"] == 4
    params = Run.open(out).params()
    assert _max_diff(params, result.params) < 1e-4


def test_evaluation_on_four_devices_matches_one_device(full_run, data_dir, tmp_path):
    """Evaluation spreads each batch's scenarios over every device (7 scenarios in batches of
    5: padded to multiples of 4) and gives the one-device numbers."""
    run, _ = full_run
    args = ["evaluate", str(run), "--data", data_dir, "--limit", "7", "--batch-size", "5",
            "--references", "--no-progress"]
    assert cli_main([*args, "--out", str(tmp_path / "one")]) == 0
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=4",
               JAX_PLATFORMS="cpu")
    cmd = [sys.executable, "-m", "igdrivsim.cli", *args, "--out", str(tmp_path / "four")]
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    for name in ("per_scenario.csv", "references/per_scenario.csv"):
        one = pd.read_csv(tmp_path / "one" / name)
        four = pd.read_csv(tmp_path / "four" / name)
        assert len(one) == len(four) > 0 and list(one.columns) == list(four.columns)
        numeric = one.select_dtypes("number").columns
        np.testing.assert_allclose(four[numeric], one[numeric], atol=1e-4)


def test_a_runs_derived_values_are_its_configs():
    """Settings, seeds, capacities, observation and simulator settings are computed in one
    place (RunConfig), and the update, the input and the evaluation take them from there."""
    from igdrivsim.data.scenario import Capacities
    from igdrivsim.observation import ObservationConfig
    from igdrivsim.training.update import update_spec

    config = with_overrides(CONFIG, ["observation.setting=full, circular_r4",
                                     "training.seed_offset=3", "observation.roadgraph_stride=2"])
    assert config.settings == ("full", "circular_r4") and config.seeds == (3, 4)
    assert config.capacities == Capacities(max_objects=config.data.max_objects,
                                           max_roadgraph_points=config.data.max_roadgraph_points)
    o = config.observation
    assert config.obs_config == ObservationConfig(o.num_objects, o.num_roadgraph_points)
    assert config.sim_params.roadgraph_stride == 2
    spec = update_spec(config.validate())
    assert (spec.obs, spec.sim, spec.record) == (config.obs_config, config.sim_params,
                                                 config.record_config)
    assert config.record_config.num_objects >= config.obs_config.num_objects
