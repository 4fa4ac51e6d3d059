"""Streaming input (``data.stream``, the paper profile): shards, order, resume, two processes.

The two-process test starts two ``jax.distributed`` processes on this CPU (local coordinator,
Gloo collectives) through the same environment variables as ``igdrivsim train``.
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys

import jax
import numpy as np
import pytest

from igdrivsim.data import write_tfexample
from igdrivsim.simulator import toy
from igdrivsim.training.config import get_profile, with_overrides
from igdrivsim.training.loop import train
from igdrivsim.training.stream import ScenarioIndex, StreamDataset
from igdrivsim.training.update import update_spec

STREAM = ["training.method=bc", "data.record_teacher=false", "data.stream=true",
          "data.shards=2", "training.num_updates=3"]
CONFIG = with_overrides(get_profile("smoke"), STREAM)
QUIET = dict(progress=False, log=lambda *_: None)


def _max_diff(a, b) -> float:
    diffs = jax.tree.map(lambda x, y: float(np.abs(np.asarray(x) - np.asarray(y)).max()), a, b)
    return max(jax.tree.leaves(diffs))


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory):
    caps = CONFIG.capacities
    path = tmp_path_factory.mktemp("stream") / "train.tfrecord"
    write_tfexample(path, [toy.straight_road(caps, speed=3.0 + i, scenario_id=f"s{i}")
                           for i in range(8)])
    return str(path.parent)


@pytest.fixture(scope="module")
def one_process(data_dir, tmp_path_factory):
    """The reference: one process reading both shards (the same global batches)."""
    return train(CONFIG, data_dir, tmp_path_factory.mktemp("runs") / "one", **QUIET)


def test_shards_are_disjoint_and_each_epoch_a_permutation(data_dir):
    source = ScenarioIndex(data_dir, CONFIG.capacities)
    assert len(source) == 8 and source.refs.nbytes == 8 * 8  # 8 bytes per scenario
    sim = update_spec(CONFIG).sim
    parts = [StreamDataset(source, 4, [0, 1], sim, 2, process=p, processes=2) for p in (0, 1)]
    for u in range(4):
        a, b = (ds.indices(u) for ds in parts)
        assert a.shape == b.shape == (2, 2)
        assert not set(a.ravel()) & set(b.ravel())
        assert set(a.ravel()) <= {0, 2, 4, 6} and set(b.ravel()) <= {1, 3, 5, 7}
    # an epoch of a shard (4 scenarios, 2 per update) is a permutation; epochs differ
    epochs = [np.concatenate([parts[0].indices(u)[0] for u in (e, e + 1)]) for e in (0, 2, 4)]
    assert all(sorted(e) == [0, 2, 4, 6] for e in epochs)
    assert len({tuple(e) for e in epochs}) > 1
    again = StreamDataset(source, 4, [0, 1], sim, 2, process=0, processes=2)
    assert np.array_equal(again.indices(7), parts[0].indices(7))  # a function of (seed, u)
    # the host batch is a few reset states, not the dataset
    _, states = parts[0].host_batch(0)
    assert states.timestep.shape == (2, 2)


def test_resume_reaches_the_same_parameters(one_process, data_dir, tmp_path):
    out = tmp_path / "resumed"
    first = train(CONFIG, data_dir, out, stop_after=2, **QUIET)
    assert not first.complete
    saved = json.loads((out / "checkpoints" / "data" / "2.p0.json").read_text())
    assert saved["iterator"] == {"next_index": 2}  # Grain's iterator state
    second = train(CONFIG, data_dir, out, resume=True, **QUIET)
    assert second.complete
    assert _max_diff(second.params, one_process.params) == 0.0


WORKER = """
import json, sys
import numpy as np
from igdrivsim.core.devices import maybe_init_distributed
maybe_init_distributed()
import jax
from igdrivsim.training.config import get_profile, with_overrides
from igdrivsim.training.loop import train
from igdrivsim.training.stream import StreamDataset
from igdrivsim.training.update import update_spec
data, out, dump = sys.argv[1:4]
config = with_overrides(get_profile("smoke"), sys.argv[4:])
ds = StreamDataset.from_config(config, data, update_spec(config).sim)
ids = [ds.indices(u).tolist() for u in range(config.training.num_updates)]
result = train(config, data, out, progress=False, log=lambda *_: None)
leaves = [np.asarray(x.addressable_data(0)) for x in jax.tree.leaves(result.params)]
np.savez(dump + ".npz", *leaves)
from igdrivsim.evaluation.evaluate import evaluate_run
evaluate_run(out, data, out + "_eval", max_scenarios=6, batch_size=4, progress=False)
json.dump({"process": jax.process_index(), "processes": jax.process_count(),
           "devices": jax.device_count(), "indices": ids}, open(dump + ".json", "w"))
