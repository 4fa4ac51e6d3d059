"""The jitted training update (PureJaxRL style), generic over the learning methods.

One update consumes, per seed, a batch of ``B`` scenarios: their teacher-forced records
(:mod:`igdrivsim.training.records`; computed once per dataset) and, for methods that drive,
their simulator states at reset. Settings are data (stacked
:class:`~igdrivsim.observation.ObservationSetting`, axis ``G``) and seeds a batch axis (``S``):
one compiled program trains every (setting, seed) pair of a method.

1. the episodes the method asks for (:mod:`igdrivsim.training.methods`): the logged episode
   under the setting's observation model, built on the fly from the record (labels: the
   discretised expert actions); the policy's own closed-loop episode from the same warm-up
   state (sampled actions, rewards ``-1[overlap] - 1[offroad]``, GAE; the episode ends at step
   90, so V = 0 there); a privileged teacher's labels of the states it visits (the teacher
   sees them fully observed); the buffer of the last labelled episodes (DAgger);
2. ``epochs`` passes over ``minibatches`` random minibatches of scenarios, each one Adam step
   on the method's loss (the maze's loop too: :func:`igdrivsim.core.learn.sgd_epochs`). The
   recurrent network is re-run over every episode of the minibatch with the current
   parameters in one pass (encoders batched over time, see
   :func:`~igdrivsim.policy.network.unroll_sequence`), so after the first step the PPO ratio
   differs from 1.

The learning rate is an argument (the driver computes the cosine schedule), so one compiled
update serves any run length.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import partial
from typing import Any

import jax
import jax.numpy as jnp
import optax
from flax import struct

from igdrivsim.core.learn import clipped_adam, gae, normalize, sgd_epochs
from igdrivsim.observation import (
    Observation,
    ObservationConfig,
    ObservationRecord,
    ObservationSetting,
    episode_observations,
    get_setting,
    stack_settings,
)
from igdrivsim.policy.act import WARMUP_STEPS, bc_loss, example_observation, policy_rollout
from igdrivsim.policy.network import PolicyConfig, initial_carry, unroll_sequence
from igdrivsim.simulator import SimParams, SimState
from igdrivsim.training.config import LossConfig, RunConfig
from igdrivsim.training.methods import Method, NoParams, Outputs, get_method
from igdrivsim.training.privileged import teacher_config
from igdrivsim.training.records import EPISODE_STEPS, record_episode


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


def settings_as_data(config: RunConfig) -> ObservationSetting | None:
    """The run's settings stacked ``[G]`` (:func:`~igdrivsim.observation.stack_settings`), or
    ``None`` when they cannot share a program (then the run has exactly one setting, compiled
    static)."""
    return stack_settings(config.settings)


def update_spec(config: RunConfig, teacher_policy: PolicyConfig | None = None) -> UpdateSpec:
    """The static part of a run's update; ``teacher_policy`` overrides the teacher run's
    network config (benchmarks use an untrained teacher)."""
    t = config.training
    epochs, minibatches = config.sgd_passes
    static = None if settings_as_data(config) is not None else get_setting(config.settings[0])
    return UpdateSpec(
        policy=config.policy, setting=static, obs=config.obs_config, sim=config.sim_params,
        method=t.method, loss=config.loss, epochs=epochs, minibatches=minibatches,
        grad_clip=t.grad_clip,
        record=config.record_config,
        teacher_policy=teacher_policy or teacher_policy_config(config),
        params=get_method(t.method).with_params(dict(t.method_params)))


def teacher_policy_config(config: RunConfig) -> PolicyConfig | None:
    """The privileged teacher's network config (``None`` when the method has no teacher)."""
    if not get_method(config.training.method).teacher:
        return None
    return teacher_config(config.training.teacher, config).policy


def optimizer(spec: UpdateSpec) -> optax.GradientTransformation:
    """Global-norm clipping + Adam moments; the (scheduled) learning rate is applied in the
    update, so the compiled program does not depend on the run length."""
    return clipped_adam(spec.grad_clip)


