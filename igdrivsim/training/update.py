"""A run's pure training functions: the static update, the state (parameters, optimiser state
and the method's buffer, ``[G settings, S seeds]``) and the jitted update (:func:`make_update`)
the driver (:mod:`igdrivsim.training.loop`) feeds batches.

One update is one compiled program for every (setting, seed) pair of a method: settings are
data (stacked :class:`~igdrivsim.observation.ObservationSetting`), seeds a batch axis. Per
pair, :func:`collect` builds the episodes the method asks for (:mod:`~igdrivsim.training.
methods`), then ``epochs`` passes over ``minibatches`` random minibatches each take one Adam
step on the method's loss with the network re-run over every episode (so the PPO ratio moves).
The learning rate is an argument: one compiled update serves any run length.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from functools import partial
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from igdrivsim.core.learn import clipped_adam, gae, normalize, sgd_epochs, take_rows
from igdrivsim.observation import (
    Observation,
    ObservationConfig,
    ObservationRecord,
    ObservationSetting,
    episode_observations,
    get_setting,
    stack_settings,
)
from igdrivsim.policy.act import WARMUP_STEPS, example_observation, policy_rollout
from igdrivsim.policy.network import (
    PolicyConfig,
    init_params_per_seed,
    initial_carry,
    unroll_sequence,
)
from igdrivsim.simulator import SimParams, SimState
from igdrivsim.training.config import LossConfig, RunConfig
from igdrivsim.training.methods import SHARED_EPISODES, Method, NoParams, Outputs, get_method
from igdrivsim.training.methods.bc import bc_loss
from igdrivsim.training.records import EPISODE_STEPS, record_episode


# --------------------------------------------------------------- the static update, optimiser
@dataclass(frozen=True)
class UpdateSpec:
    """Everything static about the compiled update (hashable). ``setting`` is ``None`` when
    the settings are data; else the one static setting (e.g. a custom function model)."""

    policy: PolicyConfig
    setting: ObservationSetting | None
    obs: ObservationConfig
    sim: SimParams
    method: str  # a registered method (what the update collects, its loss)
    loss: LossConfig  # the loss's weights and PPO's coefficients
    epochs: int
    minibatches: int
    grad_clip: float
    record: ObservationConfig  # what a teacher-forced record holds (superset of ``obs``)
    teacher_policy: PolicyConfig | None = None  # the privileged teacher's network (static)
    params: Any = NoParams()  # the method's own hyper-parameters (``Method.params``)

    @property
    def learner(self) -> Method:
        return get_method(self.method)


def update_spec(config: RunConfig, teacher_policy: PolicyConfig | None = None) -> UpdateSpec:
    """The static part of a run's update; ``teacher_policy``: the privileged teacher's network
    (required by a method with a teacher)."""
    t = config.training
    method = get_method(t.method)
    if method.teacher and teacher_policy is None:
        raise ValueError(f"update_spec: method {t.method!r} needs its teacher's network")
    epochs, minibatches = config.sgd_passes
    # settings that cannot share a program: the run has one, compiled static
    static = get_setting(config.settings[0]) if stack_settings(config.settings) is None else None
    return UpdateSpec(
        policy=config.policy, setting=static, obs=config.obs_config, sim=config.sim_params,
        method=t.method, loss=config.loss, epochs=epochs, minibatches=minibatches,
        grad_clip=t.grad_clip, record=config.record_config,
        teacher_policy=teacher_policy if method.teacher else None,
        params=method.with_params(dict(t.method_params)))


def cosine_lr(update: int, num_updates: int, lr: float, lr_end: float) -> float:
    """Cosine decay from ``lr`` (update 0) to ``lr_end`` (after the last update)."""
    frac = min(max(update / max(num_updates, 1), 0.0), 1.0)
    return lr_end + 0.5 * (lr - lr_end) * (1.0 + math.cos(math.pi * frac))


# ------------------------------------------------------------------------------- the state
def seed_keys(config: RunConfig) -> jax.Array:
    return jax.vmap(jax.random.PRNGKey)(np.asarray(config.seeds))


def init_state(config: RunConfig, spec: UpdateSpec):
    """Parameters and optimiser state ``[G, S]``; a seed starts from the same parameters in
    every setting (paired comparison)."""
    init_keys = jax.vmap(lambda k: jax.random.fold_in(k, 2**31 - 1))(seed_keys(config))
    params = init_params_per_seed(config.policy, list(init_keys), example_observation(spec.obs))
    groups = len(config.settings)
    params = jax.tree.map(lambda x: jnp.broadcast_to(x[None], (groups, *x.shape)), params)
    opt_state = jax.vmap(jax.vmap(clipped_adam(spec.grad_clip).init))(params)
    return params, opt_state


def init_buffer(config: RunConfig, spec: UpdateSpec):
    """The method's empty buffers ``[G, S]`` (``None`` for methods without one)."""
    if spec.learner.init_buffer is None:
        return None
    one = spec.learner.init_buffer(spec, config.data.batch_size)
    shape = (len(config.settings), config.training.seeds)
    return jax.tree.map(lambda x: jnp.broadcast_to(x, (*shape, *x.shape)), one)


