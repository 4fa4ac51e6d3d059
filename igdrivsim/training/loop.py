"""The training driver: config.json, data, parameters, the update loop, metrics, checkpoints.

``train(config, data, out_dir)`` runs (or resumes, or recognises as complete) one run: every
setting of ``config.observation.setting`` (a comma list; settings as data, one compiled
program) x ``config.training.seeds`` seeds. Layout of ``out_dir``:

- ``config.json``: the resolved :class:`RunConfig` (plus ``num_updates`` and the device count);
- ``metrics.jsonl``: one line per logged update (``update`` = updates done, ``bc_loss``, ``lr``,
  ``entropy``, ``grad_norm``, ``updates_per_s``, ``scenario_steps_per_s``,
  ``grad_steps_per_s``; BC-RL adds ``mean_return``, ``ppo_loss``, ``value_loss``,
  ``clip_frac``, ``ratio_dev``); each metric is the mean over settings and seeds, and
  ``<metric>_seeds`` lists the per-seed values (mean over settings);
- ``curves.jsonl``: learning curves, one line per (update, setting, seed): the training
  ``bc_loss`` at every logged update and, every ``training.eval_every`` updates when
  validation data is given, ``val_bc_loss`` (teacher-forced, fixed validation subset) and the
  closed-loop ``log_divergence`` (m), ``offroad`` and ``overlap`` (fractions of steps) of the
  policy driving that subset (sampled actions);
- ``checkpoints/<updates done>/`` (orbax), every ``checkpoint_every`` updates and at the end;
  with a streamed input (``data.stream``), ``checkpoints/data/<updates done>.p<process>.json``
  holds each process's input iterator state, restored by ``--resume``;
- ``DONE``: written when the last checkpoint is saved.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import os
import time
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np
from tqdm.auto import tqdm

from igdrivsim.data.validation import load_validation
from igdrivsim.errors import ConfigError, DataError
from igdrivsim.io import atomic_write_json, atomic_write_text
from igdrivsim.policy.act import example_observation
from igdrivsim.policy.network import count_params, init_params_per_seed
from igdrivsim.training import inputs
from igdrivsim.training.checkpoint import Checkpoints
from igdrivsim.training.closed_loop import evaluate_policy
from igdrivsim.training.config import RunConfig, from_dict, to_dict
from igdrivsim.training.cost import warn_if_cpu
from igdrivsim.training.privileged import TEACHER_SETTING, teacher_config
from igdrivsim.training.update import (
    UpdateSpec,
    cosine_lr,
    empty_aggregate,
    make_update,
    make_validation_loss,
    optimizer,
    run_settings,
    settings_as_data,
    update_spec,
)

CONFIG, METRICS, CURVES, DONE = "config.json", "metrics.jsonl", "curves.jsonl", "DONE"
_UPDATE_CACHE: dict[UpdateSpec, object] = {}


@dataclass
class TrainResult:
    params: object  # stacked over seeds
    updates_done: int
    num_updates: int
    complete: bool
    seconds: float


def total_updates(config: RunConfig, num_scenarios: int) -> int:
    t = config.training
    if t.num_updates > 0:
        return t.num_updates
    return max(1, math.ceil(t.epochs * num_scenarios / config.data.batch_size))


def seed_keys(config: RunConfig) -> jax.Array:
    t = config.training
    return jax.vmap(jax.random.PRNGKey)(np.arange(t.seed_offset, t.seed_offset + t.seeds))


def init_state(config: RunConfig, spec: UpdateSpec):
    """Parameters and optimiser state ``[G, S]`` for every setting and seed; a seed starts
    from the same parameters in every setting (the settings' comparison is paired)."""
    keys = seed_keys(config)
    init_keys = jax.vmap(lambda k: jax.random.fold_in(k, 2**31 - 1))(keys)
    params = init_params_per_seed(config.policy, list(init_keys), example_observation(spec.obs))
    groups = len(run_settings(config))
    params = jax.tree.map(lambda x: jnp.broadcast_to(x[None], (groups, *x.shape)), params)
    opt_state = jax.vmap(jax.vmap(optimizer(spec).init))(params)
    return params, opt_state


def init_buffer(config: RunConfig, spec: UpdateSpec):
    """DAgger's empty buffers ``[G, S]`` (``None`` for methods without one)."""
    one = empty_aggregate(spec, config.data.batch_size)
    if one is None:
        return None
    shape = (len(run_settings(config)), config.training.seeds)
    return jax.tree.map(lambda x: jnp.broadcast_to(x, (*shape, *x.shape)), one)


def get_update(spec: UpdateSpec):
    """The compiled update for ``spec`` (shared by every run in this process)."""
    if spec not in _UPDATE_CACHE:
        _UPDATE_CACHE[spec] = make_update(spec)
    return _UPDATE_CACHE[spec]


def is_complete(out_dir: str) -> bool:
    return os.path.isfile(os.path.join(out_dir, DONE))


def _check_config(out_dir: str, record: dict) -> None:
    """Refuse to resume a run started with another configuration (fields added to the config
    classes since then count at their defaults)."""
    path = os.path.join(out_dir, CONFIG)
    with open(path) as f:
        old = json.load(f)
    try:
        old_config = to_dict(from_dict(old.get("config", {})))
    except (ConfigError, TypeError):
        old_config = old.get("config")
    if json.loads(json.dumps(old_config)) != json.loads(json.dumps(record["config"])):
        raise ConfigError(f"{path}: the run was started with a different configuration; "
                          "use another --out or the same options")


def _truncate_jsonl(path: str, upto: int) -> None:
    """Keep the lines of updates ``<= upto`` (a resumed run re-logs the rest); a line torn by
    a kill mid-write (not JSON, or without an update) is dropped with the rest."""
    if not os.path.isfile(path):
        return

    def update_of(line: str) -> int | None:
        try:
            entry = json.loads(line)
        except ValueError:
            return None
        return entry.get("update") if isinstance(entry, dict) else None

    with open(path) as f:
        kept = [ln if ln.endswith("\n") else ln + "\n" for ln in f
                if isinstance(u := update_of(ln), int) and u <= upto]
    atomic_write_text(path, "".join(kept))


def _log_line(update: int, lr: float, metrics: dict, rates: dict) -> dict:
    line = {"update": update, "lr": lr, **rates}
    for name, values in metrics.items():
        values = np.asarray(values, np.float64)  # [G, S]
        line[name] = float(values.mean())
        line[f"{name}_seeds"] = [float(v) for v in values.mean(axis=0)]
    return line


def _curve_lines(update: int, settings: list[str], method: str, seeds: list[int],
                 values: dict) -> list[dict]:
    """One curves.jsonl line per (setting, seed) from ``{name: [G, S] array}``."""
    return [{"update": update, "setting": name, "method": method, "seed": seed,
             **{k: float(np.asarray(v)[g, i]) for k, v in values.items()}}
            for g, name in enumerate(settings) for i, seed in enumerate(seeds)]


class Validation:
    """The fixed validation subset a run is judged on while it trains: teacher-forced BC loss
    and closed-loop metrics of every (setting, seed)."""

    def __init__(self, config: RunConfig, spec: UpdateSpec, data, cache_dir: str | None):
        n = config.training.val_scenarios
        self.config, self.spec = config, spec
        self.teacher = inputs.Dataset.from_config(
            config, data, spec.sim, cache_dir=cache_dir, max_scenarios=n, record=True).teacher
        self.scenarios = load_validation(data, inputs.capacities(config), n)
        self.loss = make_validation_loss(spec)
        self.settings = settings_as_data(config)

    def __call__(self, params) -> dict:
        c = self.config
        val_bc = self.loss(params, jax.tree.map(jnp.asarray, self.teacher), self.settings,
                           jax.random.key(0))
        out = evaluate_policy(params, self.scenarios, policy_config=c.policy,
                              setting=run_settings(c), obs_config=self.spec.obs,
                              params=self.spec.sim, batch_size=c.training.val_scenarios)
        valid = out.valid
        count = np.maximum(valid.sum(axis=(2, 3)), 1)
        mean = lambda a: np.where(valid, a, 0.0).sum(axis=(2, 3)) / count  # noqa: E731
        return {"val_bc_loss": np.asarray(val_bc), "log_divergence": mean(out.log_divergence),
                "offroad": mean(out.offroad), "overlap": mean(out.overlap)}


def barrier(name: str, timeout_s: int = 3600) -> None:
    """Wait until every process gets here (several processes only). Gloo's CPU collectives give
    up after 30 s, so processes meet here before work whose duration differs between them
    (compiling, loading) is followed by a collective."""
    if jax.process_count() > 1:
        from jax._src import distributed  # private JAX API: only for several processes

        distributed.global_state.client.wait_at_barrier(f"igdrivsim-{name}", timeout_s * 1000)


def load_teacher(run_dir: str, student: RunConfig):
    """The teacher's ``full``-setting parameters stacked over the student's seeds ``[S]``."""
    teacher_config(run_dir, student)
    if not is_complete(run_dir):
        raise ConfigError(f"training.teacher: {run_dir} has not finished training")
    config, params = load_run(run_dir)
    g = run_settings(config).index(TEACHER_SETTING)
    seeds = config.training.seeds
    pick = np.arange(student.training.seeds) % seeds
    return jax.tree.map(lambda x: jnp.asarray(x[g])[pick], params)


def train(config: RunConfig, data, out_dir: str | os.PathLike, resume: bool = False,
          stop_after: int | None = None, progress: bool = True, devices=None,
          log=print, val_data=None, cache_dir: str | None = None) -> TrainResult:
    """Train (or resume) one run; see the module docstring. ``data``: a folder / files, or a
    list of :class:`~igdrivsim.data.scenario.Scenario`. ``val_data``: validation data for the
    learning curves (none: training BC loss only). ``cache_dir``: where the teacher-forced
    records are cached (none: computed, not saved). ``stop_after``: stop (with a checkpoint)
    once that many updates are done (a debugging aid for resume tests)."""
    config = config.validate()
    out_dir = os.fspath(out_dir)
    start_time = time.perf_counter()
    os.makedirs(out_dir, exist_ok=True)
    record = {"config": to_dict(config)}
    if os.path.isfile(os.path.join(out_dir, CONFIG)):
        _check_config(out_dir, record)
        if is_complete(out_dir):
            log(f"run {out_dir} is already complete; nothing to do")
            return TrainResult(None, -1, -1, True, 0.0)
        if not resume:
            raise ConfigError(f"{out_dir} holds an unfinished run; pass --resume to continue it")
    # every process has looked at the folder before process 0 writes config.json below
    # (otherwise a slower process would find it and refuse to start a "resumed" run)
    barrier("checked")
    spec = update_spec(config)
    settings_list = run_settings(config)
    mesh = inputs.make_mesh(devices)
    inputs.check_batch(config.data.batch_size, mesh)
    main = jax.process_index() == 0
    if config.data.stream:  # paper scale: per-process shards decoded on demand
        from igdrivsim.training.stream import StreamDataset  # lazy: grain, only for data.stream

        dataset = StreamDataset.from_config(config, data, spec.sim)
    else:
        dataset = inputs.Dataset.from_config(config, data, spec.sim, progress and main,
                                             cache_dir=cache_dir,
                                             need_states=config.collects_rollout)
    num_updates = total_updates(config, dataset.num)
    if main:  # the paper profile without an accelerator: say how long it would take
        warn_if_cpu(config, dataset.num, jax.default_backend(), mesh.size)
    record |= {"num_updates": num_updates, "num_scenarios": dataset.num,
               "settings": settings_list, "devices": mesh.size,
               "processes": jax.process_count()}
    if main:
        atomic_write_json(os.path.join(out_dir, CONFIG), record, indent=2)
    validation = None
    t = config.training
    if val_data is not None and t.eval_every > 0:
        validation = Validation(config, spec, val_data, cache_dir)

    params, opt_state = init_state(config, spec)
    buffer = init_buffer(config, spec)
    teacher_params = None
    if spec.learner.teacher:
        teacher_params = load_teacher(t.teacher, config)
        log(f"privileged teacher: the full setting of {t.teacher}")
    per_seed = count_params(jax.tree.map(lambda x: x[0, 0], params))
    log(f"policy: {per_seed:,} parameters per run x {len(settings_list)} setting(s) x "
        f"{t.seeds} seeds; {dataset.num} scenarios, {num_updates} updates of "
        f"{config.data.batch_size} scenarios on {mesh.size} device(s)")
    rep = inputs.replicated(mesh)
    params, opt_state = inputs.place(params, rep), inputs.place(opt_state, rep)
    buffer, teacher_params = inputs.place(buffer, rep), inputs.place(teacher_params, rep)
    settings = settings_as_data(config)
    settings = None if settings is None else inputs.place(settings, rep)
    barrier("start")
    ckpt = Checkpoints(out_dir, t.max_checkpoints)
    start, data_state = 0, None
    if resume and ckpt.latest_step() is not None:
        start = ckpt.latest_step()
        params, opt_state, buffer = ckpt.restore(start, params, opt_state, buffer)
        if config.data.stream:
            from igdrivsim.training.stream import load_state  # lazy: grain, only for data.stream

            data_state = load_state(out_dir, start)
        log(f"resuming from update {start}")
    metrics_path = os.path.join(out_dir, METRICS)
    curves_path = os.path.join(out_dir, CURVES)
    if main:
        _truncate_jsonl(metrics_path, start if resume else -1)
        _truncate_jsonl(curves_path, start if resume else -1)
    end = num_updates if stop_after is None else min(num_updates, stop_after)
    update = get_update(spec)
    keys = inputs.place(seed_keys(config), rep)
    seeds = list(range(t.seed_offset, t.seed_offset + t.seeds))
    runs = len(settings_list) * t.seeds
    steps_per_update = runs * config.data.batch_size * 80 * t.ppo_epochs
    grads_per_update = runs * t.ppo_epochs * t.ppo_minibatches
    bar = None
    if progress and main:
        bar = tqdm(total=num_updates, initial=start, unit="upd", desc="train", dynamic_ncols=True)
    batches = inputs.prefetch(dataset, range(start, end), inputs.batch_sharding(mesh),
                              config.data.prefetch, data_state)
    last_log, last_time = start, time.perf_counter()

    def write_curves(f, done, values):
        for line in _curve_lines(done, settings_list, t.method, seeds, values):
            f.write(json.dumps(line) + "\n")
        f.flush()

    with contextlib.ExitStack() as stack:
        opener = (lambda p: open(p, "a")) if main else (lambda p: open(os.devnull, "w"))
        metrics_file = stack.enter_context(opener(metrics_path))
        curves_file = stack.enter_context(opener(curves_path))
        if validation is not None and start == 0:
            write_curves(curves_file, 0, validation(params))
        for u, ((teacher, states), data_state) in zip(range(start, end), batches, strict=True):
            lr = cosine_lr(u, num_updates, t.lr, t.lr_end)
            if u == start and jax.process_count() > 1:  # compile everywhere, then meet
                update = update.lower(params, opt_state, buffer, teacher, states, settings,
                                      teacher_params, keys, u, lr).compile()
                barrier("compiled")
            params, opt_state, buffer, metrics = update(
                params, opt_state, buffer, teacher, states, settings, teacher_params, keys, u,
                lr)
            done = u + 1
            if bar is not None:
                bar.update()
            if done % t.log_every == 0 or done == end:
                metrics = jax.device_get(metrics)
                now = time.perf_counter()
                rate = (done - last_log) / max(now - last_time, 1e-9)
                line = _log_line(done, lr, metrics, {
                    "updates_per_s": rate, "scenario_steps_per_s": rate * steps_per_update,
                    "grad_steps_per_s": rate * grads_per_update})
                metrics_file.write(json.dumps(line) + "\n")
                metrics_file.flush()
                loss_key = "bc_loss" if "bc_loss" in metrics else "teacher_ce"
                write_curves(curves_file, done, {loss_key: metrics[loss_key]})
                if bar is not None:
                    bar.set_postfix({loss_key: f"{line[loss_key]:.3f}"}, refresh=False)
                last_log, last_time = done, time.perf_counter()
            if validation is not None and (done % t.eval_every == 0 or done == num_updates):
                write_curves(curves_file, done, validation(params))
                last_time = time.perf_counter()  # rates measure training only
            if done % t.checkpoint_every == 0 or done == end:
                if data_state is not None:  # the input iterator's state, saved first
                    # lazy: grain, only for data.stream
                    from igdrivsim.training.stream import save_state

                    save_state(out_dir, done, data_state, ckpt.manager.all_steps())
                barrier(f"save-{done}")
                ckpt.save(done, params, opt_state, buffer)
    if bar is not None:
        bar.close()
    ckpt.close()
    complete = end == num_updates
    if complete and main:
        atomic_write_text(os.path.join(out_dir, DONE), f"{num_updates}\n")
    return TrainResult(params, end, num_updates, complete, time.perf_counter() - start_time)


def load_run(run_dir: str | os.PathLike, step: int | None = None):
    """``(RunConfig, params stacked over settings and seeds [G, S])`` from a run folder
    (latest checkpoint); the settings are :func:`~igdrivsim.training.update.run_settings`."""
    run_dir = os.fspath(run_dir)
    path = os.path.join(run_dir, CONFIG)
    if not os.path.isfile(path):
        raise ConfigError(f"{path}: not a training run (no {CONFIG})")
    try:
        with open(path) as f:
            record = json.load(f)
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise DataError(f"cannot read the run's config ({err})", file=path) from err
    if not isinstance(record, dict) or not isinstance(record.get("config"), dict):
        raise DataError("not a run config (no \"config\" object)", file=path)
    config = from_dict(record["config"])
    spec = update_spec(config, teacher_policy=config.policy)  # shapes only: no teacher read
    params_like, opt_like = jax.eval_shape(lambda: init_state(config, spec))
    # the checkpoint's tree must be restored whole: DAgger's buffer too (then dropped)
    buffer_like = jax.eval_shape(lambda: init_buffer(config, spec))
    ckpt = Checkpoints(run_dir)
    step = ckpt.latest_step() if step is None else step
    if step is None:
        ckpt.close()
        raise ConfigError(f"{run_dir}: no checkpoint yet")
    try:
        params, _, _ = ckpt.restore(step, params_like, opt_like, buffer_like)
    finally:
        ckpt.close()
    return config, params


def replace_training(config: RunConfig, **changes) -> RunConfig:
    return dataclasses.replace(config, training=dataclasses.replace(config.training, **changes))
