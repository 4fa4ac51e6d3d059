"""The policy and the reference actors driving batches of scenarios in closed loop: the engine
of the training curves and the evaluation (:mod:`igdrivsim.evaluation.rollout` gives the
semantics), below both so that neither imports the other. ``episode_metrics``: ``None`` or a
function ``(final_state, params) -> {key: f32[]}`` run once per episode inside the jitted
rollout (a static argument).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import NamedSharding, PartitionSpec

from igdrivsim.core.devices import make_mesh, place
from igdrivsim.observation import (
    ObservationConfig,
    get_setting,
    stack_settings,
)
from igdrivsim.policy.act import policy_actor
from igdrivsim.policy.network import PolicyConfig
from igdrivsim.simulator import SimParams, reset
from igdrivsim.simulator.metrics import step_metrics
from igdrivsim.simulator.rollout import ACTORS, run_episode

EpisodeFn = Callable[[Any, SimParams], dict]

EVAL_SEED = 0  # fixed evaluation key: rerunning gives the same CSVs
DEFAULT_SIM_PARAMS = SimParams()
DEFAULT_OBS_CONFIG = ObservationConfig()


@dataclass(frozen=True)
class StepOutputs:
    """Per-step metrics of a batch of episodes, each ``[..., steps]`` (host NumPy), and, when
    requested, the registry's per-episode metrics ``scenario`` (``{key: [...]}``)."""

    log_divergence: np.ndarray
    overlap: np.ndarray
    offroad: np.ndarray
    valid: np.ndarray
    scenario: dict[str, np.ndarray] | None = None

    FIELDS = ("log_divergence", "overlap", "offroad", "valid")

    def map(self, fn: Callable[[np.ndarray], np.ndarray]) -> StepOutputs:
        """Apply ``fn`` to every array (leading axes are shared by steps and scenario)."""
        scenario = None if self.scenario is None else {k: fn(v) for k, v in
                                                       self.scenario.items()}
        return StepOutputs(*(fn(getattr(self, f)) for f in self.FIELDS), scenario)


REFERENCE_ACTORS: tuple[str, ...] = tuple(ACTORS)  # ("expert", "constant_velocity")


def _run(state, actor, key, params: SimParams, episode: EpisodeFn | None):
    """One episode through the simulator's runner: per-step metrics ``[steps]`` each (the
    fields of :class:`StepOutputs`) and the registry's episode metrics (``{}`` unless
    ``episode``)."""

    def metrics(s, p) -> tuple[jax.Array, ...]:
        m = step_metrics(s, p)
        return tuple(jnp.asarray(getattr(m, f), bool if f == "valid" else jnp.float32)
                     for f in StepOutputs.FIELDS)

    final, tr = run_episode(state, actor, key, params, metrics_fn=metrics)
    return tr.metrics, {} if episode is None else episode(final, params)


@partial(jax.jit, static_argnames=("params", "actor_name", "episode"))
def _reference_batch(scenarios, *, params: SimParams, actor_name: str,
                     episode: EpisodeFn | None = None):
    state = jax.vmap(lambda sc: reset(sc, params))(scenarios)
    actor = ACTORS[actor_name](params)  # draws nothing: the key is a placeholder
    return jax.vmap(lambda s: _run(s, actor, jax.random.key(0), params, episode))(state)


@partial(jax.jit, static_argnames=("policy_config", "setting", "obs_config", "params", "actions",
                                   "episode"))
def _policy_batch(policy_params, scenarios, keys, settings, *, policy_config: PolicyConfig,
                  setting, obs_config: ObservationConfig, params: SimParams, actions: str,
                  episode: EpisodeFn | None = None):
    """Outputs ``[G, S, B, steps]`` of ``policy_params [G, S]`` on scenarios ``[B]`` with keys
    ``[S, B]`` (shared by the settings); ``settings`` stacked ``[G]``, or ``None`` with the
    static ``setting``. Each episode: :func:`igdrivsim.policy.act.policy_actor` (the GRU warmed
    on the logged steps 0..9, then driving)."""
    state = jax.vmap(lambda sc: reset(sc, params))(scenarios)

    def per_setting(policy_params, setting_value):
        def one(p, s, k):
            actor = policy_actor(policy_config, p, setting_value, obs_config, actions)
            return _run(s, actor, k, params, episode)

        over_scenarios = jax.vmap(one, in_axes=(None, 0, 0))
        return jax.vmap(over_scenarios, in_axes=(0, None, 0))(policy_params, state, keys)

    if settings is None:
        out = per_setting(jax.tree.map(lambda x: x[0], policy_params), setting)
        return jax.tree.map(lambda x: x[None], out)
    return jax.vmap(per_setting)(policy_params, settings)


def _to_host(outs) -> StepOutputs:
    """Device outputs -> numpy; with several processes, every process gets the whole batch."""
    if jax.process_count() > 1:
        from jax.experimental import multihost_utils  # only with several processes

        outs = multihost_utils.process_allgather(outs, tiled=True)
    per_step, episode = outs
    ld, ov, off, valid = (np.asarray(x) for x in per_step)
    scenario = {k: np.asarray(v) for k, v in episode.items()} if episode else None
    return StepOutputs(ld, ov, off, valid.astype(bool), scenario)