# ------------------------------------------------------------------------------ one update
def _time_major(x):
    return jnp.swapaxes(x, 0, 1)


def expert_sequences(spec: UpdateSpec, rec: ObservationRecord, setting, episode_keys,
                     steps: int = EPISODE_STEPS) -> Observation:
    """Time-major observations ``[steps, b, ...]`` of recorded episodes ``[b]``."""
    part = jax.tree.map(lambda x: x[:, :steps], rec.replace(actions=None, action_valid=None))
    obs = jax.vmap(lambda r, k: episode_observations(r, setting, k, spec.obs))(part,
                                                                                episode_keys)
    return jax.tree.map(_time_major, obs)


def teacher_labels(spec: UpdateSpec, teacher_params, warm: Observation, seen: Observation
                   ) -> jax.Array:
    """The privileged teacher's log-probabilities ``[80, B, 3, bins]``: its GRU warmed on the
    fully observed logged steps ``warm [10, B]``, then over the student's states ``seen``."""
    obs = jax.tree.map(lambda w, s: jnp.concatenate([w, s]), warm, seen)
    b = jax.tree.leaves(seen)[0].shape[1]
    _, logits, _ = unroll_sequence(spec.teacher_policy, teacher_params,
                                   initial_carry(spec.teacher_policy, (b,)), obs)
    return jax.nn.log_softmax(logits[WARMUP_STEPS:], axis=-1)


def collect(spec: UpdateSpec, params, buffer, rec: ObservationRecord, states: SimState | None,
            setting, teacher_params, key):
    """The episodes of one update (scenario-major arrays for minibatching), the method's buffer
    after its collection, and the collection's metrics."""
    method = spec.learner
    b = rec.sdc_yaw.shape[0]
    k_ep, k_act, k_own = jax.random.split(key, 3)
    episode_keys = jax.random.split(k_ep, b)
    logged = expert_sequences(spec, rec, setting, episode_keys)  # [90, b]: built once
    data = {"logged_obs": jax.tree.map(_time_major, logged), "expert_actions": rec.actions,
            "expert_valid": rec.action_valid}
    metrics = {}
    if method.rollout:
        warm = jax.tree.map(lambda x: x[:WARMUP_STEPS], logged)
        carry, _, _ = unroll_sequence(spec.policy, params, initial_carry(spec.policy, (b,)), warm)
        full = get_setting("full") if method.teacher else None
        roll = policy_rollout(spec.policy, params, carry, states, setting, spec.obs, spec.sim,
                              episode_keys, k_act, privileged=full)
        roll = jax.tree.map(jax.lax.stop_gradient, roll)
        # Episodes end at step 90 (terminal): the value after the last step is 0.
        adv, ret = gae(roll.values.T, roll.rewards.T,
                       jnp.zeros((b, roll.valid.shape[0]), bool), jnp.zeros((b,)),
                       spec.loss.gamma, spec.loss.gae_lambda, axis=-1)  # [b, 80]
        adv = normalize(adv.T, roll.valid)
        bm = _time_major  # time-major -> scenario-major
        data |= {"rollout_obs": jax.tree.map(bm, roll.obs), "actions": bm(roll.actions),
                 "log_probs": bm(roll.log_probs), "valid": bm(roll.valid),
                 "advantages": bm(adv), "returns": ret}
        metrics["mean_return"] = roll.rewards.sum(0).mean()
        metrics["overlap_or_offroad_steps"] = (roll.rewards < 0).astype(jnp.float32).mean()
        if method.teacher:
            full_warm = expert_sequences(spec, rec, full, episode_keys, WARMUP_STEPS)
            logp = jax.lax.stop_gradient(
                teacher_labels(spec, teacher_params, full_warm, roll.privileged_obs))
            data["teacher_logp"] = bm(logp)
    if method.collect is not None:
        data, buffer, own = method.collect(spec, buffer, data, k_own)
        metrics |= own
    return data, buffer, metrics


