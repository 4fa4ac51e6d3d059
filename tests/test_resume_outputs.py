"""Interrupted work never leaves stale or torn results that a rerun would take as good."""

from __future__ import annotations

import json
import threading
import time

import pytest

from igdrivsim.cli import main
from igdrivsim.errors import IGDrivSimError
from igdrivsim.pipeline.profiles import PROFILES
from igdrivsim.pipeline.stages import Pipeline
from igdrivsim.report.figures import load_curves
from igdrivsim.training.run import truncate_jsonl


def test_a_killed_rerun_of_a_stage_is_not_taken_for_complete(tmp_path):
    pipe = Pipeline(PROFILES["smoke"], tmp_path, tmp_path / "paper", quiet=True)
    ok = [["python", "-c", "pass"]]
    assert pipe.stage("a", ok) and pipe.stamp_path("a").is_file()
    with pytest.raises(IGDrivSimError, match="failed"):  # the rerun dies half-way
        pipe.stage("a", [["python", "-c", "raise SystemExit(3)"]])
    assert not pipe.stamp_path("a").is_file()
    assert not Pipeline(PROFILES["smoke"], tmp_path, tmp_path / "paper").done("a")


def test_a_resumed_stage_counts_the_seconds_of_every_invocation(tmp_path):
    """A stage killed after some work and completed by a later invocation is stamped with the
    time of both (the interrupted one's kept in its .spent record)."""
    pipe = Pipeline(PROFILES["smoke"], tmp_path, tmp_path / "paper", quiet=True)
    slow = [["python", "-c", "import time; time.sleep(1.5)"]]
    with pytest.raises(IGDrivSimError, match="failed"):  # interrupted after ~1.5 s of work
        pipe.stage("a", [*slow, ["python", "-c", "raise SystemExit(3)"]])
    assert json.loads(pipe.spent_path("a").read_text())["seconds"] >= 1.5
    again = Pipeline(PROFILES["smoke"], tmp_path, tmp_path / "paper", quiet=True)
    assert again.stage("a", slow)
    assert again.stamp("a")["seconds"] >= 3.0 and not again.spent_path("a").exists()
    assert again.stage("a", [["python", "-c", "pass"]])  # other commands: counted anew
    assert again.stamp("a")["seconds"] < 1.5


def test_a_stage_s_seconds_do_not_compound_when_its_record_is_kept_often(tmp_path):
    """The run keeps the running stages' seconds every minute: written many times during one
    invocation, they still count that invocation once."""
    pipe = Pipeline(PROFILES["smoke"], tmp_path, tmp_path / "paper", quiet=True)
    stop = threading.Event()

    def keep() -> None:
        while not stop.wait(0.05):
            pipe.record_spent()

    keeper = threading.Thread(target=keep)
    keeper.start()
    start = time.monotonic()
    try:
        with pytest.raises(IGDrivSimError, match="failed"):
            pipe.stage("a", [["python", "-c", "import time; time.sleep(1.5); raise SystemExit(3)"]])
    finally:
        stop.set()
        keeper.join()
    elapsed = time.monotonic() - start  # counted once: at most the call's own wall time
    assert 1.5 <= json.loads(pipe.spent_path("a").read_text())["seconds"] <= elapsed + 0.1


def test_a_torn_log_line_is_dropped_on_resume(tmp_path):
    log = tmp_path / "metrics.jsonl"
    log.write_text('{"update": 1, "x": 1}\n{"update": 2, "x": 2}\n{"update": 3, "x"')
    truncate_jsonl(str(log), upto=5)
    assert [json.loads(line)["update"] for line in log.read_text().splitlines()] == [1, 2]
    truncate_jsonl(str(log), upto=1)
    assert log.read_text() == '{"update": 1, "x": 1}\n'


def test_generate_overwrite_leaves_no_shard_of_the_old_data(tmp_path):
    out = tmp_path / "data"
    base = ["generate", "--out", str(out), "--val", "0", "--no-progress", "--workers", "1"]
    assert main([*base, "--train", "4", "--shards", "2"]) == 0
    assert main([*base, "--train", "2", "--shards", "1", "--seed", "1", "--overwrite"]) == 0
    shards = sorted(p.name for p in (out / "training").iterdir())
    assert shards == ["training_tfexample.tfrecord-00000-of-00001"]


def test_learning_curves_merge_the_training_and_validation_lines_of_an_update(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    key = {"setting": "full", "method": "bc", "seed": 0, "update": 50}
    (run / "curves.jsonl").write_text(
        json.dumps({**key, "bc_loss": 1.4}) + "\n"
        + json.dumps({**key, "val_bc_loss": 1.5, "offroad": 0.1}) + "\n")
    curves = load_curves([run])
    assert len(curves) == 1
    assert curves.loc[0, "bc_loss"] == 1.4 and curves.loc[0, "val_bc_loss"] == 1.5


def test_a_run_names_the_code_that_trained_it_and_the_code_that_resumed_it(tmp_path,
                                                                           monkeypatch):
    from igdrivsim.machine import code_state
    from igdrivsim.training import run as run_module
    from igdrivsim.training.config import get_profile
    from igdrivsim.training.run import Run

    config = get_profile("smoke")
    first = Run(tmp_path, config)
    assert not first.complete_already()
    first.write_config(num_updates=2)
    started = json.loads((tmp_path / "config.json").read_text())["code"]
    assert started == code_state() and set(started) == {"commit", "dirty", "diff_hash"}
    other = {"commit": "0123abc", "dirty": True, "diff_hash": "feedfeedfeed"}
    monkeypatch.setattr(run_module, "code_state", lambda: dict(other))
    for _ in range(2):  # resumed twice under the other code: listed once
        again = Run(tmp_path, config, resume=True)
        assert not again.complete_already()
        again.write_config(num_updates=2)
    record = json.loads((tmp_path / "config.json").read_text())
    assert record["code"] == started and record["code_resumed"] == [other]
