"""DAgger with a privileged teacher (Ross et al. 2011; the idea, our code).

Iteration 0 is the logged data (BC on the discretised expert actions, weight ``w_BC``). Every
update the student drives its own closed-loop episodes under its setting; the teacher (the
Full-setting policy of ``training.teacher``) labels every state the student visits with its
action distribution, seeing the full observation of that state; the labelled episodes join a
buffer of the last ``aggregate_batches`` updates (``--set method.aggregate_batches=N``), and
the student is trained on a batch drawn from the buffer with the soft cross-entropy to the
teacher's labels. The student always drives (no mixing with the teacher: beta = 0 after
iteration 0).
"""

from __future__ import annotations

from dataclasses import dataclass

from igdrivsim.core.learn import masked_mean
from igdrivsim.errors import ConfigError
from igdrivsim.names import LEARNED
from igdrivsim.policy.act import soft_cross_entropy
from igdrivsim.training.methods import Method, register_method
from igdrivsim.training.methods.bc import logged_bc


@dataclass(frozen=True)
class Params:
    aggregate_batches: int = 4  # the buffer keeps the labelled episodes of this many updates

    def __post_init__(self):
        if self.aggregate_batches < 1:
            raise ConfigError("method.aggregate_batches must be >= 1, got "
                              f"{self.aggregate_batches}")


def loss(spec, out, batch):
    bc, metrics = logged_bc(spec, out, batch)
    mask = batch["aggregate_valid"]
    imitation = masked_mean(soft_cross_entropy(batch["aggregate_logp"],
                                               out["aggregate"].logits), mask)
    return spec.loss.w_bc * bc + imitation, metrics | {"teacher_ce": imitation}


register_method(Method("dagger", *LEARNED["dagger"], loss, episodes=("logged", "aggregate"),
                       teacher=True, params=Params()))