def _loss(spec: UpdateSpec, params, mb: dict):
    """The method's loss on one minibatch (scenario-major): the network runs once over every
    episode kind the method reads."""
    method = spec.learner
    logged = jax.tree.map(_time_major, mb["logged_obs"])  # [90, b, ...]
    sequences = {}
    if "logged" in method.episodes:
        sequences["logged"] = logged
    if "rollout" in method.episodes:  # the same logged warm-up, then the policy's own steps
        sequences["rollout"] = jax.tree.map(lambda w, p: jnp.concatenate(
            [w[:WARMUP_STEPS], _time_major(p)]), logged, mb["rollout_obs"])
    for kind in method.episodes:  # the method's own, [90, b, ...] each
        if kind not in SHARED_EPISODES:
            sequences[kind] = jax.tree.map(_time_major, mb[f"{kind}_obs"])
    obs = jax.tree.map(lambda *xs: jnp.concatenate(xs, 1), *sequences.values())
    width = jax.tree.leaves(obs)[0].shape[1]
    _, logits, values, aux = unroll_sequence(
        spec.policy, params, initial_carry(spec.policy, (width,)), obs, with_aux=True)
    outputs, at = {}, 0
    for kind, seq in sequences.items():
        n = jax.tree.leaves(seq)[0].shape[1]
        outputs[kind] = Outputs(*(None if x is None else x[WARMUP_STEPS:, at:at + n]
                                  for x in (logits, values, aux)))
        at += n
    batch = {k: _time_major(v) for k, v in mb.items() if not k.endswith("_obs")}
    return method.loss(spec, outputs, batch)


def update_one(spec: UpdateSpec, setting, lr, params, opt_state, buffer, rec: ObservationRecord,
               states: SimState | None, teacher_params, key):
    """One update of one (setting, seed) on its batch ``[B]``: ``(params, opt_state, buffer,
    metrics)``."""
    b = rec.sdc_yaw.shape[0]
    k_collect, k_perm = jax.random.split(key)
    data, buffer, metrics = collect(spec, params, buffer, rec, states, setting, teacher_params,
                                    k_collect)
    params, opt_state, aux = sgd_epochs(
        params, opt_state, data, partial(_loss, spec), clipped_adam(spec.grad_clip),
        jax.random.split(k_perm, spec.epochs), spec.minibatches, lr, size=b, select=take_rows,
        grad_norm=True)
    metrics |= jax.tree.map(jnp.mean, aux)
    return params, opt_state, buffer, metrics


@functools.cache
def make_update(spec: UpdateSpec):
    """The jitted update over all settings and seeds (cached per ``spec``): ``(params[G, S],
    opt_state, buffer, teacher records[S, B] | None, states[S, B] | None, settings[G] | None,
    teacher_params[S] | None, seed_keys[S], update_index, lr) -> (params, opt_state, buffer,
    metrics[G, S])``. Every setting sees the same scenarios and draws of a seed (paired)."""

    def update(params, opt_state, buffer, teacher, states, settings, teacher_params,
               seed_keys, update_index, lr):
        keys = jax.vmap(lambda k: jax.random.fold_in(k, update_index))(seed_keys)
        if teacher is None:  # records not kept in memory: record this batch now
            teacher = jax.vmap(jax.vmap(lambda s: record_episode(s, spec.sim, spec.record)))(
                states)

        def one_setting(setting, params, opt_state, buffer):
            return jax.vmap(partial(update_one, spec, setting, lr))(
                params, opt_state, buffer, teacher, states, teacher_params, keys)

        if spec.setting is not None:
            first = jax.tree.map(lambda x: x[0], (params, opt_state, buffer))
            out = one_setting(spec.setting, *first)
            return jax.tree.map(lambda x: x[None], out)
        return jax.vmap(one_setting)(settings, params, opt_state, buffer)

    return jax.jit(update, donate_argnums=(0, 1, 2))


def make_validation_loss(spec: UpdateSpec):
    """Teacher-forced BC loss ``[G, S]`` of ``params [G, S]`` on recorded validation episodes
    ``[V]`` (fixed keys), one compiled program per setting (the whole grid at once ran out of
    GPU memory)."""

    @jax.jit
    def per_setting(setting, params, teacher, key):
        setting = spec.setting if setting is None else setting  # a static one, or data
        v = teacher.sdc_yaw.shape[0]
        obs = expert_sequences(spec, teacher, setting, jax.random.split(key, v))  # seed-free

        def one(p):
            _, logits, _ = unroll_sequence(spec.policy, p, initial_carry(spec.policy, (v,)), obs)
            return bc_loss(logits[WARMUP_STEPS:], _time_major(teacher.actions),
                           _time_major(teacher.action_valid))

        return jax.vmap(one)(params)

    def loss(params, teacher, settings, key):  # settings None: the one static setting
        groups = jax.tree.leaves(params)[0].shape[0]
        return jnp.stack([per_setting(jax.tree.map(lambda x, g=g: x[g], settings),
                                      jax.tree.map(lambda x, g=g: x[g], params), teacher, key)
                          for g in range(groups)])

    return loss
