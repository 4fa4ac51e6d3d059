"""The pipeline's lanes (real subprocesses, trivial commands): the methods train side by side,
stages beside each other log and report progress, a failure stops the other lanes; the grid's
split over the workers and the plan printed before any stage."""

from __future__ import annotations

import json
import os
import threading
import time
from pathlib import Path

import pytest

from igdrivsim.names import SETTINGS
from igdrivsim.pipeline import planning, runner
from igdrivsim.pipeline.cli import build_parser, pipeline_from_args
from igdrivsim.pipeline.profiles import PROFILES
from igdrivsim.pipeline.runner import StageError
from igdrivsim.pipeline.stages import Pipeline


def _pipeline(tmp: Path, monkeypatch, fail: str | None = None,
              methods: tuple[str, ...] = ("bc_rl", "bc")) -> Pipeline:
    pipe = Pipeline(PROFILES["smoke"], tmp / "work", tmp / "paper", quiet=False,
                       settings=("full",), methods=methods, workers=2)
    times = tmp / "times.jsonl"

    def fake(name, echo, seconds=1.0):
        code = (f"import json,time; t=time.time(); print('step 1/2', flush=True); "
                f"time.sleep({seconds}); print('step 2/2 {name}', flush=True); "
                f"open({str(times)!r}, 'a').write(json.dumps(["
                f"{name!r}, t, time.time()]) + chr(10)); "
                f"raise SystemExit(3 if {name == fail} else 0)")
        pipe.stage(name, [["python", "-c", code]], echo=echo)

    monkeypatch.setattr(runner, "HEARTBEAT_S", 0.0)
    monkeypatch.setattr(pipe, "_machine", planning.Machine(2, "test CPU"))  # not probed
    monkeypatch.setattr(pipe, "check_work_folder", lambda: None)
    monkeypatch.setattr(pipe, "run_data", lambda: ("train", "val"))
    monkeypatch.setattr(pipe, "run_filter", lambda a, b: (Path(a), Path(b)))
    monkeypatch.setattr(pipe, "run_train", lambda part, a, b, echo: fake(
        f"train_{part.name}", echo, 1.5))
    suffix = {"log": "", "idm": "_idm"}  # the sim agents' stage-name suffix
    monkeypatch.setattr(pipe, "run_evaluate", lambda m, v, echo=True, agents="log", like=None:
                        fake(f"evaluate_{m}{suffix[agents]}", echo))
    monkeypatch.setattr(pipe, "run_reactive", lambda parts: fake("reactive", True, 0.1))
    monkeypatch.setattr(pipe, "run_speed_walk", lambda v, echo=True: fake("speed_walk", echo))
    monkeypatch.setattr(pipe, "run_maze", lambda echo=True: fake("maze", echo, 3.0))
    monkeypatch.setattr(pipe, "run_render", lambda v, echo=True: fake("render", echo))
    monkeypatch.setattr(pipe, "run_teacher", lambda c: fake("teacher", True, 0.1))
    monkeypatch.setattr(pipe, "run_report", lambda e, u, p: fake("report", True, 0.1))
    monkeypatch.setattr(pipe, "run_pdf", lambda: None)
    monkeypatch.setattr(pipe, "publish", lambda: [])
    pipe.times = times
    return pipe


def _spans(path: Path) -> dict[str, tuple[float, float]]:
    return {n: (a, b) for n, a, b in map(json.loads, path.read_text().splitlines())}


def test_methods_train_side_by_side_and_report_progress(tmp_path, monkeypatch, capsys):
    pipe = _pipeline(tmp_path, monkeypatch)
    pipe.run()
    spans = _spans(pipe.times)
    assert set(spans) == {"train_bc_rl", "evaluate_bc_rl", "train_bc", "evaluate_bc",
                          "evaluate_references", "speed_walk", "maze", "render", "report",
                          "evaluate_bc_rl_idm", "evaluate_bc_idm", "evaluate_references_idm",
                          "reactive"}
    (a0, a1), (b0, b1) = spans["train_bc_rl"], spans["train_bc"]
    assert a0 < b1 and b0 < a1  # the two trainings overlap in time
    assert spans["report"][0] >= max(end for name, (_, end) in spans.items() if name not in (
        "report", "reactive")) - 1e-3  # the report waits for both lanes
    assert spans["reactive"][0] >= spans["report"][1] - 1e-3  # after every evaluation
    err = capsys.readouterr().err
    assert "train_bc: step 2/2 train_bc" in err or "train_bc: step 1/2" in err
    assert "step 2/2 train_bc_rl" in (pipe.work / "logs" / "train_bc_rl.log").read_text()


