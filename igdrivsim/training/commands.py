"""``igdrivsim train``: train policies (settings and seeds in one program; usage:
docs/training.md). A complete run is left alone (exit 0), so pipelines can re-run the command;
several hosts run the same command with ``JAX_COORDINATOR_ADDRESS``, ``JAX_NUM_PROCESSES`` and
``JAX_PROCESS_ID`` set.
"""

from __future__ import annotations

import argparse
import os
import sys

from igdrivsim.core.devices import maybe_init_distributed
from igdrivsim.data.egos import EGO_MODES
from igdrivsim.data.manifest import MANIFEST
from igdrivsim.data.source import check_data
from igdrivsim.errors import ConfigError, check_min
from igdrivsim.io import require_folder
from igdrivsim.observation import PRESETS, get_setting
from igdrivsim.training.config import PROFILES, get_profile, with_overrides
from igdrivsim.training.methods import METHODS


def train_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = ("train policies with a registered learning method: "
                          + ", ".join(f"{m.label} ({name})" for name, m in METHODS.items()))
    parser.add_argument("--profile", choices=list(PROFILES), default="laptop",
                        help="named configuration (default: laptop)")
    parser.add_argument("--obs", default=None, metavar="SETTING",
                        help=f"observation setting: {', '.join(PRESETS)} (compose with '+'; "
                             "comma-separate several) (default: the profile's, full)")
    parser.add_argument("--method", choices=list(METHODS), default=None,
                        help="a registered learning method, " + " or ".join(METHODS)
                             + " (default: the profile's, bc)")
    parser.add_argument("--seeds", type=int, default=None,
                        help="number of seeds, vmapped (default: the profile's, 3 for laptop)")
    parser.add_argument("--data", required=True,
                        help=f"training data: a folder (with a filter {MANIFEST}, or "
                             "files of any format read: TFRecords, ScenarioNet .pkl, GPUDrive "
                             ".json); a folder holding training/ and validation/ (as written by"
                             " `igdrivsim generate`) means its training/")
    parser.add_argument("--out", required=True, help="run folder")
    parser.add_argument("--egos", choices=EGO_MODES, default=None,
                        help="sdc: each scenario from its logged SDC; all: one scenario per "
                             "vehicle valid over the window that passes the scenario filter as "
                             "the ego (default: the profile's data.egos, sdc)")
    parser.add_argument("--val-data", default=None, metavar="DIR",
                        help="validation data for the learning curves (curves.jsonl): "
                             "closed-loop metrics every training.eval_every updates")
    parser.add_argument("--cache-dir", default=None, metavar="DIR",
                        help="cache of the teacher-forced observations, shared by runs on "
                             "the same data (default: DATA/../cache when DATA is a folder)")
    parser.add_argument("--resume", action="store_true", help="continue an unfinished run")
    parser.add_argument("--set", dest="overrides", action="append", default=[],
                        metavar="SECTION.FIELD=VALUE",
                        help="override any config field, e.g. training.lr=3e-4 (repeatable; "
                             "applied after --obs/--method/--seeds, which it may not contradict)")
    parser.add_argument("--stop-after", type=int, default=None, metavar="K",
                        help="debug: stop (with a checkpoint) after K updates")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


# the config field each shortcut option sets
SHORTCUTS = {"observation.setting": "--obs", "training.method": "--method",
             "training.seeds": "--seeds", "data.egos": "--egos"}


def refuse_contradictions(shortcuts: list[str], overrides: list[str] | tuple[str, ...]) -> None:
    """One-line error when a ``--set`` override contradicts a shortcut option's
    ``key=value`` (``--obs``, ``--method``, ``--seeds``)."""
    for shortcut in shortcuts:
        key, value = shortcut.split("=", 1)
        for override in overrides:
            okey, _, ovalue = override.partition("=")
            if okey.strip() == key and ovalue.strip() != value:
                raise ConfigError(f"--set {override} contradicts {SHORTCUTS[key]} {value}; "
                                  f"give one of them")


def resolve_config(args: argparse.Namespace):
    """The run's config: profile, then the shortcut options, then ``--set`` overrides."""
    shortcuts = [f"{key}={value}" for key, option in SHORTCUTS.items()
                 if (value := getattr(args, option[2:], None)) is not None]
    refuse_contradictions(shortcuts, args.overrides)
    config = with_overrides(get_profile(args.profile), shortcuts + list(args.overrides))
    for name in config.observation.setting.split(","):
        get_setting(name)  # fail early on an unknown setting
    return config.validate()


def resolve_data(data: str) -> str:
    """``DATA/training`` when DATA is a generated folder (``training/`` and ``validation/``)."""
    check_data(data, "training")
    split = os.path.join(data, "training")
    if os.path.isdir(split) and os.path.isdir(os.path.join(data, "validation")):
        print(f"igdrivsim train: using the training split {split} (validation/ is for "
              f"--val-data and evaluate)", file=sys.stderr)
        return split
    return data


def train_command(args: argparse.Namespace) -> int:
    config = resolve_config(args)
    check_min("--stop-after", args.stop_after, 0)
    require_folder(args.out)
    if args.cache_dir:
        require_folder(args.cache_dir, "--cache-dir")
    defaulted = [f"{opt} {value}" for opt, given, value in (
        ("--obs", args.obs, config.observation.setting),
        ("--method", args.method, config.training.method)) if given is None]
    if defaulted:
        print(f"igdrivsim train: using the {args.profile} profile's {', '.join(defaulted)}",
              file=sys.stderr)
    args.data = resolve_data(args.data)
    maybe_init_distributed()
    cache = args.cache_dir
    if cache is None and os.path.isdir(args.data):
        cache = os.path.join(os.path.dirname(os.path.abspath(args.data)), "cache")
    # lazy: keeps `igdrivsim train --help` fast (the loop pulls in orbax and grain)
    from igdrivsim.training.loop import train

    result = train(config, args.data, args.out, resume=args.resume, stop_after=args.stop_after,
                   progress=not args.no_progress, val_data=args.val_data, cache_dir=cache)
    if result.complete and result.updates_done >= 0:
        print(f"trained {result.num_updates} updates in {result.seconds:.1f} s -> {args.out}")
    elif not result.complete:
        print(f"stopped after {result.updates_done}/{result.num_updates} updates "
              f"(continue with --resume) -> {args.out}")
    return 0
