"""The whole reproduction as resumable stages (what ``scripts/reproduce.sh`` runs).

Stages, in order: ``data`` (synthetic WOMD-format shards, unless ``--data``), ``filter``
(training and validation manifests), ``train`` (6 settings x {BC, BC-RL}: one run per method
with every setting and seed in one program, the methods' runs side by side in two processes),
``evaluate`` (each run, plus the reference actors), ``maze``
(paper Fig. 2), ``render`` (Fig. 1), ``report`` (Table I, vs-paper table, Fig. 3, provenance)
and ``pdf`` (when ``latexmk`` is installed). Methods with a privileged teacher (``--methods
bc,bc_rl,dagger,advisor``) come after the others: a ``teacher`` stage picks the run whose
full setting drives better on validation, and they train the other settings with it
(``report`` then adds Table II and Fig. 6).

Resumability: a stage that completes writes ``WORK/stages/<stage>.json``; a later invocation
skips it while that stamp exists and nothing it depends on ran again. An interrupted training
stage resumes from its checkpoints (``igdrivsim train --resume``). Every stage logs to
``WORK/logs/<stage>.log`` and echoes its output (progress bars) on the terminal (stages running
side by side: their latest progress line every minute); a failing stage
stops the pipeline with a message naming the stage and its log.

Layout: work files (data, filtered manifests, runs, evaluations, logs) under ``WORK``
(``outputs/<profile>`` by default, ``--out`` when given); the report files under ``PAPER``
(the repository's ``paper/`` by default, ``OUT/paper`` with ``--out``).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import shutil
import subprocess
import sys
import threading
import time
from collections.abc import Sequence
from concurrent.futures import FIRST_EXCEPTION, ThreadPoolExecutor, wait
from dataclasses import asdict, dataclass, replace
from pathlib import Path

from igdrivsim.cli import DefaultsFormatter, deprecated_alias
from igdrivsim.errors import REPORTED, ConfigError, IGDrivSimError, error_line
from igdrivsim.evaluation.schema import METHODS, SETTINGS
from igdrivsim.io import atomic_copy, atomic_write_json, atomic_write_text, require_folder
from igdrivsim.observation import get_setting, setting_params
from igdrivsim.training.methods import get_method
from igdrivsim.training.privileged import TEACHER_SETTING

REPO_ROOT = Path(__file__).resolve().parents[2]
HEARTBEAT_S = 60.0  # a stage running side by side reports its progress line this often
PAPER_SOURCES = ("main.tex", "references.bib", "Makefile")


@dataclass(frozen=True)
class PipelineProfile:
    """Sizes of one reproduction profile (training hyper-parameters live in the training
    profile of the same name)."""

    name: str
    train_scenarios: int  # synthetic training scenarios generated
    val_scenarios: int  # synthetic validation scenarios generated
    seeds: int  # seeds per (setting, method)
    eval_max_scenarios: int  # 0: every kept validation scenario
    maze_profile: str  # maze.study profile
    settings: tuple[str, ...] = SETTINGS
    eval_batch: int = 32


_LAPTOP = PipelineProfile("laptop", train_scenarios=3072, val_scenarios=512, seeds=3,
                          eval_max_scenarios=0, maze_profile="default")
PROFILES: dict[str, PipelineProfile] = {
    "smoke": PipelineProfile("smoke", train_scenarios=16, val_scenarios=8, seeds=2,
                             eval_max_scenarios=8, maze_profile="smoke", eval_batch=8),
    "laptop": _LAPTOP,
    # the laptop's data and seeds; the training profile of the same name trains 10x the updates
    "gpu": replace(_LAPTOP, name="gpu"),
    "paper": PipelineProfile("paper", train_scenarios=20_000, val_scenarios=2_000, seeds=3,
                             eval_max_scenarios=0, maze_profile="default"),
}


class StageError(IGDrivSimError):
    """A stage failed: the message names the stage and its log."""


@dataclass
class Pipeline:
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

    def __post_init__(self):
        self.work, self.paper = Path(self.work), Path(self.paper)
        self.settings = tuple(self.settings or self.profile.settings)
        for name in self.settings:  # any registered setting or '+' composition of them
            if setting_params(get_setting(name)) is None:
                raise ConfigError(f"setting {name!r} has no data form (ObservationParams), so it "
                                  "cannot train together with the others; train it on its own "
                                  "with igdrivsim train")
        self.ran: set[str] = set()  # stages that ran in this invocation
        self.stopping = threading.Event()  # a lane failed: the other lane's stage stops

    # ----------------------------------------------------------------------- bookkeeping
    def log_path(self, stage: str) -> Path:
        return self.work / "logs" / f"{stage}.log"

    def stamp_path(self, stage: str) -> Path:
        return self.work / "stages" / f"{stage}.json"

    def done(self, stage: str, depends: Sequence[str] = (),
             commands: Sequence[Sequence[str]] | None = None) -> bool:
        """Complete: stamped (with the same ``commands``, when given), and none of ``depends``
        ran again in this invocation."""
        path = self.stamp_path(stage)
        if not path.is_file() or set(depends) & self.ran:
            return False
        if commands is None:
            return True
        try:
            stamped = json.loads(path.read_text(encoding="utf-8")).get("commands")
        except (OSError, ValueError):
            return False
        return stamped == [list(map(str, c)) for c in commands]

    def _say(self, text: str) -> None:
        print(f"[reproduce {time.strftime('%H:%M:%S')}] {text}", file=sys.stderr, flush=True)

    def stage(self, name: str, commands: Sequence[Sequence[str]], depends: Sequence[str] = (),
              outputs: Sequence[Path] = (), echo: bool = True) -> bool:
        """Run ``commands`` (argv lists; ``igdrivsim ...`` or ``python -m ...``) as stage
        ``name`` unless it is complete. Returns True when it ran. ``echo=False`` (stages running
        side by side): the output goes to the log only, and the terminal gets the stage's latest
        progress line every minute."""
        if self.stopping.is_set():
            raise StageError(f"stage '{name}' not started: a stage beside it failed")
        if self.done(name, depends, commands) and all(Path(p).exists() for p in outputs):
            self._say(f"{name}: complete, skipped")
            return False
        log = self.log_path(name)
        log.parent.mkdir(parents=True, exist_ok=True)
        # an old stamp must not survive a rerun that is killed: the next invocation would take
        # the half-rewritten stage (and so its dependents) for complete
        self.stamp_path(name).unlink(missing_ok=True)
        self._say(f"{name}: running (log: {log})")
        start = time.time()
        with open(log, "a", encoding="utf-8") as fh:
            fh.write(f"\n=== {time.strftime('%Y-%m-%d %H:%M:%S')} stage {name}\n")
            for argv in commands:
                fh.write("$ " + " ".join(map(str, argv)) + "\n")
                fh.flush()
                rc = self._run(list(map(str, argv)), fh, name if not echo else None)
                if rc != 0:
                    raise StageError(f"stage '{name}' failed (exit {rc}); read {log}")
        missing = [str(p) for p in outputs if not Path(p).exists()]
        if missing:
            raise StageError(f"stage '{name}' did not write {missing[0]}; read {log}")
        atomic_write_text(self.stamp_path(name), json.dumps(dict(
            stage=name, seconds=round(time.time() - start, 1), commands=[list(map(str, c))
                                                                         for c in commands],
            finished=time.strftime("%Y-%m-%d %H:%M:%S")), indent=2) + "\n")
        self.ran.add(name)
        self._say(f"{name}: done in {time.time() - start:.0f} s")
        return True

    def _run(self, argv: list[str], fh, beat: str | None = None) -> int:
        if self.in_process and argv[0] in ("igdrivsim", "python"):
            return self._run_in_process(argv, fh)
        if argv[0] == "igdrivsim":
            argv = [sys.executable, "-m", "igdrivsim.cli", *argv[1:]]
        elif argv[0] == "python":
            argv = [sys.executable, *argv[1:]]
        # Programs compiled by one stage are reused by later ones with the same shapes (the
        # evaluation of BC and BC-RL of a setting) and by a resumed pipeline.
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        # Two lanes share one GPU: each process takes GPU memory as it needs it rather than
        # most of it up front (JAX's default), so the second one does not run out.
        env.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")
        env.setdefault("JAX_COMPILATION_CACHE_DIR", str(self.work / "jax_cache"))
        proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                cwd=REPO_ROOT, env=env)
        assert proc.stdout is not None
        latest, next_beat = "", time.time() + HEARTBEAT_S
        try:
            while chunk := os.read(proc.stdout.fileno(), 4096):
                if self.stopping.is_set():
                    proc.terminate()
                text = chunk.decode("utf-8", "replace")
                fh.write(text)
                fh.flush()
                if self.quiet:
                    continue
                if beat is None:
                    sys.stderr.write(text)
                    sys.stderr.flush()
                    continue
                lines = [ln.strip() for ln in text.replace("\r", "\n").splitlines()]
                latest = next((ln for ln in reversed(lines) if ln), latest)
                if time.time() >= next_beat and latest:
                    self._say(f"{beat}: {latest}")
                    next_beat = time.time() + HEARTBEAT_S
        except KeyboardInterrupt:
            proc.terminate()
            proc.wait()
            raise
        return proc.wait()

    def _run_in_process(self, argv: list[str], fh) -> int:
        """``igdrivsim ...`` via the CLI's main, ``python -m module ...`` via its ``main``."""
        import importlib

        out = fh if self.quiet else _Tee(fh, sys.stderr)
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
            try:
                if argv[0] == "igdrivsim":
                    from igdrivsim.cli import main

                    return int(main(argv[1:]) or 0)
                if argv[:2] == ["python", "-m"]:
                    module = importlib.import_module(argv[2])
                    if not hasattr(module, "main"):  # a package: python -m runs __main__
                        module = importlib.import_module(f"{argv[2]}.__main__")
                    return int(module.main(argv[3:]) or 0)
            except SystemExit as err:  # argparse errors
                return int(err.code or 0) if isinstance(err.code, int) else 1
            except Exception as err:  # noqa: BLE001 - reported through the stage's log
                import traceback

                traceback.print_exc()
                print(f"error: {err}")
                return 1
        raise ConfigError(f"cannot run {argv[0]!r} in process")

    # --------------------------------------------------------------------------- stages
    @property
    def data_label(self) -> str:
        if self.train_data is None:
            return (f"synthetic ({self.profile.train_scenarios} training / "
                    f"{self.profile.val_scenarios} validation scenarios generated)")
        return f"{self.train_data} | {self.val_data}"

    def run_data(self) -> tuple[str, str]:
        if self.train_data is not None:
            return self.train_data, str(self.val_data)
        out = self.work / "data"
        p = self.profile
        workers = ["--workers", 1] if self.in_process else []  # no process pool in tests
        self.stage("data", [["igdrivsim", "generate", "--out", out, "--train",
                             p.train_scenarios, "--val", p.val_scenarios, "--seed", 0,
                             *workers]],
                   outputs=[out / "training", out / "validation"])
        return str(out / "training"), str(out / "validation")

    def run_filter(self, train: str, val: str) -> tuple[Path, Path]:
        outs = []
        for split, src in (("training", train), ("validation", val)):
            out = self.work / "filtered" / split
            workers = ["--workers", 1] if self.in_process else []
            self.stage(f"filter_{split}", [["igdrivsim", "filter", src, "--out", out,
                                            *workers]],
                       depends=["data"], outputs=[out / "manifest.jsonl"])
            outs.append(out)
        return outs[0], outs[1]

    def run_train(self, method: str, train_manifest: Path, val_manifest: Path,
                  echo: bool = True) -> None:
        """One run per method: every setting and seed in one compiled program (settings as
        data); the teacher-forced observations are computed once and cached in WORK/cache.
        A method with a privileged teacher trains the settings other than ``full`` with the
        teacher the ``teacher`` stage chose."""
        run = self.work / "runs" / method
        settings, sets, depends = self.settings, list(self.overrides), []
        if get_method(method).teacher:
            choice = json.loads(self.teacher_choice.read_text(encoding="utf-8"))
            settings = tuple(s for s in self.settings if s != TEACHER_SETTING)
            sets.append(f"training.teacher={choice['run']}")
            depends = ["teacher"]
        self.stage(f"train_{method}", [[
            "igdrivsim", "train", "--profile", self.profile.name,
            "--obs", ",".join(settings), "--method", method,
            "--seeds", self.profile.seeds, "--data", train_manifest,
            "--val-data", val_manifest, "--cache-dir", self.work / "cache",
            "--out", run, "--resume", *[a for o in sets for a in ("--set", o)]]],
            depends=["filter_training", "filter_validation", *depends],
            outputs=[run / "DONE"], echo=echo)

    @property
    def teacher_choice(self) -> Path:
        return self.work / "runs" / "teacher.json"

    def run_teacher(self, candidates: Sequence[str]) -> None:
        """Pick the privileged teacher among the finished runs of ``candidates``."""
        self.stage("teacher", [["python", "-m", "igdrivsim.training.privileged", "--runs",
                                *[self.work / "runs" / m for m in candidates],
                                "--out", self.teacher_choice]],
                   depends=[f"train_{m}" for m in candidates], outputs=[self.teacher_choice])

    def _eval_common(self, val_manifest: Path) -> list:
        return ["--data", val_manifest, "--batch-size", self.profile.eval_batch,
                "--limit", self.profile.eval_max_scenarios]

    def run_evaluate(self, name: str, val_manifest: Path, echo: bool = True) -> None:
        out = self.work / "evals" / name
        self.stage(f"evaluate_{name}", [["igdrivsim", "evaluate", self.work / "runs" / name,
                                         "--out", out, *self._eval_common(val_manifest)]],
                   depends=[f"train_{name}", "filter_validation"],
                   outputs=[out / "per_scenario.csv"], echo=echo)

    def run_references(self, like: str, val_manifest: Path, echo: bool = True) -> None:
        """The reference actors, with the capacities and simulator settings of run ``like``."""
        out = self.work / "evals" / "references"
        self.stage("evaluate_references", [[
            "igdrivsim", "evaluate", "--references", "--like", self.work / "runs" / like,
            "--out", out, *self._eval_common(val_manifest)]],
            depends=["filter_validation", f"train_{like}"],
            outputs=[out / "per_scenario.csv"], echo=echo)

    def run_speed_walk(self, val_manifest: Path, echo: bool = True) -> None:
        """The speed-walk diagnostic of the validation scenarios (no trained policy)."""
        out = self.work / "evals" / "speed_walk.json"
        self.stage("speed_walk", [["python", "-m", "igdrivsim.evaluation.speed_walk", "--data",
                                   val_manifest, "--limit", self.profile.eval_max_scenarios,
                                   "--out", out]],
                   depends=["filter_validation"], outputs=[out], echo=echo)

    def run_maze(self, echo: bool = True) -> None:
        out = self.work / "maze"
        self.stage("maze", [["python", "-m", "maze", "--profile",
                             self.profile.maze_profile, "--out", out, "--work", out / "work"]],
                   outputs=[out / "figures" / "fig2_maze.png"], echo=echo)
        for sub, names in (("figures", ("fig2_maze.pdf", "fig2_maze.png", "fig2_maze.csv",
                                        "fig2b_maze_baselines.pdf", "fig2b_maze_baselines.png")),
                           ("tables", ("maze_summary.md", "maze_summary.tex", "maze_summary.csv"))):
            for fname in names:
                src = out / sub / fname
                if src.exists():
                    (self.paper / sub).mkdir(parents=True, exist_ok=True)
                    atomic_copy(src, self.paper / sub / fname)

    def run_render(self, val: str, echo: bool = True) -> None:
        from igdrivsim.data import expand_paths
        from igdrivsim.observation.commands import DEFAULT_DATA

        # Fig. 1 shows a real WOMD scenario: the user's data, else the bundled real sample.
        files = expand_paths(val)
        if self.train_data is None and DEFAULT_DATA.is_file():
            files = [str(DEFAULT_DATA)]
        if not files:
            raise StageError(f"stage 'render': no validation file in {val}")
        figures = self.paper / "figures"
        self.stage("render", [["igdrivsim", "render", "--data", files[0], "--out", figures]],
                   depends=["data"], outputs=[figures / "fig1_observations.png"], echo=echo)

    def run_report(self, evals: Path, upstream: Sequence[str]) -> None:
        self.stage("report", [["igdrivsim", "report", "--evals", evals, "--out", self.paper,
                               "--profile", self.profile.name, "--data-label", self.data_label]],
                   depends=upstream, outputs=[self.paper / "tables" / "table1.tex"])

    def run_pdf(self) -> None:
        """Build the PDF with latexmk (or pdflatex + bibtex). A LaTeX failure is reported with
        its log but does not fail the pipeline: every table and figure is already written."""
        if shutil.which("latexmk"):
            target = "pdf"
        elif shutil.which("pdflatex") and shutil.which("bibtex"):
            target = "plain"
        else:
            self._say("pdf: neither latexmk nor pdflatex found, skipping the PDF build (the "
                      "tables and figures are written)")
            return
        if self.paper.resolve() != (REPO_ROOT / "paper").resolve():
            for name in PAPER_SOURCES:  # a self-contained paper folder under --out
                atomic_copy(REPO_ROOT / "paper" / name, self.paper / name)
        try:
            self.stage("pdf", [["make", "-C", self.paper, target]], depends=["report"],
                       outputs=[self.paper / "main.pdf"])
        except StageError as err:
            self._say(f"pdf: WARNING, the PDF was not built: {err}")

    def check_work_folder(self) -> None:
        """Record the options in ``WORK/pipeline.json``; refuse a folder made with other data,
        another profile or other ``--set`` overrides (its complete stages would be wrongly
        skipped)."""
        record = json.loads(json.dumps(dict(  # JSON types, comparable with the stored record
            profile=asdict(self.profile), train_data=self.train_data, val_data=self.val_data,
            paper=str(self.paper), overrides=list(self.overrides))))
        path = self.work / "pipeline.json"
        if path.is_file():
            try:
                old = json.loads(path.read_text())
            except (OSError, json.JSONDecodeError):
                old = {}
            for key in ("profile", "train_data", "val_data", "overrides"):
                if key in old and old[key] != record[key]:
                    raise ConfigError(f"{path}: this work folder was made with another {key} "
                                      f"({old[key]!r}); use another --out or the same options")
        atomic_write_json(path, record, indent=2)

    @contextlib.contextmanager
    def work_lock(self):
        """Hold ``WORK/pipeline.lock`` (``flock``) so that a second run on the same work folder
        is refused; the kernel drops the lock when the holder exits, even when killed."""
        import fcntl

        self.work.mkdir(parents=True, exist_ok=True)
        path = self.work / "pipeline.lock"
        fh = open(path, "a+")  # noqa: SIM115 - held open for the whole run
        try:
            try:
                fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                fh.seek(0)
                holder = fh.read().strip() or "another process"
                raise ConfigError(f"another reproduction is running on {self.work} (pid "
                                  f"{holder}); wait for it to finish or use another --out"
                                  ) from None
            fh.seek(0)
            fh.truncate()
            fh.write(str(os.getpid()))
            fh.flush()
            yield
        finally:
            fh.close()

    def side_by_side(self, first, second, serial: bool = False) -> None:
        """Run two lanes (``lane(echo)``) in two threads, each driving its own processes; a
        failing lane stops the other. ``serial`` (or in-process): one after the other."""
        if self.in_process or serial:
            first(True)
            second(True)
            return
        with ThreadPoolExecutor(2) as pool:
            jobs = [pool.submit(first, False), pool.submit(second, False)]
            wait(jobs, return_when=FIRST_EXCEPTION)
            if any(j.done() and j.exception() for j in jobs):
                self.stopping.set()
            for job in jobs:
                job.result()

    def run(self) -> None:
        """Every stage in order, holding the work folder's lock."""
        with self.work_lock():
            self._run_stages()

    def _run_stages(self) -> None:
        self._say(f"profile {self.profile.name}; work files in {self.work}; report in "
                  f"{self.paper}")
        self.check_work_folder()
        train, val = self.run_data()
        train_manifest, val_manifest = self.run_filter(train, val)
        taught = [m for m in self.methods if get_method(m).teacher]
        names = [m for m in self.methods if m not in taught]

        def lane(methods: Sequence[str], rest: bool, echo: bool) -> None:
            """Train and evaluate ``methods``; with ``rest`` also the reference actors, the
            maze study and Fig. 1."""
            for method in methods:
                self.run_train(method, train_manifest, val_manifest, echo)
                self.run_evaluate(method, val_manifest, echo)
            if rest:
                self.run_references(names[-1], val_manifest, echo)
                self.run_speed_walk(val_manifest, echo)
                self.run_maze(echo)
                self.run_render(val, echo)

        # two lanes side by side (each process keeps about one core busy): the first method
        # alone, the others followed by the references, the maze and Fig. 1
        self.side_by_side(lambda echo: lane(names[:1], False, echo),
                          lambda echo: lane(names[1:], True, echo), serial=len(names) == 1)
        if taught:  # then the methods taught by the better full-setting policy
            self.run_teacher(names)
            self.side_by_side(lambda echo: lane(taught[:1], False, echo),
                              lambda echo: lane(taught[1:], False, echo),
                              serial=len(taught) == 1)
        evals = self.work / "evals"
        upstream = ["maze", "render", "evaluate_references", "speed_walk",
                    *[f"evaluate_{n}" for n in (*names, *taught)]]
        self.run_report(evals, upstream)
        self.run_pdf()
        self._say(f"finished: tables in {self.paper / 'tables'}, figures in "
                  f"{self.paper / 'figures'}")


