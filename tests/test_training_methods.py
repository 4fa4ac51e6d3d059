"""The learning-method registry: the CLI, the configuration and the figures read it."""

from __future__ import annotations

import argparse

import pytest

from igdrivsim.errors import ConfigError
from igdrivsim.training import methods
from igdrivsim.training.config import get_profile, with_overrides


@pytest.fixture
def extra_method():
    """A method registered for one test (the registry is one dict that every reader shares)."""
    method = methods.register_method(methods.Method(
        "bc_rl_strong", "BC-RL (w_RL 0.5)", "#2CA02C", uses_rl=True, baseline="bc"))
    yield method
    del methods.METHODS[method.name]


def test_the_papers_two_methods():
    assert list(methods.METHODS) == ["bc", "bc_rl"]
    assert not methods.get_method("bc").uses_rl and methods.get_method("bc_rl").uses_rl
    assert methods.get_method("bc_rl").baseline == "bc"
    with pytest.raises(ConfigError, match="unknown learning method 'dagger'"):
        methods.get_method("dagger")


def test_configuration_reads_the_registry(extra_method):
    laptop = get_profile("laptop")
    assert not with_overrides(laptop, ["training.method=bc"]).use_rl
    assert with_overrides(laptop, ["training.method=bc_rl"]).use_rl
    config = with_overrides(laptop, ["training.method=bc_rl_strong", "training.w_rl=0.5"])
    assert config.validate().use_rl
    with pytest.raises(ConfigError, match="unknown learning method"):
        with_overrides(laptop, ["training.method=nope"]).validate()
    with pytest.raises(ConfigError, match="already registered"):
        methods.register_method(methods.Method("bc", "other", "red", uses_rl=True))


def test_train_command_offers_every_registered_method(extra_method):
    from igdrivsim.training.commands import train_arguments

    parser = argparse.ArgumentParser()
    train_arguments(parser)
    args = parser.parse_args(["--method", "bc_rl_strong", "--data", "d", "--out", "o"])
    assert args.method == "bc_rl_strong"