from jax.experimental import multihost_utils
multihost_utils.sync_global_devices("done")
jax.distributed.shutdown()
"""


def _wait(procs, timeout: float) -> list[str]:
    """The workers' outputs; any still running after ``timeout`` seconds is killed (and
    fails the test through its exit code)."""
    outs = []
    try:
        outs = [proc.communicate(timeout=timeout)[0] for proc in procs]
    finally:
        for proc in procs:  # never leave a process behind
            if proc.poll() is None:
                proc.kill()
        outs = outs or [proc.communicate()[0] for proc in procs]
    return outs


@pytest.mark.slow
def test_two_processes_match_one_process(one_process, data_dir, tmp_path):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    procs = []
    for p in (0, 1):
        env = dict(os.environ, JAX_PLATFORMS="cpu", JAX_COORDINATOR_ADDRESS=f"127.0.0.1:{port}",
                   JAX_NUM_PROCESSES="2", JAX_PROCESS_ID=str(p))
        env.pop("XLA_FLAGS", None)
        cmd = [sys.executable, "-c", WORKER, data_dir, str(tmp_path / "two"),
               str(tmp_path / f"p{p}"), *STREAM]
        procs.append(subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE,
                                      stderr=subprocess.STDOUT, text=True))
    outs = _wait(procs, timeout=420)
    for proc, out in zip(procs, outs, strict=True):  # both exit by themselves, cleanly
        assert proc.returncode == 0, out[-2000:]
    info = [json.loads((tmp_path / f"p{p}.json").read_text()) for p in (0, 1)]
    assert [i["process"] for i in info] == [0, 1]
    assert all(i["processes"] == 2 and i["devices"] == 2 for i in info)
    for u in range(3):  # disjoint scenarios, every update
        a, b = (set(np.ravel(i["indices"][u])) for i in info)
        assert a and b and not a & b
    params = [list(np.load(tmp_path / f"p{p}.npz").values()) for p in (0, 1)]
    assert all(np.array_equal(x, y) for x, y in zip(*params, strict=True))  # identical
    reference = [np.asarray(x) for x in jax.tree.leaves(one_process.params)]
    assert max(float(np.abs(x - y).max()) for x, y in zip(params[0], reference,
                                                          strict=True)) < 1e-4
    assert json.loads((tmp_path / "two" / "config.json").read_text())["processes"] == 2
    # evaluation spread over both processes' devices = one process evaluating the same run
    from igdrivsim.evaluation.evaluate import evaluate_run

    evaluate_run(str(tmp_path / "two"), data_dir, tmp_path / "one_eval", max_scenarios=6,
                 batch_size=4, progress=False)
    import pandas as pd

    two, one = (pd.read_csv(tmp_path / d / "per_scenario.csv") for d in ("two_eval", "one_eval"))
    assert len(two) == len(one) > 0
    numeric = one.select_dtypes("number").columns
    np.testing.assert_allclose(two[numeric], one[numeric], atol=1e-4)


def test_paper_and_gpu_profiles_on_cpu_warn_with_the_cost_estimate(capsys):
    from igdrivsim.training import cost
    from igdrivsim.training.cost import PAPER_SCENARIOS, warn_if_cpu

    paper = with_overrides(get_profile("paper"), ["observation.setting=full"])
    assert paper.total_updates(PAPER_SCENARIOS) == 119_382  # 200 epochs of 256 scenarios
    msg = warn_if_cpu(paper, PAPER_SCENARIOS, "cpu", 1)
    assert msg and capsys.readouterr().err.count("\n") == 1
    hours = 119_382 * 256 * 3 * cost.CPU_SECONDS_PER_EPISODE / 3600  # one setting, 3 seeds
    assert f"~{hours:,.0f} hours" in msg
    table = cost.table1_hours(1.0, 2.0)  # 6 settings x 3 seeds x 256 scenarios per update
    assert table["total"] == pytest.approx(119_382 * 6 * 3 * 256 * 3.0 / 3600)
    assert "Table I at paper scale" in cost.table1_text(gpu=True)
    assert warn_if_cpu(paper, PAPER_SCENARIOS, "gpu", 8) is None
    assert warn_if_cpu(get_profile("laptop"), 1000, "cpu", 1) is None
    gpu = warn_if_cpu(get_profile("gpu"), 1000, "cpu", 1)
    assert gpu and "12 seeds, 4x the laptop" in gpu and "~10 h" in gpu  # 1,000 x 6 x 4 x 3.0 s / 2
    assert warn_if_cpu(get_profile("gpu"), 1000, "gpu", 1) is None
    short = with_overrides(get_profile("gpu"), ["training.seeds=3"])
    assert warn_if_cpu(short, 1000, "cpu", 1) is None


@pytest.mark.slow
def test_kill_9_and_resume_reach_the_uninterrupted_parameters(data_dir, tmp_path):
    import signal
    import time

    sets = [*STREAM[:-1], "training.num_updates=30", "training.checkpoint_every=2",
            "training.log_every=1"]
    config = with_overrides(get_profile("smoke"), sets)
    cmd = [sys.executable, "-m", "igdrivsim.cli", "train", "--profile", "smoke", "--data",
           data_dir, "--out", str(tmp_path / "killed"), "--no-progress",
           *[a for s in sets for a in ("--set", s)]]
    env = dict(os.environ, JAX_PLATFORMS="cpu")
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    ckpts = tmp_path / "killed" / "checkpoints"
    deadline = time.time() + 120
    while time.time() < deadline and proc.poll() is None:
        if (ckpts / "4").is_dir():
            break
        time.sleep(0.01)
    assert proc.poll() is None, proc.stderr.read()[-2000:]
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert not (tmp_path / "killed" / "DONE").exists()
    resumed = subprocess.run(cmd + ["--resume"], env=env, capture_output=True, text=True,
                             timeout=300)
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    assert "resuming from update" in resumed.stdout + resumed.stderr
    from igdrivsim.training.run import Run

    params = Run.open(tmp_path / "killed").params()
    whole = train(config, data_dir, tmp_path / "whole", **QUIET)
    assert _max_diff(params, whole.params) < 1e-6