def cosine_lr(update: int, num_updates: int, lr: float, lr_end: float) -> float:
    """Cosine decay from ``lr`` (update 0) to ``lr_end`` (after the last update)."""
    frac = min(max(update / max(num_updates, 1), 0.0), 1.0)
    return lr_end + 0.5 * (lr - lr_end) * (1.0 + math.cos(math.pi * frac))


def expert_sequences(spec: UpdateSpec, rec: ObservationRecord, setting, episode_keys,
                     steps: int = EPISODE_STEPS) -> Observation:
    """Time-major observations ``[steps, b, ...]`` of recorded episodes ``[b]``."""
    part = jax.tree.map(lambda x: x[:, :steps], rec.replace(actions=None, action_valid=None))
    obs = jax.vmap(lambda r, k: episode_observations(r, setting, k, spec.obs))(part,
                                                                                episode_keys)
    return jax.tree.map(lambda x: jnp.swapaxes(x, 0, 1), obs)


@struct.dataclass
class Aggregate:
    """DAgger's data set of one (setting, seed): the student's episodes of the last ``slots``
    updates with the teacher's labels, written one batch of ``B`` at a time in a ring."""

    obs: Observation  # [slots * B, 90, ...] the student's observations (warm-up + its steps)
    logp: jax.Array  # f32[slots * B, 80, 3, bins] the teacher's log-probabilities
    valid: jax.Array  # bool[slots * B, 80]
    pushes: jax.Array  # int32, batches written so far
    slots: int = struct.field(pytree_node=False, default=1)

    @property
    def episodes(self) -> jax.Array:
        """Episodes held: grows by ``B`` per update up to ``slots * B``."""
        b = self.valid.shape[0] // self.slots
        return jnp.minimum(self.pushes, self.slots) * b

    def push(self, obs: Observation, logp: jax.Array, valid: jax.Array) -> Aggregate:
        """Write one batch ``[B, ...]`` over the oldest."""
        at = (self.pushes % self.slots) * valid.shape[0]

        def put(buf, x):
            return jax.lax.dynamic_update_slice_in_dim(buf, x.astype(buf.dtype), at, axis=0)

        return self.replace(obs=jax.tree.map(put, self.obs, obs), logp=put(self.logp, logp),
                            valid=put(self.valid, valid), pushes=self.pushes + 1)

    def sample(self, key: jax.Array, n: int):
        """``(obs, logp, valid)`` of ``n`` episodes drawn uniformly from those held."""
        idx = jax.random.randint(key, (n,), 0, jnp.maximum(self.episodes, 1))
        return _take((self.obs, self.logp, self.valid), idx)


def empty_aggregate(spec: UpdateSpec, batch: int) -> Aggregate | None:
    """The empty buffer of one (setting, seed) (``None`` unless the method aggregates)."""
    if "aggregate" not in spec.learner.episodes:
        return None
    n = spec.params.aggregate_batches * batch
    obs = jax.tree.map(lambda x: jnp.zeros((n, EPISODE_STEPS, *x.shape), x.dtype),
                       example_observation(spec.obs))
    steps = EPISODE_STEPS - WARMUP_STEPS
    return Aggregate(obs, jnp.zeros((n, steps, 3, spec.policy.num_bins)),
                     jnp.zeros((n, steps), bool), jnp.zeros((), jnp.int32),
                     spec.params.aggregate_batches)


def _time_major(x):
    return jnp.swapaxes(x, 0, 1)


