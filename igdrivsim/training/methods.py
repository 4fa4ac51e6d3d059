"""The registry of learning methods: a method's name, label, colour and what its update does.

``igdrivsim train --method`` and ``igdrivsim bench train --method`` offer every registered
method, the configuration check accepts it and decides from ``uses_rl`` whether the update adds
the PPO term and its closed-loop rollout, and the report and the learning-curve figure take its
label and colour. The update itself (:mod:`igdrivsim.training.update`) is the paper's loss
``w_BC BC + w_RL PPO``; the pipeline trains the paper's two, and the report compares every
learned method with BC (Table I: BC-RL against BC).
"""

from __future__ import annotations

from dataclasses import dataclass

from igdrivsim.errors import ConfigError


@dataclass(frozen=True)
class Method:
    """One learning method."""

    name: str  # --method value and the ``method`` column of the CSVs
    label: str  # tables and figures
    colour: str  # figures (matplotlib colour)
    uses_rl: bool  # adds the PPO term (w_rl) and a closed-loop rollout to every update
    baseline: str | None = None  # the method it is meant to be compared with (report: BC)


METHODS: dict[str, Method] = {}


def register_method(method: Method) -> Method:
    """Add ``method`` to the registry (its name must be new)."""
    if method.name in METHODS and METHODS[method.name] != method:
        raise ConfigError(f"learning method {method.name!r} is already registered")
    METHODS[method.name] = method
    return method


def get_method(name: str) -> Method:
    """The registered method ``name`` (one-line error naming the choices otherwise)."""
    if name not in METHODS:
        raise ConfigError(f"unknown learning method {name!r}; choose from {', '.join(METHODS)}")
    return METHODS[name]


# behaviour cloning on the logged episodes (w_RL forced to 0)
register_method(Method("bc", "BC", "#4C9BE8", uses_rl=False))
# w_BC BC + w_RL PPO on the policy's own closed-loop episodes
register_method(Method("bc_rl", "BC-RL", "#F28E2B", uses_rl=True, baseline="bc"))
