"""The training driver: data, I/O, checkpoints, logging and hooks around a run's pure
update (:func:`igdrivsim.training.update.make_update`), batch by batch. ``train(config, data,
out_dir)`` runs (or resumes) every setting x seed of ``config`` in one compiled program, into
the run folder ``out_dir`` (:mod:`igdrivsim.training.run`)."""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np
from tqdm.auto import tqdm

from igdrivsim.core.devices import barrier, batch_sharding, make_mesh, place, replicated
from igdrivsim.data.source import load_validation
from igdrivsim.observation import stack_settings
from igdrivsim.policy.closed_loop import evaluate_policy
from igdrivsim.policy.network import count_params
from igdrivsim.training import inputs
from igdrivsim.training.config import RunConfig
from igdrivsim.training.cost import warn_if_cpu
from igdrivsim.training.methods import get_method
from igdrivsim.training.privileged import load_teacher
from igdrivsim.training.run import Run
from igdrivsim.training.update import (
    UpdateSpec,
    cosine_lr,
    init_buffer,
    init_state,
    make_update,
    make_validation_loss,
    seed_keys,
    update_spec,
)


@dataclass
class TrainResult:
    params: object  # stacked over seeds
    updates_done: int
    num_updates: int
    complete: bool
    seconds: float


def validation(config: RunConfig, spec: UpdateSpec, data, cache_dir: str | None
               ) -> Callable[[object], dict]:
    """The hook judging a run on the fixed validation subset while it trains: teacher-forced
    BC loss and closed-loop metrics of every (setting, seed)."""
    n = config.training.val_scenarios
    teacher = inputs.Dataset.from_config(
        config, data, spec.sim, cache_dir=cache_dir, max_scenarios=n, record=True).teacher
    teacher = jax.tree.map(jnp.asarray, teacher)  # on the device once, not per hook
    scenarios = load_validation(data, config.capacities, n, egos=config.data.egos)
    loss, settings = make_validation_loss(spec), stack_settings(config.settings)

    def hook(params) -> dict:
        val_bc = loss(params, teacher, settings, jax.random.key(0))
        out = evaluate_policy(params, scenarios, policy_config=config.policy,
                              setting=config.settings, obs_config=spec.obs, params=spec.sim,
                              batch_size=n)
        valid = out.valid
        count = np.maximum(valid.sum(axis=(2, 3)), 1)
        mean = lambda a: np.where(valid, a, 0.0).sum(axis=(2, 3)) / count
        return {"val_bc_loss": np.asarray(val_bc), "log_divergence": mean(out.log_divergence),
                "offroad": mean(out.offroad), "overlap": mean(out.overlap)}

    return hook


def train(config: RunConfig, data, out_dir: str | os.PathLike, resume: bool = False,
          stop_after: int | None = None, progress: bool = True, log=print, val_data=None,
          cache_dir: str | None = None) -> TrainResult:
    """Train (or resume) one run. ``data``: a folder / files, or a list of scenarios;
    ``val_data``: validation data for the learning curves; ``cache_dir``: where the
    teacher-forced records are cached; ``stop_after``: stop (with a checkpoint) after that many
    updates (a debugging aid)."""
    config = config.validate()
    start_time = time.perf_counter()
    t = config.training
    run = Run(out_dir, config, resume, log)
    if run.complete_already():
        return TrainResult(None, -1, -1, True, 0.0)
    teacher_policy = teacher_params = None
    if get_method(t.method).teacher:
        teacher_policy, teacher_params = load_teacher(t.teacher, config)
        log(f"privileged teacher: the full setting of {t.teacher}")
    spec = update_spec(config, teacher_policy)
    mesh = make_mesh()
    inputs.check_batch(config.data.batch_size, mesh)
    if config.data.stream:  # paper scale: per-process shards decoded on demand
        from igdrivsim.training.stream import StreamDataset  # lazy: grain, only for data.stream

        dataset = StreamDataset.from_config(config, data, spec.sim)
    else:
        dataset = inputs.Dataset.from_config(config, data, spec.sim, progress and run.main,
                                             cache_dir=cache_dir,
                                             need_states=config.collects_rollout)
    num_updates = config.total_updates(dataset.num)
    if run.main:  # the paper profile without an accelerator: say how long it would take
        warn_if_cpu(config, dataset.num, jax.default_backend(), mesh.size)
    run.write_config(num_updates=num_updates, num_scenarios=dataset.num,
                     settings=config.settings, devices=mesh.size,
                     processes=jax.process_count())
    if val_data is not None and t.eval_every > 0:
        run.hook = validation(config, spec, val_data, cache_dir)

    state = (*init_state(config, spec), init_buffer(config, spec))
    per_seed = count_params(jax.tree.map(lambda x: x[0, 0], state[0]))
    log(f"policy: {per_seed:,} parameters per run x {len(config.settings)} setting(s) x "
        f"{t.seeds} seeds; {dataset.num} scenarios, {num_updates} updates of "
        f"{config.data.batch_size} scenarios on {mesh.size} device(s)")
    state, settings, teacher_params, keys = place(  # on every device
        (state, stack_settings(config.settings), teacher_params, seed_keys(config)),
        replicated(mesh))
    barrier("start")
    start, state = run.restore(state)
    data_state = None
    if start and config.data.stream:
        from igdrivsim.training.stream import load_state  # lazy: grain, only for data.stream

        data_state = load_state(run.data_states, start)
    end = num_updates if stop_after is None else min(num_updates, stop_after)
    steps_per_update, grads_per_update = config.steps_per_update()
    if progress and run.main:  # rate and ETA
        run.bar = tqdm(total=num_updates, initial=start, unit="upd", desc="train",
                       dynamic_ncols=True)
    batches = inputs.prefetch(dataset, range(start, end), batch_sharding(mesh),
                              config.data.prefetch, data_state)
    step = make_update(spec)
    last_log, last_time = start, time.perf_counter()
    with run:
        if start == 0:
            run.run_hook(0, state[0])
        for u, (batch, data_state) in zip(range(start, end), batches, strict=True):
            lr = cosine_lr(u, num_updates, t.lr, t.lr_end)
            args = (*batch, settings, teacher_params, keys, u, lr)
            if u == start and jax.process_count() > 1:  # compile everywhere, then meet
                step = step.lower(*state, *args).compile()
                barrier("compiled")
            *state, metrics = step(*state, *args)
            done = u + 1
            if run.bar is not None:
                run.bar.update()
            if done % t.log_every == 0 or done == end:
                metrics = jax.device_get(metrics)
                now = time.perf_counter()
                rate = (done - last_log) / max(now - last_time, 1e-9)
                run.metrics(done, lr, metrics, {
                    "updates_per_s": rate, "scenario_steps_per_s": rate * steps_per_update,
                    "grad_steps_per_s": rate * grads_per_update})
                last_log, last_time = done, time.perf_counter()
            if run.run_hook(done, state[0], last=done == num_updates):
                last_time = time.perf_counter()  # rates measure training only
            if done % t.checkpoint_every == 0 or done == end:
                run.checkpoint(done, state, data_state)
    complete = run.finish(end, num_updates)
    return TrainResult(state[0], end, num_updates, complete, time.perf_counter() - start_time)