def test_a_failing_lane_stops_the_other(tmp_path, monkeypatch):
    pipe = _pipeline(tmp_path, monkeypatch, fail="train_bc_rl")
    start = time.time()
    with pytest.raises(StageError, match="train_bc_rl"):
        pipe.run()
    spans = _spans(pipe.times)
    assert "report" not in spans and "render" not in spans
    assert time.time() - start < 6.0  # the other lane did not run on to its end


def test_methods_option_reads_the_registry():
    from igdrivsim.errors import ConfigError

    args = build_parser().parse_args(["--profile", "smoke", "--methods", "bc"])
    assert pipeline_from_args(args).methods == ("bc",)
    default = pipeline_from_args(build_parser().parse_args(["--profile", "smoke"]))
    assert default.methods == ("bc_rl", "bc")
    with pytest.raises(ConfigError, match="unknown learning method 'nope'"):
        pipeline_from_args(build_parser().parse_args(["--methods", "bc,nope"]))
    with pytest.raises(ConfigError, match="privileged teacher needs a method without one"):
        pipeline_from_args(build_parser().parse_args(["--methods", "dagger"]))
    with pytest.raises(ConfigError, match="privileged teacher needs"):
        pipeline_from_args(build_parser().parse_args(
            ["--methods", "bc,dagger", "--obs", "circular_r4"]))


def test_taught_methods_train_after_the_teacher_is_chosen(tmp_path, monkeypatch):
    pipe = _pipeline(tmp_path, monkeypatch, methods=("bc", "dagger", "advisor"))
    pipe.run()
    spans = _spans(pipe.times)
    assert spans["teacher"][0] >= spans["train_bc"][1]
    (d0, d1), (a0, a1) = spans["train_dagger"], spans["train_advisor"]
    assert min(d0, a0) >= spans["teacher"][1] and d0 < a1 and a0 < d1  # side by side
    assert spans["report"][0] >= max(spans["evaluate_dagger"][1], spans["evaluate_advisor"][1])


def test_stage_processes_take_gpu_memory_as_needed(tmp_path, monkeypatch):
    """Two lanes on one GPU: neither process may take most of its memory up front."""
    monkeypatch.delenv("XLA_PYTHON_CLIENT_PREALLOCATE", raising=False)
    pipe = Pipeline(PROFILES["smoke"], tmp_path / "work", tmp_path / "paper", quiet=True)
    seen = tmp_path / "env.txt"
    code = (f"import os; open({str(seen)!r}, 'w').write("
            "os.environ.get('XLA_PYTHON_CLIENT_PREALLOCATE', 'unset'))")
    pipe.stage("probe", [["python", "-c", code]])
    assert seen.read_text() == "false"


@pytest.mark.skipif(len(getattr(os, "sched_getaffinity", lambda _: ())(0)) < 2,
                    reason="needs the CPU affinity API and 2 cores")
