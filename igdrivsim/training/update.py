"""The jitted training update (PureJaxRL style): BC and BC + PPO for every setting and seed.

One update consumes, per seed, a batch of ``B`` scenarios: their teacher-forced records
(:mod:`igdrivsim.training.teacher`; computed once per dataset) and, for BC-RL, their simulator
states at reset. Settings are data (:class:`~igdrivsim.observation.ObservationParams`, axis
``G``) and seeds a batch axis (``S``): one compiled program trains every (setting, seed) pair.

1. BC data: the recorded warm-up (t = 0..9) and expert-driven (t = 10..89) episode under the
   setting's observation model, built on the fly from the record, with the discretised expert
   actions as labels;
2. only for BC-RL (static flag): the policy drives from the same warm-up state (GRU warmed on
   the same observations), sampling its actions and observing the simulator's exact state;
   rewards -1[overlap] - 1[offroad]; GAE (the episode ends at step 90, so V = 0 there);
3. ``epochs`` passes over ``minibatches`` random minibatches of scenarios, each one Adam step
   on ``w_bc * BC + w_rl * PPO`` (PPO = clipped surrogate + vf_coef * value loss - ent_coef *
   entropy). The recurrent network is re-run over the whole 90-step episode with the current
   parameters (encoders batched over time, see :func:`~igdrivsim.policy.network.
   unroll_sequence`), so after the first step the PPO ratio differs from 1.

BC is the same code with ``w_rl = 0``: no simulator state, no rollout, no PPO term. The
learning rate is an argument (the driver computes the cosine schedule), so one compiled update
serves any run length.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import partial

import jax
import jax.numpy as jnp
import optax

from igdrivsim.observation import (
    Observation,
    ObservationConfig,
    ObservationParams,
    ObservationSetting,
    get_setting,
    setting_params,
    stack_params,
)
from igdrivsim.policy.network import PolicyConfig, initial_carry, unroll_sequence
from igdrivsim.simulator import SimParams, SimState
from igdrivsim.training import env
from igdrivsim.training.config import RunConfig
from igdrivsim.training.env import WARMUP_STEPS
from igdrivsim.training.losses import (
    action_log_prob,
    bc_loss,
    clipped_surrogate,
    entropy,
    gae,
    masked_mean,
    normalize,
    value_loss,
)
from igdrivsim.training.teacher import (
    EPISODE_STEPS,
    TeacherSteps,
    episode_observations,
    record_episode,
    superset_config,
)


@dataclass(frozen=True)
class UpdateSpec:
    """Everything static about the compiled update (hashable). ``setting`` is ``None`` when
    the settings are data; else the one static setting (e.g. a custom function model)."""

    policy: PolicyConfig
    setting: ObservationSetting | None
    obs: ObservationConfig
    sim: SimParams
    use_rl: bool
    w_bc: float
    w_rl: float
    gamma: float
    gae_lambda: float
    clip_eps: float
    ent_coef: float
    vf_coef: float
    epochs: int
    minibatches: int
    grad_clip: float
    record: ObservationConfig  # what a teacher-forced record holds (superset of ``obs``)


def sim_params(config: RunConfig) -> SimParams:
    """Simulator settings of a run (the observable map's resolution; the offroad metric's
    road-edge selection keeps its defaults)."""
    return SimParams(roadgraph_stride=config.observation.roadgraph_stride)


def run_settings(config: RunConfig) -> list[str]:
    """The observation settings a run trains (``observation.setting`` is a comma list)."""
    return [s.strip() for s in config.observation.setting.split(",") if s.strip()]


def settings_as_data(config: RunConfig) -> ObservationParams | None:
    """Stacked :class:`ObservationParams` ``[G]`` of the run's settings, or ``None`` when one
    of them has no such form (then the run must have exactly one setting, compiled static)."""
    params = [setting_params(s) for s in run_settings(config)]
    if any(p is None for p in params):
        return None
    return stack_params(params)


def update_spec(config: RunConfig) -> UpdateSpec:
    t, o = config.training, config.observation
    names = run_settings(config)
    static = None if settings_as_data(config) is not None else get_setting(names[0])
    return UpdateSpec(
        policy=config.policy, setting=static,
        obs=ObservationConfig(o.num_objects, o.num_roadgraph_points), sim=sim_params(config),
        use_rl=config.use_rl, w_bc=t.w_bc, w_rl=t.w_rl if config.use_rl else 0.0,
        gamma=t.gamma, gae_lambda=t.gae_lambda, clip_eps=t.clip_eps, ent_coef=t.ent_coef,
        vf_coef=t.vf_coef, epochs=t.ppo_epochs, minibatches=t.ppo_minibatches,
        grad_clip=t.grad_clip,
        record=superset_config(ObservationConfig(o.num_objects, o.num_roadgraph_points),
                               config.data.max_objects))


def optimizer(spec: UpdateSpec) -> optax.GradientTransformation:
    """Global-norm clipping + Adam moments; the (scheduled) learning rate is applied in the
    update, so the compiled program does not depend on the run length."""
    return optax.chain(optax.clip_by_global_norm(spec.grad_clip), optax.scale_by_adam())


def cosine_lr(update: int, num_updates: int, lr: float, lr_end: float) -> float:
    """Cosine decay from ``lr`` (update 0) to ``lr_end`` (after the last update)."""
    import math

    frac = min(max(update / max(num_updates, 1), 0.0), 1.0)
    return lr_end + 0.5 * (lr - lr_end) * (1.0 + math.cos(math.pi * frac))


def expert_sequences(spec: UpdateSpec, rec: TeacherSteps, setting, episode_keys,
                     steps: int = EPISODE_STEPS) -> Observation:
    """Time-major observations ``[steps, b, ...]`` of recorded episodes ``[b]``."""
    part = jax.tree.map(lambda x: x[:, :steps], rec.replace(actions=None, action_valid=None))
    obs = jax.vmap(lambda r, k: episode_observations(r, setting, k, spec.obs))(part,
                                                                                episode_keys)
    return jax.tree.map(lambda x: jnp.swapaxes(x, 0, 1), obs)


def _loss(spec: UpdateSpec, setting, params, mb: dict):
    """``w_bc * BC + w_rl * PPO`` on one minibatch (scenario axis first)."""
    rec = mb["teacher"]
    obs = jax.tree.map(lambda x: jnp.swapaxes(x, 0, 1), mb["expert_obs"])  # time-major
    b = rec.sdc_yaw.shape[0]
    if spec.use_rl:  # one pass of the network over both episodes (expert- and policy-driven)
        policy_obs = jax.tree.map(lambda w, p: jnp.concatenate([w[:WARMUP_STEPS],
                                                                jnp.swapaxes(p, 0, 1)]),
                                  obs, mb["policy_obs"])
        obs = jax.tree.map(lambda x, y: jnp.concatenate([x, y], 1), obs, policy_obs)
    carry = initial_carry(spec.policy, (jax.tree.leaves(obs)[0].shape[1],))
    _, logits_all, values_all = unroll_sequence(spec.policy, params, carry, obs, True)
    logits_all, values_all = logits_all[WARMUP_STEPS:], values_all[WARMUP_STEPS:]
    logits = logits_all[:, :b]
    actions = jnp.swapaxes(rec.actions, 0, 1).astype(jnp.int32)
    valid = jnp.swapaxes(rec.action_valid, 0, 1)
    bc = bc_loss(logits, actions, valid)
    aux = {"bc_loss": bc, "entropy": masked_mean(entropy(logits), valid)}
    total = spec.w_bc * bc
    if spec.use_rl:
        tm = lambda k: jnp.swapaxes(mb[k], 0, 1)  # noqa: E731
        mask = tm("valid")
        logits_pi, values = logits_all[:, b:], values_all[:, b:]
        logp = action_log_prob(logits_pi, tm("actions"))
        pg = clipped_surrogate(logp, tm("log_probs"), tm("advantages"), spec.clip_eps, mask)
        vl = value_loss(values, tm("returns"), mask)
        ent_pi = masked_mean(entropy(logits_pi), mask)
        ppo = pg + spec.vf_coef * vl - spec.ent_coef * ent_pi
        total = total + spec.w_rl * ppo
        ratio = jnp.exp(logp - tm("log_probs"))
        aux |= {"ppo_loss": ppo, "policy_loss": pg, "value_loss": vl, "policy_entropy": ent_pi,
                "clip_frac": masked_mean((jnp.abs(ratio - 1) > spec.clip_eps).astype(
                    jnp.float32), mask),
                "ratio_dev": masked_mean(jnp.abs(ratio - 1.0), mask)}
    return total, aux


def _take(tree, idx):
    return jax.tree.map(lambda x: jnp.take(x, idx, axis=0), tree)


def update_one(spec: UpdateSpec, params, opt_state, rec: TeacherSteps, states: SimState | None,
               setting, key, lr):
    """One update of one (setting, seed) on its batch ``[B]``: ``(params, opt_state,
    metrics)``."""
    b = rec.sdc_yaw.shape[0]
    k_ep, k_act, k_perm = jax.random.split(key, 3)
    episode_keys = jax.random.split(k_ep, b)
    # the setting's observations of the recorded episodes, built once for every epoch
    expert_obs = expert_sequences(spec, rec, setting, episode_keys)
    data = {"teacher": rec.replace(roadgraph=None, roadgraph_type=None, roadgraph_valid=None,
                                   objects=None, objects_valid=None),
            "expert_obs": jax.tree.map(lambda x: jnp.swapaxes(x, 0, 1), expert_obs)}
    metrics = {}
    if spec.use_rl:
        warm = jax.tree.map(lambda x: x[:WARMUP_STEPS], expert_obs)
        carry, _, _ = unroll_sequence(spec.policy, params, initial_carry(spec.policy, (b,)),
                                      warm, True)
        roll = env.policy_rollout(spec.policy, params, carry, states, setting, spec.obs,
                                  spec.sim, episode_keys, k_act)
        roll = jax.tree.map(jax.lax.stop_gradient, roll)
        # Episodes end at step 90 (terminal): the value after the last step is 0.
        adv, ret = gae(roll.rewards.T, roll.values.T, jnp.zeros((b,)), spec.gamma,
                       spec.gae_lambda)
        adv = normalize(adv.T, roll.valid)
        bm = lambda x: jnp.swapaxes(x, 0, 1)  # noqa: E731  time-major -> scenario-major
        data |= {"policy_obs": jax.tree.map(bm, roll.obs), "actions": bm(roll.actions),
                 "log_probs": bm(roll.log_probs), "valid": bm(roll.valid),
                 "advantages": bm(adv), "returns": ret}
        metrics["mean_return"] = roll.rewards.sum(0).mean()
        metrics["overlap_or_offroad_steps"] = (roll.rewards < 0).astype(jnp.float32).mean()
    tx = optimizer(spec)
    grad_fn = jax.value_and_grad(partial(_loss, spec, setting), has_aux=True)
    per_mb = b // spec.minibatches

    def minibatch_step(carry, idx):
        params, opt_state = carry
        (_, aux), grads = grad_fn(params, _take(data, idx))
        updates, opt_state = tx.update(grads, opt_state, params)
        params = optax.apply_updates(params, jax.tree.map(lambda u: -lr * u, updates))
        aux["grad_norm"] = optax.tree.norm(grads)
        return (params, opt_state), aux

    def epoch(carry, k):
        perm = jax.random.permutation(k, b).reshape(spec.minibatches, per_mb)
        return jax.lax.scan(minibatch_step, carry, perm)

    (params, opt_state), aux = jax.lax.scan(
        epoch, (params, opt_state), jax.random.split(k_perm, spec.epochs))
    metrics |= jax.tree.map(jnp.mean, aux)
    return params, opt_state, metrics


def make_update(spec: UpdateSpec, donate: bool = True):
    """The jitted update over all settings and seeds: ``(params[G, S], opt_state[G, S],
    teacher[S, B] | None, states[S, B] | None, settings[G] | None, seed_keys[S], update_index,
    lr) -> (params, opt_state, metrics[G, S])``; without ``teacher`` the batch is recorded
    from ``states`` inside the update. Every setting sees the same scenarios and draws
    of a seed (the comparison between settings is paired)."""

    def update(params, opt_state, teacher, states, settings, seed_keys, update_index, lr):
        keys = jax.vmap(lambda k: jax.random.fold_in(k, update_index))(seed_keys)
        if teacher is None:  # records not kept in memory: record this batch now
            teacher = jax.vmap(jax.vmap(lambda s: record_episode(s, spec.sim, spec.record)))(
                states)

        def one_setting(setting, params, opt_state):
            per_seed = partial(update_one, spec)
            return jax.vmap(lambda p, o, r, s, k: per_seed(p, o, r, s, setting, k, lr))(
                params, opt_state, teacher, states, keys)

        if spec.setting is not None:
            out = one_setting(spec.setting, *jax.tree.map(lambda x: x[0], (params, opt_state)))
            return jax.tree.map(lambda x: x[None], out)
        return jax.vmap(one_setting)(settings, params, opt_state)

    return jax.jit(update, donate_argnums=(0, 1) if donate else ())


def make_validation_loss(spec: UpdateSpec):
    """Jitted teacher-forced BC loss ``[G, S]`` of ``params [G, S]`` on recorded validation
    episodes ``[V]`` (fixed keys: comparable across updates)."""

    def loss(params, teacher, settings, key):
        v = teacher.sdc_yaw.shape[0]
        keys = jax.random.split(key, v)
        bc_spec = replace(spec, use_rl=False, w_rl=0.0)

        def one(setting, p):
            obs = expert_sequences(spec, teacher, setting, keys)
            data = {"teacher": teacher,
                    "expert_obs": jax.tree.map(lambda x: jnp.swapaxes(x, 0, 1), obs)}
            return _loss(bc_spec, setting, p, data)[1]["bc_loss"]

        if spec.setting is not None:
            return jax.vmap(lambda p: one(spec.setting, p))(
                jax.tree.map(lambda x: x[0], params))[None]
        return jax.vmap(lambda s, p: jax.vmap(lambda q: one(s, q))(p))(settings, params)

    return jax.jit(loss)
