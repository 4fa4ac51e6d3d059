"""``igdrivsim bench train``: training samples/s and gradient steps/s of a profile.

Times a method's whole jitted update for every ``--obs`` setting and seed in one program, on
straight-road scenarios, after compiling it and one untimed call (the teacher-forced records,
made once per dataset, are not timed). A *sample* is one scenario at one controlled step; a
gradient step one Adam step of one (setting, seed). Prints one JSON line per profile.
"""

from __future__ import annotations

import argparse
import dataclasses
import glob
import gzip
import json
import os
import re
import time
from collections import Counter

import jax
import numpy as np

from igdrivsim.core.devices import batch_sharding, make_mesh, place, replicated
from igdrivsim.core.nn import matmul_flops
from igdrivsim.errors import ConfigError, check_min
from igdrivsim.io import atomic_write_json, require_file_target
from igdrivsim.machine import machine_record
from igdrivsim.observation.models import PAPER_SETTINGS, stack_settings
from igdrivsim.policy.act import example_observation
from igdrivsim.policy.network import apply_step, init_params_per_seed, initial_carry
from igdrivsim.simulator import toy
from igdrivsim.training import inputs
from igdrivsim.training.commands import refuse_contradictions
from igdrivsim.training.config import get_profile, with_overrides
from igdrivsim.training.methods import METHODS
from igdrivsim.training.update import (
    init_buffer,
    init_state,
    make_update,
    seed_keys,
    update_spec,
)


def bench_train_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--profiles", default="laptop,paper",
                        help="comma-separated profiles (default: laptop,paper)")
    parser.add_argument("--method", choices=list(METHODS), default=next(iter(METHODS)),
                        help="learning method (default: bc)")
    parser.add_argument("--obs", default=",".join(PAPER_SETTINGS), metavar="SETTINGS",
                        help="settings trained together, comma-separated (default: the "
                             "paper's six)")
    parser.add_argument("--batch-size", dest="batch", type=int, default=0,
                        help="scenarios per update (0: the profile's; paper on CPU: 8, the "
                             "batch of the CPU rates in igdrivsim/training/cost.py)")
    parser.add_argument("--seeds", type=int, default=0, help="seeds (0: the profile's)")
    parser.add_argument("--updates", type=int, default=3, help="timed updates (after compile)")
    parser.add_argument("--set", dest="overrides", action="append", default=[],
                        metavar="SECTION.FIELD=VALUE",
                        help="override a config field, as in `igdrivsim train` (repeatable)")
    parser.add_argument("--out", default=None, metavar="FILE",
                        help="also write the results and the machine they ran on to this JSON "
                             "file")
    parser.add_argument("--trace", default=None, metavar="DIR",
                        help="after timing, trace one more update with jax.profiler into DIR "
                             "(a Perfetto trace) and add its busiest operations to the record")
    parser.add_argument("--parts", action="store_true",
                        help="also time the update's parts alone, for the first setting and "
                             "seed (recording the teacher-forced episodes, the setting's "
                             "observations, the policy's rollout, one forward and backward "
                             "pass) into the record's parts_s")


def trace_summary(trace_dir: str, top: int = 15) -> dict:
    """The busiest device (on a CPU, XLA thread) operations of the Perfetto trace under
    ``trace_dir`` by total duration, digits folded (``fusion.123`` -> ``fusion.N``) so that a
    kernel kind sums its instances (shares of all lines' busy time); and the traced span."""
    files = sorted(glob.glob(os.path.join(trace_dir, "**", "perfetto_trace.json.gz"),
                             recursive=True))
    if not files:
        raise ConfigError(f"no perfetto_trace.json.gz under {trace_dir}")
    with gzip.open(files[-1], "rt") as f:
        events = json.load(f)
    events = events.get("traceEvents", events) if isinstance(events, dict) else events
    names = {e["pid"]: e.get("args", {}).get("name", "") for e in events
             if e.get("ph") == "M" and e.get("name") == "process_name"}
    threads = {(e["pid"], e.get("tid")): e.get("args", {}).get("name", "")
               for e in events if e.get("ph") == "M" and e.get("name") == "thread_name"}
    device = {pid for pid, n in names.items() if "/device:" in n}
    keep = device or {pid for pid, n in names.items() if "host" in n.lower()} or set(names)
    spans = [e for e in events if e.get("ph") == "X" and e.get("pid") in keep and "dur" in e]
    busy, count = Counter(), Counter()
    for e in spans:
        thread = re.sub(r"\d+", "N", threads.get((e["pid"], e.get("tid")), ""))
        name = thread + ": " + re.sub(r"\d+", "N", e.get("name", "?"))
        busy[name] += e["dur"] / 1e6
        count[name] += 1
    total = sum(busy.values())
    start = min((e["ts"] for e in spans), default=0.0)
    end = max((e["ts"] + e["dur"] for e in spans), default=0.0)
    rows = sorted(busy.items(), key=lambda kv: -kv[1])[:top]
    return {"trace_file": files[-1], "trace_span_s": round((end - start) / 1e6, 4),
            "trace_busy_s": round(total, 4), "trace_events": len(spans),
            "trace_top": [{"name": n, "seconds": round(t, 4), "share": round(t / total, 4),
                           "count": count[n]} for n, t in rows]}


