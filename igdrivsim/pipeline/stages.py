"""The whole reproduction as resumable stages (:mod:`.runner`; ``scripts/reproduce.sh``).

In order: ``data`` (synthetic, unless ``--data``), ``filter``, ``train`` (the grid split into
parts over the workers, :mod:`.planning`; taught methods after a ``teacher`` stage),
``evaluate``, ``maze`` (Fig. 2), ``render`` (Fig. 1), ``report``, ``reactive`` (IDM sim agents),
``real_logs`` (every real scenario at hand, every vehicle as the ego) and ``pdf``. Work files
live under ``WORK``, the report is published under ``PAPER`` (:mod:`.publish`).
"""

from __future__ import annotations

import json
import os
import subprocess
import threading
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

from igdrivsim import lanes
from igdrivsim.data import expand_paths, samples
from igdrivsim.data.manifest import MANIFEST
from igdrivsim.errors import ConfigError
from igdrivsim.evaluation.schema import PER_SCENARIO_FILE
from igdrivsim.io import atomic_copy, atomic_write_json, read_json
from igdrivsim.names import BC, METHODS
from igdrivsim.observation import stack_settings
from igdrivsim.observation.commands import DEFAULT_DATA
from igdrivsim.pipeline import planning
from igdrivsim.pipeline.profiles import PipelineProfile
from igdrivsim.pipeline.publish import Publisher
from igdrivsim.pipeline.runner import REPO_ROOT, StageError, StageRunner
from igdrivsim.report import provenance
from igdrivsim.training import cost
from igdrivsim.training.config import QUICK_UPDATES, get_profile, with_overrides
from igdrivsim.training.cost import MAZE_CPU_S
from igdrivsim.training.methods import get_method
from igdrivsim.training.privileged import TEACHER_SETTING
from igdrivsim.training.run import CHECKPOINTS, DONE, Run, is_complete

# sim agents -> (evaluation folder, stage-name suffix, extra ``igdrivsim evaluate`` arguments)
EVAL_FOLDERS = {"log": ("evals", "", []), "idm": ("evals_idm", "_idm", ["--agents", "idm"])}
# Full BC's action read-outs on the real logs beside Table I's sampled actions (policy.act)
READOUTS = ("greedy", "mean")