def _loss(spec: UpdateSpec, params, mb: dict):
    """The method's loss on one minibatch (scenario axis first): the network runs once over
    every episode kind the method reads, and the loss gets each kind's outputs."""
    method = spec.learner
    logged = jax.tree.map(_time_major, mb["logged_obs"])  # [90, b, ...]
    sequences = {}
    if "logged" in method.episodes:
        sequences["logged"] = logged
    if "rollout" in method.episodes:  # the same logged warm-up, then the policy's own steps
        sequences["rollout"] = jax.tree.map(lambda w, p: jnp.concatenate(
            [w[:WARMUP_STEPS], _time_major(p)]), logged, mb["rollout_obs"])
    if "aggregate" in method.episodes:
        sequences["aggregate"] = jax.tree.map(_time_major, mb["aggregate_obs"])
    kinds = list(sequences)
    obs = jax.tree.map(lambda *xs: jnp.concatenate(xs, 1), *sequences.values())
    width = jax.tree.leaves(obs)[0].shape[1]
    _, logits, values, aux = unroll_sequence(spec.policy, params,
                                             initial_carry(spec.policy, (width,)), obs, True,
                                             with_aux=True)
    outputs, at = {}, 0
    for kind in kinds:
        n = jax.tree.leaves(sequences[kind])[0].shape[1]
        lo, hi = at, at + n
        outputs[kind] = Outputs(*(None if x is None else x[WARMUP_STEPS:, lo:hi]
                                  for x in (logits, values, aux)))
        at += n
    batch = {k: _time_major(v) for k, v in mb.items() if not k.endswith("_obs")}
    return method.loss(spec, outputs, batch)


def _take(tree, idx):
    return jax.tree.map(lambda x: jnp.take(x, idx, axis=0), tree)


def teacher_labels(spec: UpdateSpec, teacher_params, warm: Observation, seen: Observation
                   ) -> jax.Array:
    """The privileged teacher's log-probabilities ``[80, B, 3, bins]`` along an episode: its
    GRU warmed on the fully observed logged steps ``warm [10, B]``, then stepped over the
    fully observed states ``seen [80, B]`` the student drove through."""
    obs = jax.tree.map(lambda w, s: jnp.concatenate([w, s]), warm, seen)
    b = jax.tree.leaves(seen)[0].shape[1]
    _, logits, _ = unroll_sequence(spec.teacher_policy, teacher_params,
                                   initial_carry(spec.teacher_policy, (b,)), obs, True)
    return jax.nn.log_softmax(logits[WARMUP_STEPS:], axis=-1)


def collect(spec: UpdateSpec, params, buffer: Aggregate | None, rec: ObservationRecord,
            states: SimState | None, setting, teacher_params, key):
    """The episodes of one update (scenario-major arrays for minibatching), the buffer after
    this update's push, and the collection's metrics."""
    method = spec.learner
    b = rec.sdc_yaw.shape[0]
    k_ep, k_act, k_agg = jax.random.split(key, 3)
    episode_keys = jax.random.split(k_ep, b)
    logged = expert_sequences(spec, rec, setting, episode_keys)  # [90, b]: built once
    data = {"logged_obs": jax.tree.map(_time_major, logged), "expert_actions": rec.actions,
            "expert_valid": rec.action_valid}
    metrics = {}
    if not method.rollout:
        return data, buffer, metrics
    warm = jax.tree.map(lambda x: x[:WARMUP_STEPS], logged)
    carry, _, _ = unroll_sequence(spec.policy, params, initial_carry(spec.policy, (b,)),
                                  warm, True)
    full = get_setting("full") if method.teacher else None
    roll = policy_rollout(spec.policy, params, carry, states, setting, spec.obs, spec.sim,
                              episode_keys, k_act, privileged=full)
    roll = jax.tree.map(jax.lax.stop_gradient, roll)
    # Episodes end at step 90 (terminal): the value after the last step is 0.
    adv, ret = gae(roll.values.T, roll.rewards.T, jnp.zeros((b, roll.valid.shape[0]), bool),
                   jnp.zeros((b,)), spec.loss.gamma, spec.loss.gae_lambda, axis=-1)  # [b, 80]
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
        if "aggregate" in method.episodes:
            student = jax.tree.map(lambda w, p: bm(jnp.concatenate([w, p])), warm, roll.obs)
            buffer = buffer.push(student, bm(logp), bm(roll.valid))
            obs, agg_logp, agg_valid = buffer.sample(k_agg, b)
            data |= {"aggregate_obs": obs, "aggregate_logp": agg_logp,
                     "aggregate_valid": agg_valid}
            metrics["aggregate_episodes"] = buffer.episodes.astype(jnp.float32)
    return data, buffer, metrics