class _Tee:
    """A text stream writing to a log file and to the terminal (in-process stages)."""

    def __init__(self, *streams):
        self.streams = streams

    def write(self, text: str) -> int:
        for stream in self.streams:
            stream.write(text)
        return len(text)

    def flush(self) -> None:
        for stream in self.streams:
            stream.flush()

    def isatty(self) -> bool:
        return False


# ------------------------------------------------------------------------------------ CLI
def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="scripts/reproduce.sh", formatter_class=DefaultsFormatter,
                                     description=(
        "Regenerate every table and figure: data -> filter -> train -> evaluate -> maze -> "
        "render -> report -> PDF. Resumable: rerun the same command after an interruption."))
    parser.add_argument("--profile", choices=tuple(PROFILES), default="laptop",
                        help="smoke (minutes, CI), laptop (about an hour on 2 cores, default), "
                             "gpu (the laptop network at 10x the updates; one GPU), "
                             "paper (the paper's sizes; GPUs)")
    parser.add_argument("--data", nargs="+", metavar="DIR", default=None,
                        help="real data instead of synthetic: one folder holding training/ and "
                             "validation/, or two locations TRAIN VAL (files, folders, globs, "
                             "name@N)")
    parser.add_argument("--out", default=None,
                        help="put everything under OUT (work files, and the report in "
                             "OUT/paper); default: outputs/<profile>/ and paper/")
    parser.add_argument("--obs", dest="settings", default=None, metavar="SETTINGS",
                        help="comma-separated observation settings: any of the paper's six, "
                             "a registered one (occlusion) or a '+' composition "
                             "(default: the paper's six)")
    deprecated_alias(parser, "--settings", "settings")
    parser.add_argument("--methods", default=",".join(METHODS), metavar="METHODS",
                        help="comma-separated registered learning methods to train and "
                             "compare (igdrivsim/training/methods/); dagger and advisor are taught "
                             "by the better full-setting run of the others")
    parser.add_argument("--set", dest="overrides", action="append", default=[],
                        metavar="SECTION.FIELD=VALUE",
                        help="override a config field for every training run (repeatable; "
                             "not observation.setting or training.method), e.g. "
                             "--set training.num_updates=400; use a fresh --out for it")
    parser.add_argument("--in-process", action="store_true",
                        help="run the commands in this Python process (faster for smoke)")
    parser.add_argument("--no-progress", dest="quiet", action="store_true",
                        help="do not echo stage output and progress bars on the terminal (the "
                             "logs in WORK/logs/ are complete either way)")
    deprecated_alias(parser, "--quiet", "quiet", action="store_true")
    return parser


