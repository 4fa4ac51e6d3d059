"""The jitted training update (PureJaxRL style): BC, and BC + PPO, for all seeds at once.

One update consumes one batch of ``B`` scenarios per seed (``SimState [S, B]`` at reset):

1. warm-up: the logged steps 0..9 are observed and warm the GRU (state zeroed at t = 0);
2. BC data: the discretised expert drives the 80 controlled steps (observations + labels);
3. only for BC-RL (static flag): the policy drives from the same warm-up state, sampling its
   actions; rewards -1[overlap] - 1[offroad]; GAE (episode ends at step 90, so V = 0 there);
4. ``epochs`` passes over ``minibatches`` random minibatches of scenarios, each one Adam step
   on ``w_bc * BC + w_rl * PPO`` (PPO = clipped surrogate + vf_coef * value loss - ent_coef *
   entropy). The recurrent policy is re-run over the whole episode (warm-up included) with the
   current parameters, so after the first step the PPO ratio differs from 1.

BC is the same code with ``w_rl = 0``: no policy rollout, no PPO term. Seeds are a ``vmap``
dimension over parameters, optimiser state, keys and batches. The learning rate is an argument
(the cosine schedule is computed by the driver), so one compiled update serves any run length.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import jax
import jax.numpy as jnp
import optax

from igdrivsim.observation import ObservationConfig, ObservationSetting, get_setting
from igdrivsim.policy.network import PolicyConfig
from igdrivsim.simulator import SimParams, SimState
from igdrivsim.training import env
from igdrivsim.training.config import RunConfig
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


@dataclass(frozen=True)
class UpdateSpec:
    """Everything static about the compiled update (hashable)."""

    policy: PolicyConfig
    setting: ObservationSetting
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


def sim_params(config: RunConfig) -> SimParams:
    """Simulator settings of a run: the roadgraph crop at reset follows the data config."""
    d = config.data
    cap = min(d.roadgraph_capacity, d.max_roadgraph_points)
    return SimParams(crop_radius=d.crop_radius, roadgraph_capacity=cap,
                     edge_capacity=min(1024, cap))


def update_spec(config: RunConfig) -> UpdateSpec:
    t, o = config.training, config.observation
    return UpdateSpec(
        policy=config.policy, setting=get_setting(o.setting),
        obs=ObservationConfig(o.num_objects, o.num_roadgraph_points), sim=sim_params(config),
        use_rl=config.use_rl, w_bc=t.w_bc, w_rl=t.w_rl if config.use_rl else 0.0,
        gamma=t.gamma, gae_lambda=t.gae_lambda, clip_eps=t.clip_eps, ent_coef=t.ent_coef,
        vf_coef=t.vf_coef, epochs=t.ppo_epochs, minibatches=t.ppo_minibatches,
        grad_clip=t.grad_clip)


def optimizer(spec: UpdateSpec) -> optax.GradientTransformation:
    """Global-norm clipping + Adam moments; the (scheduled) learning rate is applied in the
    update, so the compiled program does not depend on the run length."""
    return optax.chain(optax.clip_by_global_norm(spec.grad_clip), optax.scale_by_adam())


def cosine_lr(update: int, num_updates: int, lr: float, lr_end: float) -> float:
    """Cosine decay from ``lr`` (update 0) to ``lr_end`` (after the last update)."""
    import math

    frac = min(max(update / max(num_updates, 1), 0.0), 1.0)
    return lr_end + 0.5 * (lr - lr_end) * (1.0 + math.cos(math.pi * frac))


def _take(tree, idx, axis: int):
    return jax.tree.map(lambda x: jnp.take(x, idx, axis=axis), tree)


def _loss(spec: UpdateSpec, params, mb: dict):
    """``w_bc * BC + w_rl * PPO`` on one minibatch (time-major arrays ``[T, b, ...]``)."""
    carry = env.warm_carry(spec.policy, params, mb["warm_obs"])
    obs, b = mb["expert_obs"], carry.shape[0]
    if spec.use_rl:  # one pass of the network over both episodes (expert- and policy-driven)
        obs = jax.tree.map(lambda x, y: jnp.concatenate([x, y], 1), obs, mb["policy_obs"])
        carry = jnp.concatenate([carry, carry], 0)
    _, logits_all, values_all = env.scan_policy(spec.policy, params, carry, obs, False)
    logits = logits_all[:, :b] if spec.use_rl else logits_all
    bc = bc_loss(logits, mb["expert_actions"], mb["expert_valid"])
    ent = masked_mean(entropy(logits), mb["expert_valid"])
    aux = {"bc_loss": bc, "entropy": ent}
    total = spec.w_bc * bc
    if spec.use_rl:
        mask = mb["valid"]
        logits_pi, values = logits_all[:, b:], values_all[:, b:]
        logp = action_log_prob(logits_pi, mb["actions"])
        pg = clipped_surrogate(logp, mb["log_probs"], mb["advantages"], spec.clip_eps, mask)
        vl = value_loss(values, mb["returns"], mask)
        ent_pi = masked_mean(entropy(logits_pi), mask)
        ppo = pg + spec.vf_coef * vl - spec.ent_coef * ent_pi
        total = total + spec.w_rl * ppo
        ratio = jnp.exp(logp - mb["log_probs"])
        aux |= {"ppo_loss": ppo, "policy_loss": pg, "value_loss": vl, "policy_entropy": ent_pi,
                "clip_frac": masked_mean((jnp.abs(ratio - 1) > spec.clip_eps).astype(
                    jnp.float32), mask),
                "ratio_dev": masked_mean(jnp.abs(ratio - 1.0), mask)}
    return total, aux


def update_one_seed(spec: UpdateSpec, params, opt_state, batch: SimState, key, lr):
    """One update of one seed on its batch ``[B]``; returns ``(params, opt_state, metrics)``."""
    b = batch.timestep.shape[0]
    k_ep, k_act, k_perm = jax.random.split(key, 3)
    episode_keys = jax.random.split(k_ep, b)
    data = {"warm_obs": env.warmup_observations(batch, spec.setting, spec.obs, episode_keys)}
    expert = env.expert_rollout(batch, spec.setting, spec.obs, spec.sim, episode_keys)
    data |= {"expert_obs": expert.obs, "expert_actions": expert.actions,
             "expert_valid": expert.valid}
    metrics = {}
    if spec.use_rl:
        carry = env.warm_carry(spec.policy, params, data["warm_obs"])
        roll = env.policy_rollout(spec.policy, params, carry, batch, spec.setting, spec.obs,
                                  spec.sim, episode_keys, k_act)
        roll = jax.tree.map(jax.lax.stop_gradient, roll)
        # Episodes end at step 90 (terminal): the value after the last step is 0.
        adv, ret = gae(roll.rewards.T, roll.values.T, jnp.zeros((b,)), spec.gamma,
                       spec.gae_lambda)
        adv = normalize(adv.T, roll.valid)
        data |= {"policy_obs": roll.obs, "actions": roll.actions, "log_probs": roll.log_probs,
                 "valid": roll.valid, "advantages": adv, "returns": ret.T}
        metrics["mean_return"] = roll.rewards.sum(0).mean()
        metrics["overlap_or_offroad_steps"] = (roll.rewards < 0).astype(jnp.float32).mean()
    tx = optimizer(spec)
    grad_fn = jax.value_and_grad(partial(_loss, spec), has_aux=True)
    per_mb = b // spec.minibatches

    def minibatch_step(carry, idx):
        params, opt_state = carry
        mb = _take(data, idx, axis=1)
        (_, aux), grads = grad_fn(params, mb)
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
    """The jitted update over all seeds: ``(params[S], opt_state[S], batch[S, B], seed_keys[S],
    update_index, lr) -> (params, opt_state, metrics[S])``."""

    def update(params, opt_state, batch, seed_keys, update_index, lr):
        keys = jax.vmap(lambda k: jax.random.fold_in(k, update_index))(seed_keys)
        return jax.vmap(partial(update_one_seed, spec), in_axes=(0, 0, 0, 0, None))(
            params, opt_state, batch, keys, lr)

    return jax.jit(update, donate_argnums=(0, 1) if donate else ())
