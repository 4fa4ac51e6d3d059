"""The registry of learning methods: one module each, ending with one :func:`register_method`.

A :class:`Method` declares its params, its loss, the episodes its loss reads, its own collection
(with a buffer kept across updates, e.g. DAgger's aggregate) and the loss it reports. The update
(:mod:`igdrivsim.training.update`) builds the shared episodes it asks for: ``logged`` (the logged
episodes under the setting, labelled with the discretised expert actions) and ``rollout`` (the
policy's own closed-loop episode from the same warm-up, with log-probabilities, values, rewards,
GAE and, with ``teacher=True``, a privileged teacher's labels). Any other kind ``K`` is the
method's own: its ``collect`` adds ``K_obs [b, 90, ...]`` and what its loss reads. The network
runs once over all of them and the method's ``loss`` gets the outputs.

A method's own hyper-parameters are a frozen dataclass instance holding the defaults
(``params``; validate in ``__post_init__``), set with ``--set method.NAME=VALUE`` and read in
the loss as ``spec.params.NAME``; its label and colour are :mod:`igdrivsim.names`' ``LEARNED``.
docs/ARCHITECTURE.md, "To add a method", has a worked example.
"""

from __future__ import annotations

import dataclasses
import importlib
import pkgutil
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, NamedTuple

import jax

from igdrivsim.errors import ConfigError

SHARED_EPISODES = ("logged", "rollout")  # built by the update; any other kind is the method's


class Outputs(NamedTuple):
    """The network over one kind of episode, time-major over the 80 controlled steps."""

    logits: jax.Array  # [80, b, 3, bins]
    values: jax.Array  # [80, b]
    aux_logits: jax.Array | None  # [80, b, 3, bins] with the auxiliary head, else None


# loss(spec: the static UpdateSpec, outputs by episode kind, batch) -> (total, metrics); the
# batch holds time-major [80, b, ...] arrays: expert_actions / expert_valid (logged), actions /
# log_probs / valid / advantages / returns / teacher_logp (rollout), and what collect added
LossFn = Callable[[Any, dict[str, Outputs], dict[str, jax.Array]],
                  tuple[jax.Array, dict[str, jax.Array]]]
# init_buffer(spec, batch) -> the method's empty buffer of one (setting, seed)
# collect(spec, buffer, data, key) -> (data, buffer, metrics): ``data`` (scenario-major) holds
# logged_obs [b, 90] and, when the policy drives, rollout_obs [b, 80] and the rollout's arrays
InitBuffer = Callable[[Any, int], Any]
CollectFn = Callable[[Any, Any, dict[str, Any], jax.Array],
                     tuple[dict[str, Any], Any, dict[str, jax.Array]]]


@dataclass(frozen=True)
class NoParams:
    """The hyper-parameters of a method that has none of its own."""


@dataclass(frozen=True)
class Method:
    """One learning method."""

    name: str  # --method value and the ``method`` column of the CSVs
    label: str  # tables and figures
    colour: str  # figures (matplotlib colour)
    loss: LossFn
    episodes: tuple[str, ...] = ("logged",)  # what the loss reads (see the module docstring)
    teacher: bool = False  # a privileged teacher labels the rollout's states
    aux_head: bool = False  # the network gets an auxiliary imitation head (ADVISOR)
    baseline: str | None = "bc"  # the method it is compared with (Tables I-II: BC)
    params: Any = NoParams()  # its own hyper-parameters (see the module docstring)
    # the training loss it reports first (progress bar, learning curves, ``bench train``)
    reports: str = "bc_loss"
    init_buffer: InitBuffer | None = None  # its state across updates (DAgger's aggregate)
    collect: CollectFn | None = None  # adds its own episodes to an update's data

    def __post_init__(self):
        if not dataclasses.is_dataclass(self.params) or isinstance(self.params, type):
            raise ConfigError(f"method {self.name!r}: params must be a dataclass instance "
                              f"(its defaults), got {self.params!r}")
        own = [k for k in self.episodes if k not in SHARED_EPISODES]
        if not self.episodes or (own and self.collect is None):
            raise ConfigError(f"method {self.name!r}: episodes must be among "
                              f"{SHARED_EPISODES} or its own, built by its collect hook")

    def with_params(self, values: Mapping[str, Any]) -> Any:
        """The method's params with those of ``values`` it declares set (the others are another
        method's, ignored); the params' own checks raise a one-line error."""
        own = {f.name for f in dataclasses.fields(self.params)}
        return dataclasses.replace(self.params, **{k: v for k, v in values.items() if k in own})

    @property
    def rollout(self) -> bool:
        """The policy drives a closed-loop episode every update."""
        return "rollout" in self.episodes or self.teacher


METHODS: dict[str, Method] = {}


def register_method(method: Method) -> Method:
    """Add ``method`` to the registry (its name must be new)."""
    if method.name in METHODS and METHODS[method.name] != method:
        raise ConfigError(f"learning method {method.name!r} is already registered")
    METHODS[method.name] = method
    return method


def method_param_defaults() -> dict[str, Any]:
    """Every hyper-parameter a registered method declares (``--set method.NAME=VALUE``), with
    the default of the first method declaring it (its type parses the value)."""
    found: dict[str, Any] = {}
    for method in METHODS.values():
        for f in dataclasses.fields(method.params):
            found.setdefault(f.name, getattr(method.params, f.name))
    return found


def get_method(name: str) -> Method:
    """The registered method ``name`` (one-line error naming the choices otherwise)."""
    if name not in METHODS:
        raise ConfigError(f"unknown learning method {name!r}; choose from {', '.join(METHODS)}")
    return METHODS[name]


# Registration order (the tables' order): the paper's two methods, the remedies beyond it, then
# any other module of this package alphabetically.
ORDER = ("bc", "bc_rl", "dagger", "advisor")
DEFAULT_METHOD = ORDER[0]  # what a run trains unless told otherwise: the paper's BC


def method_modules() -> list[str]:
    """The modules of this package, in registration order."""
    found = {m.name for m in pkgutil.iter_modules(__path__) if not m.name.startswith("_")}
    return [m for m in ORDER if m in found] + sorted(found - set(ORDER))


for _module in method_modules():
    importlib.import_module(f"{__name__}.{_module}")