def update_one(spec: UpdateSpec, params, opt_state, buffer: Aggregate | None,
               rec: ObservationRecord, states: SimState | None, setting, teacher_params, key, lr):
    """One update of one (setting, seed) on its batch ``[B]``: ``(params, opt_state, buffer,
    metrics)``."""
    b = rec.sdc_yaw.shape[0]
    k_collect, k_perm = jax.random.split(key)
    data, buffer, metrics = collect(spec, params, buffer, rec, states, setting, teacher_params,
                                    k_collect)
    params, opt_state, aux = sgd_epochs(
        params, opt_state, data, partial(_loss, spec), optimizer(spec),
        jax.random.split(k_perm, spec.epochs), spec.minibatches, lr, size=b, select=_take,
        grad_norm=True)
    metrics |= jax.tree.map(jnp.mean, aux)
    return params, opt_state, buffer, metrics


def make_update(spec: UpdateSpec, donate: bool = True):
    """The jitted update over all settings and seeds: ``(params[G, S], opt_state[G, S],
    buffer[G, S] | None, teacher[S, B] | None, states[S, B] | None, settings[G] | None,
    teacher_params[S] | None, seed_keys[S], update_index, lr) -> (params, opt_state, buffer,
    metrics[G, S])``; without ``teacher`` records the batch is recorded from ``states`` inside
    the update. Every setting sees the same scenarios and draws of a seed (the comparison
    between settings is paired); seed ``s`` is labelled by the teacher's seed ``s``."""

    def update(params, opt_state, buffer, teacher, states, settings, teacher_params,
               seed_keys, update_index, lr):
        keys = jax.vmap(lambda k: jax.random.fold_in(k, update_index))(seed_keys)
        if teacher is None:  # records not kept in memory: record this batch now
            teacher = jax.vmap(jax.vmap(lambda s: record_episode(s, spec.sim, spec.record)))(
                states)

        def one_setting(setting, params, opt_state, buffer):
            def per_seed(p, o, buf, r, s, tp, k):
                return update_one(spec, p, o, buf, r, s, setting, tp, k, lr)

            return jax.vmap(per_seed)(params, opt_state, buffer, teacher, states,
                                      teacher_params, keys)

        if spec.setting is not None:
            first = jax.tree.map(lambda x: x[0], (params, opt_state, buffer))
            out = one_setting(spec.setting, *first)
            return jax.tree.map(lambda x: x[None], out)
        return jax.vmap(one_setting)(settings, params, opt_state, buffer)

    return jax.jit(update, donate_argnums=(0, 1, 2) if donate else ())


def make_validation_loss(spec: UpdateSpec):
    """Jitted teacher-forced BC loss ``[G, S]`` of ``params [G, S]`` on recorded validation
    episodes ``[V]`` (fixed keys: comparable across updates)."""

    def loss(params, teacher, settings, key):
        v = teacher.sdc_yaw.shape[0]
        keys = jax.random.split(key, v)

        def one(setting, p):
            obs = expert_sequences(spec, teacher, setting, keys)
            _, logits, _ = unroll_sequence(spec.policy, p, initial_carry(spec.policy, (v,)),
                                           obs, True)
            return bc_loss(logits[WARMUP_STEPS:], _time_major(teacher.actions),
                           _time_major(teacher.action_valid))

        if spec.setting is not None:
            return jax.vmap(lambda p: one(spec.setting, p))(
                jax.tree.map(lambda x: x[0], params))[None]
        return jax.vmap(lambda s, p: jax.vmap(lambda q: one(s, q))(p))(settings, params)

    return jax.jit(loss)