def pipeline_from_args(args: argparse.Namespace) -> Pipeline:
    profile = PROFILES[args.profile]
    train = val = None
    if args.data:
        if len(args.data) == 1:
            root = Path(args.data[0])
            train, val = str(root / "training"), str(root / "validation")
            if not (root / "training").exists() or not (root / "validation").exists():
                raise ConfigError(f"--data {root}: expected training/ and validation/ inside "
                                  "(or give two locations: --data TRAIN VAL)")
        elif len(args.data) == 2:
            train, val = args.data
            from igdrivsim.data import expand_paths

            for where in (train, val):
                expand_paths(where)  # names files, else a one-line error (before any stage)
        else:
            raise ConfigError("--data takes one folder or two locations (TRAIN VAL)")
    if args.out:
        work, paper = Path(args.out), Path(args.out) / "paper"
    else:
        work, paper = REPO_ROOT / "outputs" / profile.name, REPO_ROOT / "paper"
    require_folder(work)
    settings = tuple(s.strip() for s in args.settings.split(",")) if args.settings else None
    if settings is not None and (not all(settings) or len(set(settings)) != len(settings)):
        raise ConfigError(f"--obs must name distinct settings, got {args.settings!r}")
    for override in args.overrides:
        key = override.partition("=")[0].strip()
        if key in ("observation.setting", "training.method"):
            raise ConfigError(f"--set {override}: the pipeline sets {key} itself (use --obs / "
                              "--methods)")
    from igdrivsim.training.config import get_profile, with_overrides

    methods = tuple(m.strip() for m in args.methods.split(",") if m.strip())
    if not methods or len(set(methods)) != len(methods):
        raise ConfigError(f"--methods must name distinct methods, got {args.methods!r}")
    for name in methods:
        get_method(name)  # a registered method, else a one-line error naming the choices
    if any(get_method(m).teacher for m in methods):
        plain = [m for m in methods if not get_method(m).teacher]
        chosen = tuple(s.strip() for s in args.settings.split(",")) if args.settings else None
        if not plain or (chosen is not None and TEACHER_SETTING not in chosen):
            raise ConfigError("--methods: a method with a privileged teacher needs a method "
                              f"without one (bc, bc_rl) trained on the {TEACHER_SETTING!r} "
                              "setting to pick the teacher from")

    with_overrides(get_profile(args.profile), args.overrides)  # a bad --set fails here, clearly
    return Pipeline(profile, work, paper, train, val, in_process=args.in_process,
                    quiet=args.quiet, settings=settings, methods=methods,
                    overrides=tuple(args.overrides))


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        pipeline_from_args(args).run()
    except REPORTED as err:
        print(f"reproduce: error: {error_line(err)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("reproduce: interrupted; rerun the same command to resume", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