def test_side_by_side_workers_on_a_cpu_get_a_core_each(tmp_path, monkeypatch):
    """Two lanes at once on a 2-core CPU: each worker runs on its own core (XLA's thread pool
    would otherwise compete with the other's), a stage run alone is not pinned, and the cores
    come back when the workers end."""
    cores = sorted(os.sched_getaffinity(0))
    pipe = Pipeline(PROFILES["smoke"], tmp_path / "work", tmp_path / "paper", quiet=True,
                    workers=2)
    monkeypatch.setattr(pipe, "_machine", planning.Machine(2, "test CPU"))
    monkeypatch.setattr(pipe, "free_cores", cores[:2])
    seen = tmp_path / "cores"
    seen.mkdir()

    def probe(name: str, echo: bool) -> None:
        code = (f"import os, time; time.sleep(1.0); open({str(seen / name)!r}, 'w').write("
                "' '.join(map(str, sorted(os.sched_getaffinity(0)))))")
        pipe.stage(name, [["python", "-c", code]], echo=echo)

    lanes = [threading.Thread(target=probe, args=(f"lane{i}", False)) for i in range(2)]
    for lane in lanes:
        lane.start()
    for lane in lanes:
        lane.join(timeout=60)
    pinned = [(seen / f"lane{i}").read_text().split() for i in range(2)]
    assert all(len(p) == 1 for p in pinned) and pinned[0] != pinned[1]
    assert sorted(pipe.free_cores) == cores[:2]
    probe("alone", True)
    assert len((seen / "alone").read_text().split()) == len(cores)


def test_gpu_profile_trains_the_laptop_updates_with_more_seeds():
    import dataclasses

    from igdrivsim.training.config import get_profile

    laptop, gpu, quick = get_profile("laptop"), get_profile("gpu"), get_profile("quick")
    assert gpu.training.num_updates == laptop.training.num_updates == 1000
    assert quick.training.num_updates == 300 and gpu.training.seeds > laptop.training.seeds
    same = dataclasses.replace(gpu, profile="laptop", training=laptop.training)
    assert same == laptop  # network, data, observation: the laptop's
    g, lap = PROFILES["gpu"], PROFILES["laptop"]
    assert g.train_scenarios == lap.train_scenarios and g.seeds == gpu.training.seeds
    assert g.val_scenarios > lap.val_scenarios


def test_grid_split_keeps_every_worker_busy_and_the_plan_comes_first(tmp_path, monkeypatch,
                                                                      capsys):
    from igdrivsim.names import METHODS

    seconds = planning.part_seconds("laptop", 3, 1000, False)
    for workers in (1, 2, 4, 8):
        parts = planning.split_grid(METHODS, SETTINGS, workers, seconds, [534.0])
        cells = sorted((p.method, s) for p in parts for s in p.settings)
        assert cells == sorted((m, s) for m in METHODS for s in SETTINGS)  # each cell once
        assert len(parts) >= min(workers, 2)
    one = planning.estimate_seconds("laptop", METHODS, (), SETTINGS, 3, 1000, 1)
    two = planning.estimate_seconds("laptop", METHODS, (), SETTINGS, 3, 1000, 2)
    assert one and two and 1.6 < one / two < 2.0 and two < 3 * 3600
    pipe = Pipeline(PROFILES["quick"], tmp_path / "work", tmp_path / "paper", workers=0)
    monkeypatch.setattr(pipe, "_machine", planning.Machine(2, "test CPU"))

    def first_stage():
        raise RuntimeError("the first stage")

    monkeypatch.setattr(pipe, "run_data", first_stage)
    with pytest.raises(RuntimeError, match="the first stage"):
        pipe.run()
    err = capsys.readouterr().err
    assert "plan: estimated wall time ~" in err and "below the competence targets" in err
    assert "test CPU, 2 cores; 2 worker process(es), one XLA thread each" in err


def test_a_resumed_run_is_priced_for_what_is_left():
    """The methods run after the default run: only the taught methods' training is left, and
    of a part checkpointed halfway, half."""
    plain, taught = ("bc", "bc_rl"), ("dagger", "advisor")
    whole = planning.estimate_seconds("laptop", plain, taught, SETTINGS, 3, 1000, 2)
    seconds = planning.part_seconds("laptop", 3, 1000, False)
    first = planning.split_grid(plain, SETTINGS, 2, seconds, [planning.cost.MAZE_CPU_S])
    complete = {f"train_{p.name}" for p in first} | {"maze"}
    left = planning.estimate_seconds("laptop", plain, taught, SETTINGS, 3, 1000, 2,
                                     left=lambda stage: float(stage not in complete))
    second = planning.split_grid(taught, [s for s in SETTINGS if s != "full"], 2, seconds)
    assert left == pytest.approx(planning.makespan([p.seconds for p in second], 2)
                                 + planning.cost.LAPTOP_OTHER_CPU_S)
    assert whole and 0 < left < whole
    halfway = planning.estimate_seconds(  # the taught parts checkpointed at half their updates
        "laptop", plain, taught, SETTINGS, 3, 1000, 2,
        left=lambda stage: 0.0 if stage in complete else 0.5 if stage.startswith("train_") else 1)
    assert halfway == pytest.approx(0.5 * planning.makespan([p.seconds for p in second], 2)
                                    + planning.cost.LAPTOP_OTHER_CPU_S)
    everything = complete | {f"train_{p.name}" for p in second} | {"report"}
    assert planning.estimate_seconds("laptop", plain, taught, SETTINGS, 3, 1000, 2,
                                     left=lambda stage: float(stage not in everything)) == 0


