"""DAgger with a privileged teacher (Ross et al. 2011; the idea, our code).

Iteration 0 is the logged data (BC, weight ``w_BC``). Every update the student drives its own
closed-loop episodes (beta = 0: no mixing with the teacher); the teacher (the Full-setting policy
of ``training.teacher``) labels every visited state from its full observation; the labelled
episodes join a buffer of the last ``aggregate_batches`` updates (``--set
method.aggregate_batches=N``), and the student learns the teacher's labels (soft cross-entropy)
on a batch drawn from it.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
from flax import struct

from igdrivsim.core.learn import masked_mean, soft_cross_entropy, take_rows
from igdrivsim.errors import ConfigError
from igdrivsim.names import LEARNED
from igdrivsim.observation import Observation
from igdrivsim.policy.act import CONTROLLED_STEPS, WARMUP_STEPS, example_observation
from igdrivsim.training.methods import Method, register_method
from igdrivsim.training.methods.bc import logged_bc


@dataclass(frozen=True)
class Params:
    aggregate_batches: int = 4  # the buffer keeps the labelled episodes of this many updates

    def __post_init__(self):
        if self.aggregate_batches < 1:
            raise ConfigError("method.aggregate_batches must be >= 1, got "
                              f"{self.aggregate_batches}")


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
        return take_rows((self.obs, self.logp, self.valid), idx)


def init_buffer(spec, batch: int) -> Aggregate:
    """The empty buffer of one (setting, seed)."""
    n = spec.params.aggregate_batches * batch
    obs = jax.tree.map(lambda x: jnp.zeros((n, WARMUP_STEPS + CONTROLLED_STEPS, *x.shape),
                                           x.dtype), example_observation(spec.obs))
    return Aggregate(obs, jnp.zeros((n, CONTROLLED_STEPS, 3, spec.policy.num_bins)),
                     jnp.zeros((n, CONTROLLED_STEPS), bool), jnp.zeros((), jnp.int32),
                     spec.params.aggregate_batches)


def collect(spec, buffer: Aggregate, data: dict, key: jax.Array):
    """Push this update's labelled student episodes (its logged warm-up, then its own steps),
    and draw a batch of ``aggregate`` episodes from the buffer."""
    student = jax.tree.map(lambda w, p: jnp.concatenate([w[:, :WARMUP_STEPS], p], 1),
                           data["logged_obs"], data["rollout_obs"])
    buffer = buffer.push(student, data["teacher_logp"], data["valid"])
    obs, logp, valid = buffer.sample(key, data["valid"].shape[0])
    data = data | {"aggregate_obs": obs, "aggregate_logp": logp, "aggregate_valid": valid}
    return data, buffer, {"aggregate_episodes": buffer.episodes.astype(jnp.float32)}


def loss(spec, out, batch):
    bc, metrics = logged_bc(spec, out, batch)
    mask = batch["aggregate_valid"]
    imitation = masked_mean(soft_cross_entropy(batch["aggregate_logp"],
                                               out["aggregate"].logits).sum(-1), mask)
    return spec.loss.w_bc * bc + imitation, metrics | {"teacher_ce": imitation}


register_method(Method("dagger", *LEARNED["dagger"], loss, episodes=("logged", "aggregate"),
                       teacher=True, params=Params(), init_buffer=init_buffer,
                       collect=collect))
