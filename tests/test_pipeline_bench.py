"""A stage's stamp records its processes' CPU seconds; ``bench pipeline`` groups them."""

from __future__ import annotations

import json

from igdrivsim.bench.pipeline import group_of, stage_costs, summarise
from igdrivsim.io import read_json
from igdrivsim.pipeline.profiles import PROFILES
from igdrivsim.pipeline.stages import Pipeline

BUSY = "import time; t = time.process_time(); exec('while time.process_time() - t < 0.6: pass')"
IDLE = "import time; time.sleep(0.6)"


def test_stamp_records_the_stage_processes_cpu_seconds(tmp_path):
    pipe = Pipeline(PROFILES["smoke"], tmp_path / "work", tmp_path / "paper", quiet=True)
    pipe.stage("busy", [["python", "-c", BUSY]])
    pipe.stage("idle", [["python", "-c", IDLE]])
    busy = read_json(pipe.stamp_path("busy"))
    idle = read_json(pipe.stamp_path("idle"))
    assert busy["cpu_seconds"] >= 0.6  # the child's own CPU time, read when it is reaped
    assert idle["seconds"] >= 0.6 and idle["cpu_seconds"] < busy["cpu_seconds"]
    costs = stage_costs(tmp_path / "work")
    assert {c["stage"] for c in costs} == {"busy", "idle"}


def test_groups_and_shares(tmp_path):
    assert [group_of(s) for s in ("data", "filter_training", "train_bc_rl-1of3",
                                  "evaluate_references", "maze", "render")] == [
        "data", "filter", "train", "evaluate", "maze", "other"]
    stamps = tmp_path / "stages"
    stamps.mkdir()
    for name, seconds, cpu in (("data", 10.0, 18.0), ("train_bc", 50.0, 60.0),
                               ("train_bc_rl-1of2", 40.0, None), ("render", 5.0, 2.0)):
        stamp = {"stage": name, "seconds": seconds, "finished": f"2026-01-01 00:00:{seconds:02.0f}"}
        if cpu is not None:
            stamp["cpu_seconds"] = cpu
        (stamps / f"{name}.json").write_text(json.dumps(stamp))
    groups = summarise(stage_costs(tmp_path))
    assert list(groups) == ["train", "data", "other"]  # most CPU first
    assert groups["train"]["cpu_seconds"] == 100.0  # a stamp without CPU counts its wall
    assert abs(sum(g["share"] for g in groups.values()) - 1.0) < 1e-3