def test_stop_terminates_the_running_stage_processes(tmp_path, monkeypatch):
    """An interrupted run (Ctrl-C, or SIGTERM, which main turns into the same) leaves no stage
    process behind: ``stop`` terminates every running one and no later stage starts."""
    pipe = _pipeline(tmp_path, monkeypatch)
    lane = threading.Thread(target=lambda: pytest.raises(
        StageError, pipe.stage, "sleeper", [["python", "-c", "import time; time.sleep(60)"]],
        echo=False))
    lane.start()
    deadline = time.time() + 30
    while not pipe.children and time.time() < deadline:
        time.sleep(0.05)
    (proc,) = pipe.children
    pipe.stop()
    lane.join(timeout=30)
    assert not lane.is_alive() and proc.poll() is not None and not pipe.children
    with pytest.raises(StageError, match="not started"):
        pipe.stage("later", [["python", "-c", "pass"]])


def test_stamps_say_where_each_training_part_ran(tmp_path, monkeypatch):
    """A run resumed on another machine (the taught methods trained on a GPU, say) states both
    machines in its provenance, each with its parts; stamps from before the field count as
    this machine's."""
    pipe = Pipeline(PROFILES["smoke"], tmp_path / "work", tmp_path / "paper", workers=2,
                    methods=("bc", "bc_rl", "dagger"))
    monkeypatch.setattr(pipe, "_machine", planning.Machine(2, "test CPU"))
    assert pipe.stage("train_bc", [["python", "-c", "pass"]])
    assert json.loads(pipe.stamp_path("train_bc").read_text())["device"] == (
        "test CPU, 2 cores, 2 worker process(es)")
    assert pipe.trained_on() == "test CPU, 2 cores, 2 worker process(es)"
    stamps = pipe.work / "stages"
    (stamps / "train_bc_rl-1of2.json").write_text(json.dumps({"commands": []}))
    (stamps / "train_dagger.json").write_text(json.dumps({"device": "GPU box, 1 worker"}))
    (stamps / "train_other.json").write_text(json.dumps({"device": "not this run's"}))
    assert pipe.trained_on() == ("test CPU, 2 cores, 2 worker process(es) (bc, bc_rl-1of2); "
                                 "GPU box, 1 worker (dagger)")


def test_the_default_and_the_methods_run_keep_their_own_wall_time(tmp_path):
    """Both runs share a work folder; each one's provenance states its own invocations' time."""
    work = tmp_path / "work"
    work.mkdir()
    (work / "wall.json").write_text(json.dumps({"default": 100.0}))
    methods = Pipeline(PROFILES["smoke"], work, tmp_path / "paper",
                       methods=("bc", "bc_rl", "dagger"))
    methods.started -= 40.0
    methods._record_wall()
    walls = json.loads((work / "wall.json").read_text())
    assert walls["default"] == 100.0 and 40.0 <= walls["methods"] < 45.0
    default = Pipeline(PROFILES["smoke"], work, tmp_path / "paper")
    assert 100.0 <= default.wall_seconds() < 105.0
    assert 40.0 <= methods.wall_seconds() < 90.0
    # written again while running (an invocation killed outright still counts): the time
    # before this invocation is not added twice
    methods._record_wall()
    methods._record_wall()
    assert 40.0 <= json.loads((work / "wall.json").read_text())["methods"] < 45.0