def time_parts(spec, params, states, keys, teacher_params, repeats: int = 2) -> dict:
    """Seconds of each part of one update of the first setting and seed (record, observe,
    collect, forward and backward), each jitted and timed alone (mean of ``repeats`` calls)."""
    from functools import partial

    from igdrivsim.observation import get_setting
    from igdrivsim.training.update import _loss, collect, expert_sequences, record_episode

    def timed(fn, *args):
        jax.block_until_ready(fn(*args))
        t0 = time.perf_counter()
        for _ in range(repeats):
            out = fn(*args)
        jax.block_until_ready(out)
        return out, round((time.perf_counter() - t0) / repeats, 4)

    first = lambda tree: jax.tree.map(lambda x: x[0], tree)
    p, st, tp = first(first(params)), first(states), first(teacher_params)
    setting = spec.setting or get_setting("full")
    rec, record_s = timed(jax.jit(jax.vmap(lambda s: record_episode(s, spec.sim, spec.record))),
                          st)
    episode_keys = jax.random.split(first(keys), rec.sdc_yaw.shape[0])
    _, observe_s = timed(jax.jit(lambda r, k: expert_sequences(spec, r, setting, k)), rec,
                         episode_keys)
    data, collect_s = timed(jax.jit(lambda p, r, s, tp, k: collect(
        spec, p, None, r, s, setting, tp, k)[0]), p, rec, st, tp, first(keys))
    _, pass_s = timed(jax.jit(jax.value_and_grad(partial(_loss, spec), has_aux=True)), p, data)
    return {"record": record_s, "observe": observe_s, "collect": collect_s,
            "forward_backward": pass_s}


