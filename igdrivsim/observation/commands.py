"""``igdrivsim render``: the observation-model pictures (paper Fig. 1) and a rollout animation."""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

import jax

import igdrivsim.simulator as sim
from igdrivsim.data import decode_scenario_id, load_scenario
from igdrivsim.data.formats import format_of
from igdrivsim.data.samples import find_samples
from igdrivsim.data.synthetic.plot import GENERATED_ID
from igdrivsim.errors import ConfigError, DataError, check_min
from igdrivsim.io import require_folder
from igdrivsim.observation import render
from igdrivsim.observation.models import PAPER_SETTINGS, get_setting

REPO_ROOT = Path(__file__).resolve().parents[2]
DEFAULT_DATA = REPO_ROOT.parent / "shared" / "data" / "womd" / "motion_data_one_example.tfrecord"


def render_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--data", default=None,
                        help=f"WOMD file (tf.Example or Scenario proto) or ScenarioNet / "
                             f"MetaDrive pickle (default: {DEFAULT_DATA} when present, else the "
                             "first of igdrivsim samples' cache)")
    parser.add_argument("--record", type=int, default=0, help="record index in the file")
    parser.add_argument("--out", default=str(REPO_ROOT / "paper" / "figures"),
                        help="output directory (default: paper/figures)")
    parser.add_argument("--step", type=int, default=10,
                        help="simulator timestep of the Fig. 1 panels (10..90, expert replay)")
    parser.add_argument("--gif", nargs="?", const="", default=None, metavar="PATH",
                        help="also write an animation of the expert replay to PATH (default "
                             "when given without PATH: OUT/rollout_<setting>.gif)")
    parser.add_argument("--obs", dest="setting", default="circular_r6", metavar="SETTING",
                        help="observation setting of the animation (a preset, '+' composes)")
    parser.add_argument("--panels", default=None, metavar="SETTINGS",
                        help="comma-separated settings of the Fig. 1 panels (default: the paper's "
                             "six; e.g. full,occlusion)")
    parser.add_argument("--view", type=float, default=30.0, help="panel size scale (metres)")
    parser.add_argument("--seed", type=int, default=0, help="PRNG seed (noise, masking)")
    parser.add_argument("--every", type=int, default=1, help="animate every N-th step")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def _data_path(args) -> str:
    path = args.data
    if path is None:
        if DEFAULT_DATA.exists():
            return str(DEFAULT_DATA)
        if (samples := find_samples()) is not None:  # fetched by igdrivsim samples
            return str(sorted(samples.glob("*.pkl"))[0])
        raise DataError(f"no --data given, the default sample {DEFAULT_DATA} is missing and no "
                        "public samples are fetched (igdrivsim samples)")
    if not os.path.exists(path):
        raise DataError("file not found", file=path)
    return path


def scene_source(path: str, scenario) -> str:
    """What the figure shows, said in it: a synthetic scenario or a real one (and its dataset)."""
    sid = decode_scenario_id(scenario.scenario_id)
    if GENERATED_ID.fullmatch(sid):
        return f"synthetic scenario {sid} (igdrivsim's generator, not a real log)"
    dataset = format_of(path).dataset(path)
    return f"real {dataset or 'logged'} scenario {sid} ({os.path.basename(path)})"


def render_command(args) -> int:
    require_folder(args.out)
    if not 10 <= args.step <= 90:
        raise ConfigError(f"--step must be in 10..90, got {args.step}")
    if not args.view > 0:  # also rejects nan
        raise ConfigError(f"--view must be > 0, got {args.view:g}")
    check_min("--every", args.every, 1)
    check_min("--record", args.record, 0)
    setting = get_setting(args.setting)  # fail early on a bad name
    panels = ([p.strip() for p in args.panels.split(",") if p.strip()]
              if args.panels is not None else list(PAPER_SETTINGS))
    if not panels:
        raise ConfigError(f"--panels names no setting, got {args.panels!r}")
    for name in panels:
        get_setting(name)

    path = _data_path(args)
    scenario = load_scenario(path, args.record)
    state = jax.jit(sim.reset)(scenario)
    key = jax.random.PRNGKey(args.seed)
    states = render.expert_states(state, 80 if args.gif is not None else args.step - 10)
    source = scene_source(path, scenario)
    written = render.write_observation_figure(states[args.step - 10], args.out, panels,
                                              key, args.view, source=source)
    if args.gif is not None:
        gif = args.gif or os.path.join(args.out, f"rollout_{setting.name.replace('+', '_')}.gif")
        written.append(render.write_rollout_animation(
            states, setting, gif, key, args.view, every=args.every,
            progress=not args.no_progress))
    print(json.dumps({"data": path, "record": args.record, "step": args.step,
                      "source": source, "written": written}))
    return 0