@dataclass
class Pipeline(Publisher, StageRunner):
    """One reproduction: profile, locations, and how commands run."""

    profile: PipelineProfile
    work: Path
    paper: Path
    train_data: str | None = None  # None: generate synthetic data
    val_data: str | None = None
    in_process: bool = False  # run igdrivsim commands in this process (tests: shared compiles)
    quiet: bool = False  # do not echo stage output on the terminal
    settings: tuple[str, ...] | None = None
    methods: tuple[str, ...] = METHODS
    overrides: tuple[str, ...] = ()  # ``section.field=value`` for every training run
    workers: int = 0  # worker processes (0: one per CPU core; two on an accelerator)
    # real scenarios: the samples cache and every --samples location (Fig. 1, real_logs stage)
    samples: tuple[str, ...] = ()
    samples_given: tuple[str, ...] = ()  # the --samples locations typed on the command line

    def __post_init__(self):
        self.work, self.paper = Path(self.work), Path(self.paper)
        self.settings = tuple(self.settings or self.profile.settings)
        for i, name in enumerate(self.settings):  # any registered setting or '+' composition
            if stack_settings(self.settings[:i + 1]) is None:
                raise ConfigError(f"setting {name!r} cannot share one program with the settings "
                                  "before it (a model that is not a pytree or has no neutral() "
                                  "form, or another order of the same models; "
                                  "docs/EXTENDING.md); train it on its own with igdrivsim train")
        self.ran: set[str] = set()  # stages that ran in this invocation
        self.started = time.time()
        self._walls_before: dict[str, float] | None = None  # wall.json when this one began
        self._machine: planning.Machine | None = None
        self.stopping = threading.Event()  # a lane failed: the other lane's stage stops
        self.children: set[subprocess.Popen] = set()  # stage processes now running
        # stages now running -> when they began, moved back by their earlier invocations' seconds
        self.running: dict[str, float] = {}
        # cores a side-by-side worker may be pinned to (StageRunner._pin; none off Linux)
        self.free_cores = sorted(getattr(os, "sched_getaffinity", lambda _: ())(0))
        self.core_lock = threading.Lock()

    @property
    def data_label(self) -> str:
        if self.train_data is None:
            return (f"synthetic ({self.profile.train_scenarios} training / "
                    f"{self.profile.val_scenarios} validation scenarios generated)")
        return f"{self.train_data} | {self.val_data}"

    @property
    def pool_workers(self) -> list:
        """``--workers 1`` in process (no process pool in tests), else nothing."""
        return ["--workers", 1] if self.in_process else []

    def run_data(self) -> tuple[str, str]:
        if self.train_data is not None:
            return self.train_data, str(self.val_data)
        out = self.work / "data"
        p = self.profile
        self.stage("data", [["igdrivsim", "generate", "--out", out, "--train",
                             p.train_scenarios, "--val", p.val_scenarios, "--seed", 0,
                             *self.pool_workers]],
                   outputs=[out / "training", out / "validation"])
        return str(out / "training"), str(out / "validation")

    def run_filter(self, train: str, val: str) -> tuple[Path, Path]:
        out = self.work / "filtered"
        for split, src in (("training", train), ("validation", val)):
            self.stage(f"filter_{split}", [["igdrivsim", "filter", src, "--out", out / split,
                                            *self.pool_workers]],
                       depends=["data"], outputs=[out / split / MANIFEST])
        return out / "training", out / "validation"

    def run_train(self, part: planning.Part, train_manifest: Path, val_manifest: Path,
                  echo: bool) -> None:
        """Train one part of the grid in one program; a method with a privileged teacher skips
        ``full`` and learns from the chosen teacher."""
        run = self.work / "runs" / part.name
        settings, sets, depends = part.settings, list(self.overrides), []
        if get_method(part.method).teacher:
            settings = tuple(s for s in settings if s != TEACHER_SETTING)
            sets.append(f"training.teacher={read_json(self.teacher_choice)['run']}")
            depends = ["teacher"]
        self.stage(f"train_{part.name}", [[
            "igdrivsim", "train", "--profile", self.profile.name,
            "--obs", ",".join(settings), "--method", part.method,
            "--seeds", self.profile.seeds, "--data", train_manifest,
            "--val-data", val_manifest, "--cache-dir", self.work / "cache",
            "--out", run, "--resume", *[a for o in sets for a in ("--set", o)]]],
            depends=["filter_training", "filter_validation", *depends],
            outputs=[run / DONE], echo=echo)

    @property
    def teacher_choice(self) -> Path:
        return self.work / "runs" / "teacher.json"

    def run_teacher(self, candidates: Sequence[str]) -> None:
        self.stage("teacher", [["igdrivsim", "teacher", "--runs",
                                *[self.work / "runs" / m for m in candidates],
                                "--out", self.teacher_choice]],
                   depends=[f"train_{m}" for m in candidates], outputs=[self.teacher_choice])

    def run_evaluate(self, name: str, val_manifest: Path, echo: bool = True,
                     agents: str = "log", like: str | None = None) -> None:
        """Evaluate run ``name`` under ``agents`` (:data:`EVAL_FOLDERS`); with ``like``, the
        reference actors with that run's capacities and simulator settings."""
        folder, suffix, extra = EVAL_FOLDERS[agents]
        out = self.work / folder / name
        what = ([self.work / "runs" / name] if like is None
                else ["--references", "--like", self.work / "runs" / like])
        self.stage(f"evaluate_{name}{suffix}", [[
            "igdrivsim", "evaluate", *what, "--out", out, "--data", val_manifest,
            "--batch-size", self.profile.eval_batch, "--limit", self.profile.eval_max_scenarios,
            *extra]],
            depends=[f"train_{like or name}", "filter_validation"],
            outputs=[out / PER_SCENARIO_FILE], echo=echo)

    def run_reactive(self, parts: Sequence[str]) -> None:
        """Table I's companion: every driver under log-replay and IDM sim agents
        (:mod:`igdrivsim.report.reactive`, tables/reactive.md and Fig. 7)."""
        self.stage("reactive", [[
            "igdrivsim", "report", "reactive", "--log", self.work / "evals",
            "--idm", self.work / "evals_idm", "--out", self.staged]],
            depends=["evaluate_references", "evaluate_references_idm",
                     *[f"evaluate_{p}{s}" for p in parts for s in ("", "_idm")]],
            outputs=[self.staged / "tables" / "reactive.md"])

    def run_speed_walk(self, val_manifest: Path, echo: bool = True) -> None:
        """The speed-walk diagnostic of the validation scenarios (no trained policy)."""
        out = self.work / "evals" / "speed_walk.json"
        self.stage("speed_walk", [["igdrivsim", "speed-walk", "--data", val_manifest, "--limit",
                                   self.profile.eval_max_scenarios, "--out", out]],
                   depends=["filter_validation"], outputs=[out], echo=echo)

    def run_maze(self, echo: bool = True) -> None:
        out = self.work / "maze"
        self.stage("maze", [["python", "-m", "maze", "--profile",
                             self.profile.maze_profile, "--out", out, "--work", out / "work"]],
                   outputs=[out / "figures" / "fig2_maze.png"], echo=echo)
        for rel in (*(f"figures/fig2_maze.{ext}" for ext in ("pdf", "png", "csv")),
                    "figures/fig2b_maze_baselines.pdf", "figures/fig2b_maze_baselines.png",
                    "figures/maze_frames.png", "maze_config.json",
                    *(f"tables/maze_summary.{ext}" for ext in ("md", "tex", "csv"))):
            if (out / rel).exists():  # atomic_copy makes the folder
                atomic_copy(out / rel, self.staged / rel)

    def run_render(self, val: str, echo: bool = True) -> None:
        # Fig. 1 shows a real scenario when one is at hand: the user's data, else the public
        # samples (--samples), else the shared one; else a synthetic one (the figure says which)
        files = expand_paths(val)
        if self.train_data is None and self.samples:
            files = expand_paths(list(self.samples))[:1]
        elif self.train_data is None and DEFAULT_DATA.is_file():
            files = [str(DEFAULT_DATA)]
        if not files:
            raise StageError(f"stage 'render': no validation file in {val}")
        figures = self.staged / "figures"
        self.stage("render", [["igdrivsim", "render", "--data", files[0], "--out", figures]],
                   depends=["data"], outputs=[figures / "fig1_observations.png"], echo=echo)

    @property
    def samples_label(self) -> str:
        """What the real scenarios are: each location of :attr:`samples`, in words."""
        def label(where: str) -> str:
            if samples.find_samples(Path(where).parent) == Path(where):
                return (f"{len(samples.FILES)} public WOMD logs ({samples.PACKAGE}'s wheel, "
                        "igdrivsim samples) in 91-step windows")
            return f"the real scenarios in {where}"

        return "; ".join(map(label, self.samples)) + (
            ", every vehicle that passes the scenario filter as the ego in turn")

    def full_bc_run(self, runs: Sequence[str]) -> str | None:
        """The run among ``runs`` (folder names) that trained BC on the full setting."""
        for name in runs:
            config = Run.open(self.work / "runs" / name).config
            if config.training.method == BC and TEACHER_SETTING in config.settings:
                return name
        return None

    def run_real_logs(self) -> None:
        """Every trained run and the references on every real scenario at hand, every vehicle
        that passes the filter as the ego; Full BC also under the :data:`READOUTS`."""
        runs = sorted(p.name for p in (self.work / "runs").glob("*")
                      if is_complete(p) and (self.work / "evals" / p.name).is_dir())
        if not self.samples or not runs:
            why = "no evaluated run" if self.samples else (
                "no real samples (igdrivsim samples fetches them; then --samples DIR)")
            self._say(f"real_logs: {why}, skipped")
            return
        out, readouts = self.work / "evals_real", self.work / "evals_real_readouts"
        # every ego of every real location (real egos are few: no --limit)
        common = ["--data", *self.samples, "--egos", "all", "--batch-size",
                  self.profile.eval_batch, "--limit", 0]
        commands = [["igdrivsim", "evaluate", self.work / "runs" / r, "--out", out / r, *common]
                    for r in runs]
        commands += [["igdrivsim", "evaluate", "--references", "--like",
                      self.work / "runs" / runs[-1], "--out", out / "references", *common]]
        full_bc = self.full_bc_run(runs)
        if full_bc is not None:
            commands += [["igdrivsim", "evaluate", self.work / "runs" / full_bc, "--out",
                          readouts / mode, "--actions", mode, *common] for mode in READOUTS]
        commands += [["igdrivsim", "report", "real-logs", "--real", out,
                      "--synthetic", self.work / "evals", "--out", self.staged / "tables",
                      "--real-label", self.samples_label, "--synthetic-label", self.data_label,
                      *(["--readouts", readouts] if full_bc is not None else [])]]
        self.stage("real_logs", commands,
                   depends=[*[f"evaluate_{r}" for r in runs], "evaluate_references"],
                   outputs=[self.staged / "tables" / "real_logs.md"])

    @property
    def default_paper(self) -> bool:
        """The report goes to the repository's paper/ (no --out)."""
        return self.paper.resolve() == (REPO_ROOT / "paper").resolve()

    def run_report(self, evals: Path, upstream: Sequence[str], parts: Sequence[str]) -> None:
        """The report of this run (its learning curves from its own ``parts``' runs only)."""
        # results.md: published with the tables (PAPER/results.md); the default run's goes to
        # docs/results.md instead, rewritten from paper/ once published (write_results)
        page = ["--results", self.work / "results.md"] if self.default_paper else []
        runs = [self.work / "runs" / part for part in parts]
        self.stage("report", [["igdrivsim", "report", "--evals", evals, "--out", self.staged,
                               "--profile", self.profile.name, "--data-label", self.data_label,
                               "--work", self.work, "--runs", *runs, *page]],
                   depends=upstream, outputs=[self.staged / "tables" / "table1.tex"])

    def training_config(self):
        return with_overrides(get_profile(self.profile.name), list(self.overrides))

    @property
    def device_text(self) -> str:
        """This machine and its worker processes, as stamps and provenance state it."""
        return f"{self.machine.label()}, {self.lanes} worker process(es)"

    @property
    def machine(self) -> planning.Machine:
        if self._machine is None:
            self._machine = planning.detect_machine()
        return self._machine

    @property
    def lanes(self) -> int:
        """Worker processes: ``--workers``, else one per core (two on an accelerator)."""
        if self.in_process:
            return 1
        return self.workers or planning.default_workers(self.machine)

    @property
    def one_thread(self) -> bool:
        """Workers get one XLA thread each: several of them on a CPU."""
        return self.lanes > 1 and self.machine.accelerator is None

    def check_work_folder(self) -> None:
        """Record the options in ``WORK/pipeline.json``; refuse a folder made with other ones."""
        record = json.loads(json.dumps(dict(  # JSON types, comparable with the stored record
            profile=asdict(self.profile), train_data=self.train_data, val_data=self.val_data,
            paper=str(self.paper), overrides=list(self.overrides))))
        path = self.work / "pipeline.json"
        old = read_json(path, {})
        for key in ("profile", "train_data", "val_data", "overrides"):
            if key in old and old[key] != record[key]:
                raise ConfigError(f"{path}: this work folder was made with another {key} "
                                  f"({old[key]!r}); use another --out or the same options")
        atomic_write_json(path, record, indent=2)

    def method_groups(self) -> tuple[list[str], list[str]]:
        taught = [m for m in self.methods if get_method(m).teacher]
        return [m for m in self.methods if m not in taught], taught

    def parts(self) -> tuple[list[planning.Part], list[planning.Part]]:
        """The grid's parts: the untaught methods on every setting, then the taught ones."""
        plain, taught = self.method_groups()
        updates = self.training_config().training.num_updates
        seconds = planning.part_seconds(self.profile.name, self.profile.seeds, updates,
                                        self.machine.accelerator is not None)
        first = planning.split_grid(plain, self.settings, self.lanes, seconds,
                                    [self.maze_seconds])
        rest = [s for s in self.settings if s != TEACHER_SETTING]
        return first, planning.split_grid(taught, rest, self.lanes, seconds) if taught else []

    @property
    def maze_seconds(self) -> float:
        """The maze stage's measured CPU-s (0: a profile whose costs were not measured)."""
        return MAZE_CPU_S if self.profile.name in planning.PRICED_PROFILES else 0.0

    def left(self, stage: str) -> float:
        """The share of ``stage`` still to run (a training part: past its latest checkpoint)."""
        if self.done(stage):
            return 0.0
        run = self.work / "runs" / stage.removeprefix("train_")
        if not stage.startswith("train_") or not (run / CHECKPOINTS).is_dir():
            return 1.0
        updates = self.training_config().training.num_updates
        return max(0.0, 1.0 - (Run.open(run).latest_step() or 0) / updates)

    def plan(self) -> list[str]:
        """What this run will do and how long it should take (printed before any stage)."""
        first, second = self.parts()
        t = self.training_config().training
        plain, taught = self.method_groups()
        gpu = self.machine.accelerator is not None
        wall = planning.estimate_seconds(self.profile.name, plain, taught, self.settings,
                                         self.profile.seeds, t.num_updates, self.lanes, gpu,
                                         left=self.left)
        grid = ", ".join(f"{p.name} ({len(p.settings)} setting{'s' * (len(p.settings) > 1)})"
                         for p in (*first, *second))
        lines = [
            f"plan: profile {self.profile.name}: {t.num_updates:,} updates x "
            f"{self.profile.seeds} seeds x {len(self.settings)} settings x "
            f"{', '.join(self.methods)}; data {self.data_label}",
            f"plan: machine {self.machine.label()}; {self.lanes} worker process(es)"
            + (", one XLA thread each" if self.one_thread else "")
            + (f" (fewer than the cores: {planning.WORKER_MEMORY_GB} GB of memory each)"
               if not self.workers and self.lanes < self.machine.cores
               and not self.machine.accelerator and not self.in_process else ""),
            f"plan: stages data -> filter -> train + evaluate {len(first) + len(second)} parts "
            f"[{grid}]" + (" (taught methods after the teacher stage)" if second else "")
            + ", references, speed walk, maze, Fig. 1 -> report -> publish -> PDF",
        ]
        if wall is None:
            lines.append(f"plan: no measured per-update cost for profile {self.profile.name}; "
                         "no time estimate")
            if self.profile.name == "paper":
                lines.append("plan: " + cost.table1_text(gpu))
        else:
            where = ("training at the measured H200 rates, the other stages at their measured "
                     "CPU costs" if self.machine.accelerator else "measured per-update costs")
            lines.append(f"plan: estimated wall time ~{planning.hours_text(wall)} ({where}: "
                         "igdrivsim/training/cost.py; work already complete or checkpointed "
                         "is not counted)")
        note = provenance.competence_note(self.profile.name, t.num_updates)
        if note:
            lines.append(f"plan: {note}")
        elif (self.profile.name == "laptop" and wall is not None and not self.machine.accelerator
              and not self.stamped_stages()):  # a first look is for a run not yet begun
            quick = planning.estimate_seconds("quick", plain, taught, self.settings,
                                              self.profile.seeds, QUICK_UPDATES, self.lanes, gpu)
            lines.append(f"plan: for a first look in ~{planning.hours_text(quick or 0.0)} "
                         "(300 updates, below the competence targets): bash scripts/reproduce.sh "
                         "--profile quick")
        if self.machine.accelerator and self.profile.name != "gpu":
            lines.append(f"plan: accelerator found ({self.machine.accelerator}): the gpu "
                         "profile is recommended (bash scripts/reproduce.sh --profile gpu)")
        return lines

    def run(self) -> None:
        with self.work_lock():
            self.wall_seconds()  # the time of the invocations before this one, read now
            stop = threading.Event()
            threading.Thread(target=self._keep_wall, args=(stop,), daemon=True).start()
            try:
                self._run_stages()
            finally:
                stop.set()
                self._record_wall()

    def _run_stages(self) -> None:
        self._say(f"profile {self.profile.name}; work files in {self.work}; report in "
                  f"{self.paper}")
        self.check_work_folder()
        for line in self.plan():
            self._say(line)
        first, second = self.parts()
        names = [p.name for p in (*first, *second)]
        train, val = self.run_data()
        tm, vm = self.run_filter(train, val)
        like = first[-1].name  # the references take its capacities and simulator settings

        def train_job(part: planning.Part, after: tuple[str, ...] = ()) -> lanes.Job:
            return lanes.Job(f"train_{part.name}", lambda e: self.run_train(part, tm, vm, e), after)

        # the longest first; the maze among them by its cost
        costly = [*[(p.seconds, train_job(p)) for p in first],
                  (self.maze_seconds, lanes.Job("maze", self.run_maze))]
        jobs = [job for _, job in sorted(costly, key=lambda x: -x[0])]
        if second:  # the methods taught by the better full-setting policy
            jobs.append(lanes.Job("teacher", lambda e: self.run_teacher([p.name for p in first]),
                                  after=tuple(f"train_{p.name}" for p in first)))
            jobs += [train_job(p, ("teacher",)) for p in second]
        jobs += [lanes.Job(f"evaluate_{n}{suffix}", lambda e, n=n, a=agents: self.run_evaluate(
                     n, vm, e, a), after=(f"train_{n}",))
                 for agents, (_, suffix, _) in EVAL_FOLDERS.items() for n in names]
        jobs += [lanes.Job(f"evaluate_references{suffix}", lambda e, a=agents: self.run_evaluate(
                     "references", vm, e, a, like), after=(f"train_{like}",))
                 for agents, (_, suffix, _) in EVAL_FOLDERS.items()]
        jobs += [lanes.Job("speed_walk", lambda e: self.run_speed_walk(vm, e)),
                 lanes.Job("render", lambda e: self.run_render(val, e))]
        lanes.run_jobs(jobs, self.lanes, self.stopping)
        upstream = ["maze", "render", "evaluate_references", "speed_walk",
                    *[f"evaluate_{n}" for n in names]]
        self.run_report(self.work / "evals", upstream, names)
        self.run_reactive(names)
        self.run_real_logs()
        self.publish()
        self.write_results()
        self.run_pdf()
        self._say(f"finished: tables in {self.paper / 'tables'}, figures in "
                  f"{self.paper / 'figures'}")