def bench_profile(profile: str, method: str = next(iter(METHODS)), batch: int = 0, seeds: int = 0,
                  updates: int = 3, overrides: tuple[str, ...] = (),
                  obs: str = ",".join(PAPER_SETTINGS), trace: str | None = None,
                  parts: bool = False) -> dict:
    """Measure one profile; returns the JSON record."""
    cpu = jax.default_backend() == "cpu"
    sets = [f"training.method={method}", f"observation.setting={obs}"]
    refuse_contradictions(sets, overrides)
    if any(o.partition("=")[0].strip() == "training.teacher" for o in overrides):
        raise ConfigError("bench train times a method's update with an untrained teacher of the "
                          "same network; --set training.teacher is not taken")
    if batch or (profile == "paper" and cpu):
        sets.append(f"data.batch_size={batch or 8}")
    if seeds or (profile == "paper" and cpu):
        sets.append(f"training.seeds={seeds or 1}")
    config = with_overrides(get_profile(profile), sets + list(overrides))
    minibatches = [f"training.{k}={min(getattr(config.training, k), config.data.batch_size)}"
                   for k in ("ppo_minibatches", "rollout_minibatches")]
    config = with_overrides(config, [*minibatches, "training.teacher=untrained"]).validate()
    # methods with a privileged teacher are timed with an untrained one of the same network
    teacher_policy = dataclasses.replace(config.policy, aux_head=False)
    spec = update_spec(config, teacher_policy)
    mesh = make_mesh()
    inputs.check_batch(config.data.batch_size, mesh)
    scenarios = [toy.straight_road(config.capacities, speed=4.0 + i % 8)
                 for i in range(config.data.batch_size)]
    dataset = inputs.Dataset.from_config(config, scenarios, spec.sim,
                                         need_states=config.collects_rollout)
    rep = replicated(mesh)
    params, opt_state = init_state(config, spec)
    n_params = int(sum(x[0, 0].size for x in jax.tree.leaves(params)))
    # the network's forward pass over one observation (one scenario at one step)
    step_flops = matmul_flops(lambda p, o: apply_step(config.policy, p, initial_carry(
        config.policy), o, jax.numpy.zeros((), bool)), jax.tree.map(lambda x: x[0, 0], params),
        example_observation(spec.obs))
    params, opt_state = place(params, rep), place(opt_state, rep)
    buffer = place(init_buffer(config, spec), rep)
    teacher_params = None
    if spec.learner.teacher:
        teacher_params = init_params_per_seed(
            teacher_policy, list(seed_keys(config)), example_observation(spec.obs))
    keys = place(seed_keys(config), rep)
    teacher, states = place(dataset.host_batch(0), batch_sharding(mesh))
    args = (teacher, states, stack_settings(config.settings), teacher_params, keys)
    t0 = time.perf_counter()
    update = make_update(spec).lower(params, opt_state, buffer, *args, 0, 1e-3).compile()
    compile_s = time.perf_counter() - t0
    flops = matmul_flops(make_update(spec), params, opt_state, buffer, *args, 0, 1e-3)
    t0 = time.perf_counter()
    params, opt_state, buffer, m = update(params, opt_state, buffer, *args, 0, 1e-3)
    jax.block_until_ready(params)
    first_s = time.perf_counter() - t0
    t0, c0 = time.perf_counter(), time.process_time()
    for u in range(1, updates + 1):
        params, opt_state, buffer, m = update(params, opt_state, buffer, *args, u, 1e-3)
    jax.block_until_ready(params)
    per_update = (time.perf_counter() - t0) / updates
    cpu_per_update = (time.process_time() - c0) / updates
    traced = {}
    if trace:
        with jax.profiler.trace(trace, create_perfetto_trace=True):
            params, opt_state, buffer, m = update(params, opt_state, buffer, *args, 0, 1e-3)
            jax.block_until_ready(params)
        traced = trace_summary(trace)
    if parts:
        with_states = inputs.Dataset.from_config(config, scenarios, spec.sim, need_states=True)
        traced["parts_s"] = time_parts(spec, params, with_states.host_batch(0)[1], keys,
                                       teacher_params)
    steps, grads = config.steps_per_update()
    return {"profile": profile, "method": method, "backend": jax.default_backend(),
            "devices": mesh.size, "params_per_seed": n_params,
            "forward_matmul_flops_per_step": step_flops, "seeds": config.training.seeds,
            "settings": len(config.settings), "batch": config.data.batch_size,
            "compile_s": round(compile_s, 2), "first_update_s": round(first_s, 2),
            "seconds_per_update": round(per_update, 4),
            "cpu_seconds_per_update": round(cpu_per_update, 4),
            "updates_per_s": round(1.0 / per_update, 3),
            "scenario_steps_per_s": round(steps / per_update, 1),
            "grad_steps_per_s": round(grads / per_update, 2),
            "matmul_flops_per_update": flops,
            "matmul_tflop_per_s": round(flops / per_update / 1e12, 4),
            spec.learner.reports: float(np.mean(jax.device_get(m[spec.learner.reports]))),
            **traced}


def bench_train_command(args: argparse.Namespace) -> int:
    names = [p.strip() for p in args.profiles.split(",") if p.strip()]
    if not names:
        raise ConfigError(f"--profiles names no profile, got {args.profiles!r}")
    check_min("--updates", args.updates, 1)
    check_min("--batch-size", args.batch, 0)
    check_min("--seeds", args.seeds, 0)
    for name in names:
        get_profile(name)  # an unknown name fails before anything is timed
    if args.out:
        require_file_target(args.out)
    records = []
    for name in names:
        trace = os.path.join(args.trace, name) if args.trace else None
        records.append(bench_profile(name, args.method, args.batch, args.seeds, args.updates,
                                     tuple(args.overrides), args.obs, trace, args.parts))
        print(json.dumps(records[-1]), flush=True)
    if args.out:
        atomic_write_json(args.out, {"machine": machine_record(), "records": records}, indent=2)
    return 0