def test_the_report_draws_the_learning_curves_of_this_runs_parts_only(tmp_path, monkeypatch):
    """The default and the methods run share runs/: each report names its own parts' runs
    (an unfinished DAgger run beside the default run is not in the default run's Fig. 4)."""
    pipe = Pipeline(PROFILES["smoke"], tmp_path / "work", tmp_path / "paper")
    seen = []
    monkeypatch.setattr(pipe, "stage", lambda name, commands, **kw: seen.append(commands))
    pipe.run_report(pipe.work / "evals", [], ["bc", "bc_rl-1of2"])
    argv = [str(a) for a in seen[0][0]]
    runs = argv[argv.index("--runs") + 1:]
    runs = runs[:next((i for i, a in enumerate(runs) if a.startswith("--")), len(runs))]
    assert runs == [str(pipe.work / "runs" / "bc"), str(pipe.work / "runs" / "bc_rl-1of2")]


def test_the_paper_plan_prices_table_one_at_paper_scale(tmp_path, monkeypatch):
    """The paper profile has no per-update price for the pipeline, but its plan states what
    Table I at paper scale costs at the measured rates; on a GPU machine the gpu profile's
    maze is priced at that machine's time."""
    from igdrivsim.names import SETTINGS
    from igdrivsim.training import cost

    pipe = Pipeline(PROFILES["paper"], tmp_path / "work", tmp_path / "paper", workers=1)
    monkeypatch.setattr(pipe, "_machine", planning.Machine(2, "test CPU"))
    lines = pipe.plan()
    assert any("no time estimate" in line for line in lines)
    (table,) = [line for line in lines if "Table I at paper scale" in line]
    hours = cost.table1_hours(cost.CPU_SECONDS_PER_EPISODE, cost.CPU_SECONDS_PER_ROLLOUT_EPISODE)
    assert f"~{hours['total']:,.0f} CPU-process-hours" in table
    gpu = planning.estimate_seconds("gpu", ("bc", "bc_rl"), (), SETTINGS, 12, 1000, 2, gpu=True)
    # the two methods' unsplit runs and the maze on 2 lanes bound it above; splitting a method
    # over the lanes costs a compile per part, so half the unsplit work bounds it below
    jobs = [cost.laptop_train_seconds(1000, 6, 12, r, gpu=True) for r in (False, True)]
    jobs.append(cost.GPU_MACHINE_MAZE_S)
    other = cost.LAPTOP_OTHER_CPU_S
    assert sum(jobs) / 2 + other <= gpu <= planning.makespan(jobs, 2) + other


def test_the_lanes_run_jobs_after_their_inputs_and_stop_at_the_first_failure():
    """The one lane scheduler (igdrivsim/lanes.py, the pipeline's and the maze study's): a job
    starts after the jobs it needs, two lanes run side by side, and after a failure no new job
    starts (a job that needs the failed one never runs) and the failure is raised."""
    from igdrivsim.lanes import Job, run_jobs

    events, lock = [], threading.Lock()

    def job(name, seconds=0.05, fail=False):
        def run(echo):
            with lock:
                events.append(("start", name))
            time.sleep(seconds)
            with lock:
                events.append(("end", name))
            if fail:
                raise RuntimeError(f"{name} failed")
        return run

    run_jobs([Job("a", job("a", 0.3)), Job("b", job("b")), Job("c", job("c"), ("a", "b"))], 2)
    assert events.index(("start", "b")) < events.index(("end", "a"))  # side by side
    assert events[-2:] == [("start", "c"), ("end", "c")]  # after both inputs
    events.clear()
    with pytest.raises(RuntimeError, match="b failed"):
        run_jobs([Job("a", job("a", 0.3)), Job("b", job("b", fail=True)),
                  Job("c", job("c"), ("b",)), Job("d", job("d"), ("a",))], 2)
    assert ("start", "c") not in events and ("start", "d") not in events
    with pytest.raises(ValueError, match="cycle"):
        run_jobs([Job("a", job("a"), ("b",)), Job("b", job("b"), ("a",))], 2)
