"""``scripts/reproduce.sh``'s command line: options -> a :class:`.stages.Pipeline`, run with a
one-line error on bad input and a resumable stop on Ctrl-C or SIGTERM."""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from pathlib import Path

from igdrivsim.cli_args import DefaultsFormatter
from igdrivsim.data import expand_paths, samples
from igdrivsim.errors import ConfigError, run_command
from igdrivsim.io import require_folder
from igdrivsim.names import METHODS
from igdrivsim.pipeline.profiles import PROFILES
from igdrivsim.pipeline.runner import REPO_ROOT
from igdrivsim.pipeline.stages import Pipeline
from igdrivsim.training.config import get_profile, with_overrides
from igdrivsim.training.methods import get_method
from igdrivsim.training.privileged import TEACHER_SETTING


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="scripts/reproduce.sh", formatter_class=DefaultsFormatter,
                                     description=(
        "Regenerate the report's tables and figures (Table II and Fig. 6: the --methods "
        "bc,bc_rl,dagger,advisor run): data -> filter -> train -> evaluate -> maze -> render -> "
        "report -> publish -> PDF, over one worker process per core. Prints its plan and "
        "estimated wall time first. Resumable: rerun the same command after an interruption."))
    parser.add_argument("--profile", choices=tuple(PROFILES), default="laptop",
                        help="smoke (minutes, CI), laptop (the default: 1,000 updates, "
                             "about 3 h on 2 cores; the plan printed first gives the estimate "
                             "for this machine), quick (the laptop network "
                             "at 300 updates, about 50 min on 2 cores, below the competence "
                             "targets), gpu (the laptop's updates with 4x the seeds and "
                             "validation scenarios; one GPU), paper (the paper's sizes; GPUs)")
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
    parser.add_argument("--methods", default=",".join(METHODS), metavar="METHODS",
                        help="comma-separated registered learning methods to train and "
                             "compare (igdrivsim/training/methods/); dagger and advisor are taught "
                             "by the better full-setting run of the others")
    parser.add_argument("--set", dest="overrides", action="append", default=[],
                        metavar="SECTION.FIELD=VALUE",
                        help="override a config field for every training run (repeatable; "
                             "not observation.setting or training.method), e.g. "
                             "--set training.num_updates=400; use a fresh --out for it")
    parser.add_argument("--workers", type=int, default=0, metavar="N",
                        help="worker processes for the (setting, method) grid, the maze and "
                             "the evaluations (0: one per CPU core, one XLA thread each; two "
                             "on an accelerator); the numbers do not depend on it")
    parser.add_argument("--in-process", action="store_true",
                        help="run the commands in this Python process (faster for smoke)")
    parser.add_argument("--no-progress", dest="quiet", action="store_true",
                        help="do not echo stage output and progress bars on the terminal (the "
                             "logs in WORK/logs/ are complete either way)")
    parser.add_argument("--samples", dest="samples", nargs="+", action="extend",
                        default=None, metavar="DIR",
                        help="real scenarios for Fig. 1 and the real-log table, besides the "
                             "samples cache (always used when fetched): folders of igdrivsim "
                             "samples, or any WOMD / ScenarioNet / GPUDrive locations (several "
                             "allowed, repeatable); none and no cache: synthetic Fig. 1, no "
                             "real-log table")
    return parser


def resolve_samples(given: list[str] | str | None) -> tuple[str, ...]:
    """Every real-scenario location of the run: the verified samples cache (when fetched),
    then each ``--samples`` location (``igdrivsim samples``' folder, or any data location),
    each once."""
    found = samples.find_samples()
    out = [] if found is None else [str(found)]
    for where in [given] if isinstance(given, str) else (given or []):
        if (folder := samples.find_samples(where)) is not None:
            where = str(folder)
        elif Path(where).is_dir() and not any(Path(where).iterdir()):
            raise ConfigError(f"--samples {where}: empty; fetch the public samples there with: "
                              f"igdrivsim samples --out {where}")
        else:
            expand_paths(where)  # names files, else a one-line error (before any stage)
        if not any(Path(where).resolve() == Path(o).resolve() for o in out):
            out.append(where)
    return tuple(out)


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
            for where in (train, val):
                expand_paths(where)  # names files, else a one-line error (before any stage)
        else:
            raise ConfigError("--data takes one folder or two locations (TRAIN VAL)")
    work, paper = ((Path(args.out), Path(args.out) / "paper") if args.out
                   else (REPO_ROOT / "outputs" / profile.name, REPO_ROOT / "paper"))
    require_folder(work)
    settings = tuple(s.strip() for s in args.settings.split(",")) if args.settings else None
    if settings is not None and (not all(settings) or len(set(settings)) != len(settings)):
        raise ConfigError(f"--obs must name distinct settings, got {args.settings!r}")
    for override in args.overrides:
        key = override.partition("=")[0].strip()
        if key in ("observation.setting", "training.method"):
            raise ConfigError(f"--set {override}: the pipeline sets {key} itself (use --obs / "
                              "--methods)")
    methods = tuple(m.strip() for m in args.methods.split(",") if m.strip())
    if not methods or len(set(methods)) != len(methods):
        raise ConfigError(f"--methods must name distinct methods, got {args.methods!r}")
    # get_method: a registered method, else a one-line error naming the choices
    taught = [m for m in methods if get_method(m).teacher]
    if taught and (len(taught) == len(methods)
                   or (settings is not None and TEACHER_SETTING not in settings)):
        raise ConfigError("--methods: a method with a privileged teacher needs a method "
                          f"without one (bc, bc_rl) trained on the {TEACHER_SETTING!r} "
                          "setting to pick the teacher from")

    with_overrides(get_profile(args.profile), args.overrides)  # a bad --set fails here, clearly
    if args.workers < 0:
        raise ConfigError(f"--workers must be >= 0, got {args.workers}")
    return Pipeline(profile, work, paper, train, val, in_process=args.in_process,
                    quiet=args.quiet, settings=settings, methods=methods,
                    overrides=tuple(args.overrides), workers=args.workers,
                    samples=resolve_samples(args.samples),
                    samples_given=tuple(args.samples or ()))


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    on_main = threading.current_thread() is threading.main_thread()
    if on_main:
        # `kill` stops the stages as Ctrl-C does, while this call runs (then the caller's
        # handler is back: a process that called main() keeps its own)
        previous = signal.signal(signal.SIGTERM, signal.default_int_handler)
    pipeline = None

    def body() -> None:
        nonlocal pipeline
        pipeline = pipeline_from_args(args)
        pipeline.run()

    try:
        return run_command("reproduce", body)
    except KeyboardInterrupt:
        if pipeline is not None:
            pipeline.stop()
        print("reproduce: interrupted; rerun the same command to resume", file=sys.stderr)
        return 130
    finally:
        if on_main:
            signal.signal(signal.SIGTERM, signal.SIG_DFL if previous is None else previous)