def _spread(tree, axis: int | None):
    """Place arrays split on ``axis`` (scenarios) over every device of every process, or
    replicated when ``axis`` is None; one device: unchanged."""
    if jax.device_count() == 1 or tree is None:
        return tree
    spec = PartitionSpec() if axis is None else PartitionSpec(*([None] * axis), "data")
    return place(tree, NamedSharding(make_mesh(), spec))


def _join(parts: list[StepOutputs], axis: int = 0) -> StepOutputs:
    """``parts`` concatenated on ``axis``, field by field."""
    scenario = None if parts[0].scenario is None else {
        k: np.concatenate([p.scenario[k] for p in parts], axis) for k in parts[0].scenario}
    return StepOutputs(*(np.concatenate([getattr(p, f) for p in parts], axis)
                         for f in StepOutputs.FIELDS), scenario)


def _batched(scenarios, batch_size: int, axis: int, progress, run: Callable) -> StepOutputs:
    """``run(start, stop, batch)`` over fixed-size batches (a multiple of the device count,
    padded with copies of their first scenario; the scenario axis spread over all devices), its
    outputs cut back to the batch's scenarios and joined on the scenario ``axis``."""
    n = jax.tree.leaves(scenarios)[0].shape[0]
    size = -(-min(batch_size, n) // jax.device_count()) * jax.device_count()
    parts = []
    for start in range(0, n, batch_size):
        stop = min(start + batch_size, n)
        index = np.concatenate([np.arange(start, stop), np.full(size - stop + start, start)])
        batch = _spread(jax.tree.map(lambda x, i=index: np.asarray(x)[i], scenarios), 0)
        outs = _to_host(run(start, stop, batch))
        parts.append(outs.map(lambda a, k=stop - start: np.take(a, np.arange(k), axis)))
        if progress:
            progress(stop - start)
    return _join(parts, axis)


def evaluate_reference(scenarios, actor_name: str, params: SimParams = DEFAULT_SIM_PARAMS,
                       batch_size: int = 32, progress: Callable[[int], Any] | None = None,
                       episode_metrics: EpisodeFn | None = None) -> StepOutputs:
    """Roll a reference actor out on stacked scenarios ``[N]``; outputs ``[N, steps]`` (and the
    per-episode metrics ``[N]`` of ``episode_metrics`` when given)."""

    def run(start, stop, batch):
        return _reference_batch(batch, params=params, actor_name=actor_name,
                                episode=episode_metrics)

    return _batched(scenarios, batch_size, 0, progress, run)


def evaluate_policy(policy_params, scenarios, *, policy_config: PolicyConfig,
                    setting: Sequence[str],
                    obs_config: ObservationConfig = DEFAULT_OBS_CONFIG,
                    params: SimParams = DEFAULT_SIM_PARAMS, actions: str = "sample",
                    batch_size: int = 32, seed: int = EVAL_SEED,
                    progress: Callable[[int], Any] | None = None,
                    episode_metrics: EpisodeFn | None = None) -> StepOutputs:
    """Evaluate every seed of stacked ``policy_params [G, S]`` on scenarios ``[N]`` under ``G``
    setting names: metrics ``[G, S, N, steps]``, in one compiled program when the settings
    stack. The key of scenario ``i`` and seed ``s`` depends on ``seed``, ``i`` and ``s`` only,
    so results do not depend on the batch size or the settings run together.
    ``episode_metrics`` adds per-episode metrics (``scenario``, ``[G, S, N]``).
    """
    names = list(setting)
    settings = stack_settings(names)
    if settings is None and len(names) > 1:
        groups = [evaluate_policy(jax.tree.map(lambda x, g=g: x[g:g + 1], policy_params),
                                  scenarios, policy_config=policy_config, setting=[n],
                                  obs_config=obs_config, params=params, actions=actions,
                                  batch_size=batch_size, seed=seed, progress=progress,
                                  episode_metrics=episode_metrics)
                  for g, n in enumerate(names)]
        return _join(groups)
    static = get_setting(names[0]) if settings is None else None
    num_seeds = jax.tree.leaves(policy_params)[0].shape[1]
    seed_keys = jax.vmap(partial(jax.random.fold_in, jax.random.key(seed)))(jnp.arange(num_seeds))
    policy_params, settings = _spread(policy_params, None), _spread(settings, None)

    def run(start, stop, batch):  # keys [S, B]: fold_in(fold_in(key(seed), s), scenario index)
        size = jax.tree.leaves(batch)[0].shape[0]  # padded
        index = jnp.asarray(np.minimum(np.arange(start, start + size), stop - 1))
        keys = jax.vmap(lambda k: jax.vmap(partial(jax.random.fold_in, k))(index))(seed_keys)
        keys = _spread(keys, 1)
        return _policy_batch(policy_params, batch, keys, settings, policy_config=policy_config,
                             setting=static, obs_config=obs_config, params=params,
                             actions=actions, episode=episode_metrics)

    return _batched(scenarios, batch_size, 2, progress, run)
